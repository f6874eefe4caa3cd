//! Selection settings: the policy, `τ` and its hysteresis, and geomorphing.

/// How detail is chosen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Policy {
    /// Screen-space error from the error tables: `ρ = ε·λ/d ≤ τ`.
    #[default]
    ScreenError,
    /// Distance only (the brute-force policy Kang compares against): a cell's own
    /// size stands in for its error, so `τ` bounds the on-screen size of a cell
    /// whatever the terrain's roughness.
    Distance,
}

/// Selection settings.
#[derive(Clone, Copy, Debug)]
pub struct SelectParams {
    /// Screen-space error threshold `τ` in pixels.
    pub tau: f64,
    /// Hysteresis: a finer choice is only given up once the coarser one is below
    /// `τ·(1 − hysteresis)`.
    pub hysteresis: f64,
    pub policy: Policy,
    /// Seconds a geomorph transition takes ([`super::morph::transition`]): a patch that
    /// replaces a coarser surface starts as that surface and morphs to its own
    /// LOD in this time (of the clock given to [`Selector::select_at`](super::Selector::select_at)); 0 for
    /// none.
    pub morph_seconds: f64,
    /// Whether patches also slide towards `n/2` across a band of distance (CDLOD,
    /// [`super::morph::patch_factor`]) rather than only over time. Off by default: on
    /// the moon descent it changed the popping figures by nothing measurable
    /// once transitions run over time, and it cost 1 dB of PSNR at `τ = 1`, since
    /// it draws every patch in its band coarser than its LOD (DECISIONS.md
    /// "Geomorphing over time").
    pub morph_by_distance: bool,
    /// The most error a transition may draw, as a multiple of `τ` (at least 1):
    /// a refined patch starts as the old surface only as far as its `ρ` there
    /// stays within `morph_error_limit·τ`, and jumps the rest of the way
    /// ([`super::morph::transition`]). Without a limit, transitions lagged fast flight
    /// (moon `canyon` at 150 ms: 37% of frames within τ as drawn and 90% within
    /// 2τ, against 96% and 100% as selected).
    pub morph_error_limit: f64,
}

/// [`SelectParams::morph_seconds`] unless told otherwise.
pub const MORPH_SECONDS: f64 = 0.25;

/// [`SelectParams::morph_error_limit`] unless told otherwise: `τ` itself, so that
/// the surface as drawn keeps `τ` wherever the selected LODs do. On the moon
/// descent of `bench/popping.sh` it popped as little as no limit (same-camera
/// excess 0.012 both ways: a refinement starts where `ρ_{n/2}` has only just
/// passed `τ`, nearly at the old surface), and it cut only the transitions that
/// lagged fast flight (DECISIONS.md "Geomorphing over time").
pub const MORPH_ERROR_LIMIT: f64 = 1.0;

impl Default for SelectParams {
    fn default() -> Self {
        Self {
            tau: 1.0,
            hysteresis: 0.15,
            policy: Policy::ScreenError,
            morph_seconds: MORPH_SECONDS,
            morph_by_distance: false,
            morph_error_limit: MORPH_ERROR_LIMIT,
        }
    }
}

impl SelectParams {
    /// Whether geomorph transitions run over time (a positive, finite duration).
    pub fn transitions(&self) -> bool {
        self.morph_seconds > 0.0 && self.morph_seconds.is_finite()
    }
}
