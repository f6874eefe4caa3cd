//! What a frame's selection gives: the tiles and patches to draw, the tiles wanted,
//! and the frame's statistics.

use super::patch::Patch;
use tessera_shared::TileId;

/// A tile the selection wants and does not have, with how much it is wanted (the
/// screen-space error of what is drawn in its place).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wanted {
    pub tile: TileId,
    pub rho: f64,
}

/// Per-frame statistics: the deficit is reported, never hidden
/// (docs/ARCHITECTURE.md#screen-space-error-met-or-reported), and what could not be had
/// is reported as missing, not as a huge number
/// (docs/ARCHITECTURE.md#the-client-never-goes-blind).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrameStats {
    pub tiles: usize,
    pub patches: usize,
    pub triangles: u64,
    /// Coarsest pyramid level drawn (`None` when nothing is drawn): 0 once the
    /// root is resident, 1 or finer while a bad root is drawn through its children.
    #[serde(default)]
    pub coarsest_level: Option<u8>,
    /// Largest screen-space error of anything drawn, in pixels. `None` ("missing")
    /// when it has no bound: part of the view has nothing drawn at all
    /// (`missing > 0`), or the eye is inside the error box of a coarse tile drawn in
    /// place of missing children (`ρ = ε·λ/d` with `d = 0`).
    pub max_rho: Option<f64>,
    /// `max_rho / τ`: above 1 while what is needed is still streaming; `None` with
    /// `max_rho`.
    pub deficit: Option<f64>,
    /// [`FrameStats::max_rho`] of the surface as drawn, geomorph transitions
    /// included (the deficit is never hidden:
    /// docs/ARCHITECTURE.md#screen-space-error-met-or-reported): while a patch's
    /// transition runs it is drawn part-way to the next coarser grid, and its bound is
    /// the mix of the two grids' ([`super::morph::drawn_rho`]). Equal to `max_rho` when
    /// no transition is in flight; `None` with it.
    #[serde(default)]
    pub drawn_max_rho: Option<f64>,
    /// `drawn_max_rho / τ`.
    #[serde(default)]
    pub drawn_deficit: Option<f64>,
    /// Tiles in view with nothing drawn in their place (no resident ancestor): the
    /// root before it arrives, or the parts of a bad root's children that have not
    /// arrived or cannot be had.
    #[serde(default)]
    pub missing: usize,
    pub select_us: f64,
}

impl FrameStats {
    /// Whether the frame drew something and every drawn error is within `limit·τ`.
    pub fn within(&self, limit: f64) -> bool {
        self.tiles > 0 && self.deficit.is_some_and(|d| d <= limit)
    }

    /// [`FrameStats::within`] for the surface as drawn, transitions included.
    pub fn drawn_within(&self, limit: f64) -> bool {
        self.tiles > 0 && self.drawn_deficit.is_some_and(|d| d <= limit)
    }
}

/// What to draw this frame.
#[derive(Clone, Debug, Default)]
pub struct Selection {
    pub tiles: Vec<TileId>,
    /// The patches as drawn: at the inner LODs and factors of geomorphing.
    pub patches: Vec<Patch>,
    /// The same patches at the inner and edge LODs selection chose, before
    /// geomorph transitions raised any ([`super::morph::transition`]): what selection
    /// decided, which the popping metric compares from frame to frame.
    pub chosen: Vec<Patch>,
    pub wanted: Vec<Wanted>,
    pub stats: FrameStats,
}
