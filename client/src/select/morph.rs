//! Geomorphing (CDLOD, Strugar 2009; Kang §4.4): how far each patch has slid from
//! its own inner LOD `n` towards the `n/2` grid, so that a change of LOD is a
//! continuous motion instead of a jump. The morph itself is CDLOD's (Strugar
//! 2009: odd vertices slide onto the next coarser grid, by a factor that CDLOD
//! takes from the distance); here *when* a patch slides is set over time
//! ([`transition`], below) and, only with [`SelectParams::morph_by_distance`],
//! also by distance (the interior factor below; off by default, since with
//! transitions it changed popping by nothing measurable and cost 1 dB of PSNR:
//! DECISIONS.md "Geomorphing over time"). Without it, a patch's target is its own
//! LOD at factor 0. A refined tile's shading fades in alongside ([`super::fade`]).
//!
//! A vertex at an odd grid index takes the height `h + (h̄ − h)·f`, where `h̄` is the
//! average of its even neighbours' heights (along the row, the column or the cell's
//! north-west → south-east diagonal, as the `n/2` grid splits its cells); at
//! `f = 1` the patch is exactly the `n/2` patch, triangle for triangle. Positions
//! east–west and north–south never move, only heights: the vertex stays on its
//! finest-grid point, so `relative()` in the shader is unchanged.
//!
//! **The factor of a patch's interior** must be 1 where selection switches
//! between `n/2` and `n` (both there and in the hysteresis zone between, where
//! either may be drawn, the two must look alike), and 0 where it switches between
//! `n` and `2n`. Selection (Kang §4.4 with hysteresis `h`) draws `n` rather than
//! `n/2` once `ρ_{n/2} > τ` coming closer, and keeps it until `ρ_{n/2} ≤ τ·(1 − h)`
//! going away; so a patch at `n` is drawn as `n/2` (`f = 1`) while `ρ_{n/2} ≤ τ`,
//! and as itself (`f = 0`) once `ρ_n ≥ τ·(1 − h)`, where an `n/2` patch, had it
//! been drawn, would be at 0 too. Between the two, `ρ ∝ 1/d` and the factor is
//! linear in `1/d` (CDLOD's band of distance, here set by the error tables):
//! with `u = ρ_n/(τ·(1 − h))` and `v = ρ_{n/2}/τ`, `f = v·(1 − u)/(v − u)`. It is
//! further capped so that the mixed surface keeps `τ`: heights are a convex mix,
//! off by at most `(1 − f)·ε_n + f·ε_{n/2}`, i.e. `ρ ≤ (1 − f)·ρ_n + f·ρ_{n/2}`, so
//! `f ≤ (τ − ρ_n)/(ρ_{n/2} − ρ_n)` (equal to 1 at `ρ_{n/2} = τ`, so the cap keeps
//! both ends). Where `ε_n ≥ (1 − h)·ε_{n/2}` the two hysteresis zones overlap and
//! no factor suits both: the cap alone is used (1 at `ρ_{n/2} = τ`, 0 at `ρ_n = τ`,
//! where a patch coming closer switches), and the band is narrow, crossed in a
//! few frames: LOD `n` is short-lived there whatever is drawn.
//!
//! **Edges** (docs/ARCHITECTURE.md#crack-free-edges at every factor): a vertex on a patch
//! side is shared with the patches across it, so its factor must be something both sides
//! hold. Each shared side (a group of [`super::edge_lod`], spacing `D`) gets one
//! factor, written into every member's side: the largest interior factor among
//! the members whose own spacing is `D` (those that set the edge LOD: when one of
//! them goes to `n/2` the group's spacing doubles, and the edge has already slid
//! there). Odd vertices on the `D` grid move to the average of their neighbours at
//! `±D`, which both sides read from the same DEM samples. An edge only morphs when
//! `2D` divides every member's side (all edge LODs ≥ 2): then every patch corner
//! sits at an even index and never moves, and the neighbours at `±D` lie on the
//! side itself. Heights are mixed in integers ([`mix`]), so both sides, and the
//! CPU and the GPU, get the same bits.
//!
//! **Over time** ([`transition`]): a distance factor alone cannot make every
//! change of selection continuous. A quadtree split or a tile refinement gives
//! children that pick their LODs from their own, smaller blocks: the near ones
//! are finer than the parent drew, and their distance factor (capped to keep
//! `τ`) is then often below 1, so they do not start from the old surface; the
//! far ones are often coarser than the parent drew, which no factor towards
//! `n/2` can undo. (Measured on the moon descent of `bench/popping.sh`, the
//! distance factor alone cut the same-camera pop by only 1.2×.) So, as CDLOD's
//! morph is continuous in distance, this one is also continuous in time:
//! selection remembers what each square of the global grid was drawn as, its
//! *coarseness* `FULL·log2(spacing) + f` ([`coarseness`]; a patch of spacing `D`
//! at `f = FULL` is the `2D` surface at 0), and each frame a patch is drawn at a
//! coarseness that starts where the old surface was and moves towards its own
//! target (its LOD at its distance factor) by at most one grid per
//! [`super::SelectParams::morph_seconds`] of the caller's clock
//! ([`super::Selector::select_at`]): a refinement starts at `FULL`, exactly the
//! old surface, and falls; a patch coarser than what was drawn (a split's far
//! children, a merge) is drawn with its inner LOD raised and rises. Time is
//! explicit (a flight's time at its fixed frame rate, the window's wall clock),
//! so runs are reproducible, and selecting again at the same time (a settled
//! frame) advances nothing. The price: while a transition runs, a refined patch
//! is coarser than its LOD, though never past
//! [`super::SelectParams::morph_error_limit`]`·τ` (by default `τ` itself: a
//! refinement that would start above it jumps part of the way, which in slow
//! flight is rarely and little, since `ρ_{n/2}` has only just passed `τ` when
//! selection refines; the frame reports this bound as `drawn_max_rho`, [`drawn_rho`]),
//! and a raised one costs triangles. The change a pop made at once is spread over
//! the frames of the transition; crack-freedom is untouched (the sides are shared
//! as below, from whatever interior factors the patches have).
//!
//! **Tiles and their children**: a child tile's level `m` grid is its parent's
//! level `m + 1` grid, on the same samples (the pyramid decimates), so a child
//! patch at factor 1 is its parent's surface one level coarser; and since factors
//! come from the errors of the surface drawn and the distance, the same surface
//! gets about the same factor on either side of a refinement.

use super::edge_lod;
use super::metric::TileRho;
use super::params::SelectParams;
use super::patch::Patch;
use super::world::World;
use std::collections::{HashMap, HashSet};
use tessera_shared::TileId;

pub use super::patch::{FULL, Morph};

/// A height mixed from quantized samples: `q` moved by `f/FULL` of the way to the
/// average of `a` and `b`, in units of `1/(2·FULL)` of a quantization step (so
/// exact: at most `2·65535·256 < 2^25`). An unmoved vertex is `2·FULL·q`.
pub const fn mix(q: u16, a: u16, b: u16, f: u16) -> u32 {
    let (q, a, b, f) = (q as u32, a as u32, b as u32, f as u32);
    2 * q * (FULL as u32 - f) + (a + b) * f
}

/// The units of [`mix`] per quantization step.
pub const HEIGHT_UNITS: u32 = 2 * FULL as u32;

/// The interior factor of a patch drawn at inner LOD `n` whose `ρ` there is
/// `rho_n` and at `n/2` is `rho_half` (`None` for `n = 1`, which has nothing
/// coarser), with selection's `tau` and `hysteresis`; rounded down.
pub fn patch_factor(tau: f64, hysteresis: f64, rho_n: f64, rho_half: Option<f64>) -> u16 {
    let Some(rho_half) = rho_half else { return 0 };
    // The cap that keeps τ: FULL where n/2 meets τ; 0 where n itself misses τ
    // (selection refines it, or it is forced), or NaN: as itself.
    let keeps_tau = limit_factor(tau, rho_n, rho_half);
    if keeps_tau == 0 || keeps_tau == FULL {
        return keeps_tau;
    }
    // Here ρ_n < τ < ρ_{n/2}.
    let (u, v) = (rho_n / (tau * (1.0 - hysteresis)), rho_half / tau);
    // Whether the two hysteresis zones are apart (ε_n < (1 − h)·ε_{n/2}): a ratio
    // of errors, the same at any distance, so the choice never flips as the eye
    // moves.
    if rho_n < (1.0 - hysteresis) * rho_half {
        // Then u < v, and the band runs from 1 (v = 1) to 0 (u = 1).
        keeps_tau.min(to_factor(v * (1.0 - u) / (v - u)))
    } else {
        // They overlap: no factor suits both; LOD n lives only between
        // ρ_{n/2} = τ and ρ_n = τ coming closer, and the cap alone runs from 1 to
        // 0 across exactly that.
        keeps_tau
    }
}

/// A fraction in `[0, 1]` as a factor, rounded down (clamped; NaN is 0).
fn to_factor(f: f64) -> u16 {
    (f * f64::from(FULL)).floor().clamp(0.0, f64::from(FULL)) as u16
}

/// The largest factor at which a patch whose `ρ` is `rho_n` at its inner LOD
/// and `rho_half` one grid coarser keeps its drawn bound,
/// `(1 − f)·ρ_n + f·ρ_{n/2}` ([`drawn_rho`]), within `limit`; rounded down. 0 where
/// `ρ_n` alone misses it (or is NaN), [`FULL`] where `ρ_{n/2}` keeps it.
pub fn limit_factor(limit: f64, rho_n: f64, rho_half: f64) -> u16 {
    if rho_half <= limit {
        return FULL;
    }
    if rho_n.is_nan() || rho_half.is_nan() || rho_n >= limit {
        return 0;
    }
    // ρ_n < limit < ρ_{n/2}: in (0, 1).
    to_factor((limit - rho_n) / (rho_half - rho_n))
}

/// Depth `k` and node `(i, j)` of a patch in its tile's quadtree.
fn node(world: &World, p: &Patch) -> (u32, u32, u32) {
    let k = (world.geometry.tile_size() / p.size).trailing_zeros();
    (k, p.origin[0] / p.size, p.origin[1] / p.size)
}

/// Sets every patch's [`Morph`], after the edge LODs are final
/// ([`edge_lod::assign`]); `rhos` are this frame's `ρ` tables of the drawn tiles.
/// With `before` (what the last frame drew) and this frame's time `t`, the
/// patches then move over time from the surface drawn before ([`transition`]:
/// inner LODs may be raised, and edge LODs are then assigned again); without,
/// each interior factor is the distance factor alone (0 unless
/// [`SelectParams::morph_by_distance`]). Returns what this frame
/// draws, for the next one, when it has a time.
pub fn assign(
    world: &World,
    params: &SelectParams,
    patches: &mut [Patch],
    rhos: &HashMap<TileId, TileRho>,
    before: Option<&Drawn>,
    t: Option<f64>,
) -> Option<Drawn> {
    for p in patches.iter_mut() {
        let f = match rhos.get(&p.tile) {
            Some(rho) if params.morph_by_distance => {
                let (k, i, j) = node(world, p);
                let l = p.inner.trailing_zeros();
                let half = (l > 0).then(|| rho.rho(k + l - 1, k, i, j));
                patch_factor(params.tau, params.hysteresis, rho.rho(k + l, k, i, j), half)
            }
            _ => 0,
        };
        p.morph.inner = f;
    }
    let selected: Vec<u32> = patches.iter().map(|p| p.inner).collect();
    if let (Some(before), Some(t)) = (before, t)
        && transition(world, params, patches, rhos, before, t)
    {
        // Finer patches only make a side's spacing finer: no inner LOD is raised
        // again, only the edge LODs follow.
        edge_lod::assign(world, patches);
    }
    share_edges(world, patches);
    t.map(|t| Drawn::new(world, patches, &selected, t))
}

/// The largest `ρ` of the patches as drawn: a patch at inner LOD `n` slid by
/// `f` towards `n/2` has heights within `(1 − f)·ε_n + f·ε_{n/2}` of the DEM (a
/// convex mix, as [`patch_factor`] says), so its bound is that mix of the two
/// `ρ`, by its interior factor (a side slides by the factor of the patches
/// across it that set its spacing, and is in their bound). `rhos` are this
/// frame's tables of the drawn tiles.
pub fn drawn_rho(world: &World, patches: &[Patch], rhos: &HashMap<TileId, TileRho>) -> f64 {
    patches
        .iter()
        .filter_map(|p| {
            let rho = rhos.get(&p.tile)?;
            let (k, i, j) = node(world, p);
            let l = p.inner.trailing_zeros();
            let own = rho.rho(k + l, k, i, j);
            let f = p.morph.inner;
            if l == 0 || f == 0 {
                return Some(own);
            }
            let f = f64::from(f) / f64::from(FULL);
            Some((1.0 - f) * own + f * rho.rho(k + l - 1, k, i, j))
        })
        .fold(0.0, f64::max)
}

/// A patch's square on the global finest grid: `(log2 S, X/S, Y/S)`.
type Square = (u32, u64, u64);

fn square(world: &World, p: &Patch) -> Square {
    let (s, x, y) = edge_lod::global(world, p);
    (s, x >> s, y >> s)
}

/// How coarse a drawn surface is, in `1/FULL` steps of `log2` of its spacing in
/// finest samples: a patch of side `2^s` at inner LOD `n` and factor `f` draws
/// `FULL·log2(2^s/n) + f` (at `f = FULL` it is the grid of spacing `2·2^s/n`,
/// the same surface as `n/2` at 0).
pub fn coarseness(s: u32, inner: u32, factor: u16) -> u32 {
    (s - inner.trailing_zeros()) * u32::from(FULL) + u32::from(factor)
}

/// What one frame drew, kept for the next frame's [`transition`]s: every
/// patch's square, the inner LOD selection chose for it, the inner LOD and
/// interior factor it was drawn at, and the frame's time.
#[derive(Clone, Debug, Default)]
pub struct Drawn {
    /// Seconds (the caller's clock) the frame was selected at.
    pub t: f64,
    patches: HashMap<Square, (u32, u32, u16)>,
    /// Every square that holds a drawn patch and is larger than it.
    above: HashSet<Square>,
    max_log: u32,
}

/// Larger than any patch's square (`log2` of finest samples).
const TOP_LOG: u32 = 48;

impl Drawn {
    /// The patches of a frame selected at `t` as drawn, with the inner LODs
    /// selection chose (`selected`, one per patch).
    fn new(world: &World, patches: &[Patch], selected: &[u32], t: f64) -> Self {
        let mut d = Self {
            t,
            patches: HashMap::with_capacity(patches.len()),
            above: HashSet::with_capacity(2 * patches.len()),
            max_log: 0,
        };
        for (p, &n) in patches.iter().zip(selected) {
            let (s, x, y) = square(world, p);
            d.patches.insert((s, x, y), (n, p.inner, p.morph.inner));
            d.max_log = d.max_log.max(s);
            // Up to the first square already known to hold one (whose own
            // holders are known then).
            for j in 1..TOP_LOG.saturating_sub(s) {
                if !d.above.insert((s + j, x >> j, y >> j)) {
                    break;
                }
            }
        }
        d
    }

    /// The [`coarseness`] drawn over `sq`: of the patch that was that square or
    /// held it, else the finest of the smaller patches inside it (a merge);
    /// `None` where nothing was drawn there.
    fn over(&self, sq: Square) -> Option<u32> {
        let (s, x, y) = sq;
        for j in 0..=self.max_log.saturating_sub(s) {
            if let Some(&(_, n, f)) = self.patches.get(&(s + j, x >> j, y >> j)) {
                return Some(coarseness(s + j, n, f));
            }
        }
        self.finest_inside(sq)
    }

    fn finest_inside(&self, (s, x, y): Square) -> Option<u32> {
        if !self.above.contains(&(s, x, y)) {
            return None;
        }
        [(0, 0), (1, 0), (0, 1), (1, 1)]
            .into_iter()
            .filter_map(|(a, b)| {
                let c = (s - 1, 2 * x + a, 2 * y + b);
                match self.patches.get(&c) {
                    Some(&(_, n, f)) => Some(coarseness(c.0, n, f)),
                    None => self.finest_inside(c),
                }
            })
            .min()
    }
}

/// The largest change of [`coarseness`] over `dt` seconds: one whole grid
/// (`FULL`) per [`SelectParams::morph_seconds`], rounded up so that a grid is
/// crossed in that time; 0 when time stands still or goes back; unlimited
/// without a duration.
pub fn step(params: &SelectParams, dt: f64) -> u32 {
    if !params.transitions() || dt.is_nan() {
        return u32::MAX;
    }
    (f64::from(FULL) * dt.max(0.0) / params.morph_seconds)
        .ceil()
        .min(f64::from(u32::MAX)) as u32
}

/// Geomorphing over time. On entry every patch is at the inner LOD selection
/// chose and its distance factor (0 without the distance band), i.e. its target
/// [`coarseness`]; it is drawn
/// instead at the coarseness that moves from what `before` drew over its square
/// towards that target:
///
/// - a square drawn last frame with the same selected inner LOD moves from
///   there towards its target by at most [`step`]`(t − before.t)`;
/// - anything else (a split, a merge, a tile refinement, another inner LOD)
///   starts exactly at the coarseness drawn there before (that of the patch
///   that was or held its square, else the finest inside it), and does not move
///   this frame: a change of selection at `t` draws, at `t`, what was drawn;
/// - where nothing was drawn before, its target.
///
/// A coarseness above the target's grid is drawn on that grid at factor up to
/// `FULL` (a refinement by one grid starts exactly as the old surface, by more
/// as the coarsest this grid can be); one below it raises the inner LOD (at
/// most 64) to the grid below it, so that a patch coarser than what was drawn
/// (the far children of a split often are, and a merge is) comes down to its own
/// LOD over time instead of jumping. Returns whether an inner LOD was raised.
///
/// **The error limit**: a coarseness above the target is further cut to the
/// largest whose drawn `ρ` ([`drawn_rho`]'s mix) keeps within
/// [`SelectParams::morph_error_limit`]`·τ` ([`limit_factor`]), though never below
/// the target: where the old surface is that much coarser than the new LOD (a
/// fast flight, or tiles that arrived late), the refinement jumps part of the
/// way and morphs the rest, rather than lag the flight with a surface far off
/// `τ`.
pub fn transition(
    world: &World,
    params: &SelectParams,
    patches: &mut [Patch],
    rhos: &HashMap<TileId, TileRho>,
    before: &Drawn,
    t: f64,
) -> bool {
    if !params.transitions() {
        return false;
    }
    let step = step(params, t - before.t);
    let full = u32::from(FULL);
    let mut raised = false;
    for p in patches.iter_mut() {
        let sq = square(world, p);
        let s = sq.0;
        let own = s - p.inner.trailing_zeros();
        let target = own * full + u32::from(p.morph.inner);
        let c = match before.patches.get(&sq) {
            Some(&(sel, n, f)) if sel == p.inner => {
                let was = coarseness(s, n, f);
                target.clamp(was.saturating_sub(step), was.saturating_add(step))
            }
            _ => before.over(sq).unwrap_or(target),
        };
        // Inner LOD at most 64; nothing coarser than n/2 (inner LOD 1: itself).
        let coarsest = own * full + if p.inner >= 2 { full } else { 0 };
        let mut c = c.clamp(s.saturating_sub(6) * full, coarsest);
        if c > target
            && let Some(rho) = rhos.get(&p.tile)
        {
            // Coarser than the target only on its own grid (at most `coarsest`):
            // the mix of ρ_n and ρ_{n/2} by the factor.
            let (k, i, j) = node(world, p);
            let l = p.inner.trailing_zeros();
            let f = limit_factor(
                params.morph_error_limit * params.tau,
                rho.rho(k + l, k, i, j),
                rho.rho(k + l - 1, k, i, j),
            );
            c = c.min((own * full + u32::from(f)).max(target));
        }
        let grid = (c / full).min(own);
        if grid < own {
            p.inner = 1 << (s - grid);
            raised = true;
        }
        p.morph.inner = (c - grid * full) as u16;
    }
    raised
}

/// Sets every side's factor from the interior factors (`morph.inner`), one per
/// shared side group, as the module says; a side shared with no one is the
/// patch's own (when its inner LOD is ≥ 2, so that the corners stay even).
pub fn share_edges(world: &World, patches: &mut [Patch]) {
    for p in patches.iter_mut() {
        let side = if p.inner >= 2 { p.morph.inner } else { 0 };
        p.morph.edges = [side; 4];
    }
    edge_lod::for_each_group(world, patches, |patches, group, sizes| {
        let spacing = |&(j, _): &(usize, usize)| sizes[j] / u64::from(patches[j].inner);
        let d = group.iter().map(spacing).max().unwrap_or(0);
        let smallest = group.iter().map(|&(j, _)| sizes[j]).min().unwrap_or(0);
        let f = if d > 0 && 2 * d <= smallest {
            group
                .iter()
                .filter(|m| spacing(m) == d)
                .map(|&(j, _)| patches[j].morph.inner)
                .max()
                .unwrap_or(0)
        } else {
            0
        };
        for &(j, side) in group {
            patches[j].morph.edges[side] = f;
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::select::{SelectParams, Selector};
    use crate::tessellate::{self, Vertex};
    use glam::{DVec2, DVec3};
    use std::collections::HashSet;
    use tessera_shared::{ErrorTable, Quantization, TileGeometry};

    /// Two levels of 512-cell tiles, 10 m apart; errors that halve with each
    /// within-tile level, so that patches of many LODs and sizes are drawn.
    fn scene() -> (
        World,
        HashMap<TileId, ErrorTable>,
        HashMap<TileId, Vec<u16>>,
    ) {
        let world = World {
            geometry: TileGeometry::new(2049, 2049, 512).unwrap(),
            quant: Quantization {
                offset: 0.0,
                scale: 1.0,
                max_error: 0.0,
            },
            spacing: DVec2::splat(10.0),
            globe: None,
        };
        let dem = |x: u64, y: u64| {
            let h = (x.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503)).wrapping_mul(97);
            (h >> 22) as u16 % 4000
        };
        let g = world.geometry;
        let (mut tables, mut heights) = (HashMap::new(), HashMap::new());
        for level in g.levels() {
            for tile in g.present_tiles(level) {
                let mut t = ErrorTable::empty(9);
                for n in 0..=9 {
                    let full = level == g.finest() && n == 9;
                    let e = if full {
                        0.0
                    } else {
                        400.0 / f32::from(1u16 << n)
                    };
                    for b in 0..64 {
                        t.set_error(n, b % 8, b / 8, e);
                        t.set_block_range(b % 8, b / 8, 0, 4000);
                    }
                }
                tables.insert(tile, t);
                let (gx, gy) = g.origin(tile);
                let s = g.spacing(level);
                let samples = u64::from(g.tile_size()) + 1;
                let h = (0..samples)
                    .flat_map(|v| (0..samples).map(move |u| (u, v)))
                    .map(|(u, v)| dem(gx + u * s, gy + v * s))
                    .collect();
                heights.insert(tile, h);
            }
        }
        (world, tables, heights)
    }

    fn camera(yaw: f64) -> Camera {
        Camera {
            position: DVec3::new(6000.0, 4600.0, 7500.0),
            yaw,
            pitch: -0.6,
            fovy: 60f64.to_radians(),
            width: 960,
            height: 540,
            near: 1.0,
            far: 100_000.0,
        }
    }

    /// Invariant 3 at the morph: every finest-grid point that two patches both
    /// place a side vertex on gets the same height from both. Returns how many
    /// shared points moved (morphed), were checked, and differ.
    fn shared_points(
        world: &World,
        patches: &[Patch],
        heights: &HashMap<TileId, Vec<u16>>,
    ) -> (usize, usize, usize) {
        let mut at: HashMap<(u64, u64), (Vertex, usize)> = HashMap::new();
        let (mut moved, mut checked, mut differ) = (0, 0, 0);
        for (k, p) in patches.iter().enumerate() {
            let mut seen = HashSet::new();
            for side in 0..4 {
                for v in tessellate::side_vertices(&world.geometry, p, &heights[&p.tile], side) {
                    if !seen.insert((v.x, v.y)) {
                        continue;
                    }
                    match at.get(&(v.x, v.y)) {
                        Some(&(w, other)) if other != k => {
                            differ += usize::from(v != w);
                            checked += 1;
                            moved += usize::from(v.h != u32::from(v.q) * HEIGHT_UNITS);
                        }
                        Some(_) => {}
                        None => {
                            at.insert((v.x, v.y), (v, k));
                        }
                    }
                }
            }
        }
        (moved, checked, differ)
    }

    #[test]
    fn shared_sides_agree_bit_for_bit_at_every_factor() {
        let (world, tables, heights) = scene();
        let mut levels = HashSet::new();
        let mut lods = HashSet::new();
        // The distance factors (CDLOD's band), which selection sets only when asked.
        let params = SelectParams {
            morph_by_distance: true,
            ..SelectParams::default()
        };
        for yaw in [0.3, 1.9, 4.0] {
            let mut selector = Selector::new(world, params);
            let sel = selector.select(&camera(yaw), &tables);
            levels.extend(sel.tiles.iter().map(|t| t.level()));
            lods.extend(sel.patches.iter().map(|p| p.inner));
            // The factors selection chose.
            let natural: Vec<u16> = sel.patches.iter().map(|p| p.morph.inner).collect();
            assert!(natural.iter().any(|&f| f > 0 && f < FULL), "{natural:?}");
            let (moved, checked, differ) = shared_points(&world, &sel.patches, &heights);
            assert_eq!(differ, 0, "{differ} of {checked} shared points differ");
            assert!(checked > 100 && moved > 0, "{moved} of {checked}");
            // Every factor, the same for all patches, then a different one for each.
            for f in [1, 77, FULL / 2, 255, FULL] {
                let mut patches = sel.patches.clone();
                for p in &mut patches {
                    p.morph.inner = f;
                }
                share_edges(&world, &mut patches);
                let (moved, checked, differ) = shared_points(&world, &patches, &heights);
                assert_eq!(differ, 0, "factor {f}: {differ} of {checked} differ");
                assert!(moved > 10, "factor {f}: {moved} of {checked} moved");
            }
            let mut patches = sel.patches.clone();
            for (k, p) in patches.iter_mut().enumerate() {
                p.morph.inner = (k as u16 * 37) % (FULL + 1);
            }
            share_edges(&world, &mut patches);
            let (moved, _, differ) = shared_points(&world, &patches, &heights);
            assert_eq!(differ, 0);
            assert!(moved > 10);
            // Each patch's own factor on its sides instead breaks the invariant:
            // the check can fail.
            for p in &mut patches {
                p.morph.edges = [p.morph.inner; 4];
            }
            let (_, _, broken) = shared_points(&world, &patches, &heights);
            assert!(broken > 0, "own factors on shared sides went unnoticed");
        }
        assert!(levels.len() >= 2, "{levels:?}");
        assert!(lods.len() >= 3, "{lods:?}");
    }

    /// The height `patches` draw at global finest-grid point `(x, y)`, in
    /// [`HEIGHT_UNITS`]: interpolated in the triangle of the patch holding it;
    /// `None` outside them or in a cell along a patch side (where snapping moves
    /// vertices off the grid).
    fn drawn_at(
        world: &World,
        patches: &[Patch],
        heights: &HashMap<TileId, Vec<u16>>,
        (x, y): (u64, u64),
    ) -> Option<f64> {
        let g = &world.geometry;
        for p in patches {
            let (s, x0, y0) = edge_lod::global(world, p);
            let side = 1u64 << s;
            if x < x0 || y < y0 || x > x0 + side || y > y0 + side {
                continue;
            }
            let step = side as f64 / f64::from(p.inner);
            let (u, v) = ((x - x0) as f64 / step, (y - y0) as f64 / step);
            let (i, j) = (
                u.floor().min(f64::from(p.inner - 1)),
                v.floor().min(f64::from(p.inner - 1)),
            );
            let (fx, fy) = (u - i, v - j);
            let (i, j) = (i as u32, j as u32);
            if i == 0 || j == 0 || i + 1 == p.inner || j + 1 == p.inner {
                return None;
            }
            let h = |i, j| f64::from(tessellate::vertex(g, p, &heights[&p.tile], i, j).h);
            // Cells split north-west → south-east.
            return Some(if fx >= fy {
                h(i, j) + fx * (h(i + 1, j) - h(i, j)) + fy * (h(i + 1, j + 1) - h(i + 1, j))
            } else {
                h(i, j) + fy * (h(i, j + 1) - h(i, j)) + fx * (h(i + 1, j + 1) - h(i, j + 1))
            });
        }
        None
    }

    /// The patch of `patches` whose square holds `p`'s.
    fn holder<'a>(world: &World, patches: &'a [Patch], p: &Patch) -> Option<&'a Patch> {
        let (s, x, y) = edge_lod::global(world, p);
        patches.iter().find(|q| {
            let (t, qx, qy) = edge_lod::global(world, q);
            t >= s && x >> t == qx >> t && y >> t == qy >> t
        })
    }

    /// A descent towards the scene: frame `k` of a flight at 20 fps.
    fn descent(yaw: f64, k: u32) -> Camera {
        let mut c = camera(yaw);
        c.position.y *= 0.96f64.powi(k as i32);
        c.position.x += 40.0 * f64::from(k);
        c
    }

    #[test]
    fn a_change_of_selection_starts_as_the_surface_drawn_before_and_stays_crack_free() {
        let (world, tables, heights) = scene();
        let full = u32::from(FULL);
        let (mut new_squares, mut at_full, mut checked) = (0, 0, 0);
        // Over time alone (the default), and with the distance band as well;
        // without the error limit, which cuts a transition short where the old
        // surface is too coarse (tested below).
        for (yaw, morph_by_distance) in [0.3, 1.9, 4.0]
            .into_iter()
            .flat_map(|y| [(y, false), (y, true)])
        {
            let params = SelectParams {
                morph_by_distance,
                morph_error_limit: f64::INFINITY,
                ..SelectParams::default()
            };
            let mut selector = Selector::new(world, params);
            let mut before = selector.select_at(&descent(yaw, 0), &tables, 0.0).patches;
            for k in 1..12 {
                let t = f64::from(k) * 0.05;
                let now = selector.select_at(&descent(yaw, k), &tables, t).patches;
                // Crack-free with transitions in flight.
                let (_, shared, differ) = shared_points(&world, &now, &heights);
                assert_eq!(differ, 0, "{differ} of {shared} shared points differ");
                for p in &now {
                    let Some(q) = holder(&world, &before, p) else {
                        continue;
                    };
                    let (sp, sq) = (edge_lod::global(&world, p), edge_lod::global(&world, q));
                    if (sp, p.inner) == (sq, q.inner) || p.inner < 2 {
                        continue;
                    }
                    // What q drew, if p's grid can draw it (one grid coarser at
                    // most, or its own grid at any factor).
                    let (cp, cq) = (
                        coarseness(sp.0, p.inner, p.morph.inner),
                        coarseness(sq.0, q.inner, q.morph.inner),
                    );
                    let grid = coarseness(sp.0, p.inner, 0);
                    if cq < grid || cq > grid + full {
                        continue;
                    }
                    let hs = &heights[&p.tile];
                    let mut exact = true;
                    for j in 1..p.inner {
                        for i in 1..p.inner {
                            let v = tessellate::vertex(&world.geometry, p, hs, i, j);
                            if let Some(h) = drawn_at(&world, &before, &heights, (v.x, v.y)) {
                                exact &= (f64::from(v.h) - h).abs() < 1e-6;
                                checked += 1;
                            }
                        }
                    }
                    if sp == sq {
                        // The same square: exactly the old surface where the selected
                        // LOD changed, within a step of it where only the drawn grid
                        // moved on.
                        assert!(
                            exact || cp.abs_diff(cq) <= step(&params, 0.05),
                            "frame {k}: {p:?} from {q:?}"
                        );
                    } else {
                        // A split, a merge or a tile refinement: exactly the old
                        // surface.
                        assert!(exact, "frame {k}: {p:?} is not {q:?}");
                        new_squares += 1;
                        at_full += usize::from(cq == grid + full);
                    }
                }
                before = now;
            }
        }
        assert!(
            new_squares > 10 && at_full > 5 && checked > 1000,
            "{new_squares} new squares ({at_full} from one grid coarser), {checked} vertices"
        );
    }

    #[test]
    fn a_transition_never_draws_more_error_than_its_limit_and_goes_up_to_it() {
        // The default limit (τ), and one above it.
        for limit in [SelectParams::default().morph_error_limit, 1.5] {
            limit_holds(limit);
        }
    }

    fn limit_holds(limit: f64) {
        let (world, tables, heights) = scene();
        let capped = SelectParams {
            morph_error_limit: limit,
            ..SelectParams::default()
        };
        let free = SelectParams {
            morph_error_limit: f64::INFINITY,
            ..capped
        };
        let (mut over, mut at_limit, mut refining) = (0, 0, 0);
        for yaw in [0.3, 1.9, 4.0] {
            let (mut a, mut b) = (Selector::new(world, capped), Selector::new(world, free));
            for k in 0..12 {
                // A fast descent: four frames of `descent` per 20 fps frame.
                let (camera, t) = (descent(yaw, 4 * k), f64::from(k) * 0.05);
                let sel = a.select_at(&camera, &tables, t);
                let unlimited = b.select_at(&camera, &tables, t).stats;
                let (selected, drawn) =
                    (sel.stats.max_rho.unwrap(), sel.stats.drawn_max_rho.unwrap());
                assert!(selected <= capped.tau, "frame {k}: selected {selected}");
                assert!(
                    drawn <= limit * capped.tau + 1e-9,
                    "frame {k}: drawn {drawn} over the limit"
                );
                over += usize::from(unlimited.drawn_max_rho.unwrap() > limit * capped.tau);
                let (_, shared, differ) = shared_points(&world, &sel.patches, &heights);
                assert_eq!(differ, 0, "{differ} of {shared} shared points differ");
                // Each refinement in flight (at its selected LOD, slid towards the
                // coarser grid) is within the limit, and where it was cut short it
                // is at the limit: as close to the old surface as the limit lets.
                for (p, chosen) in sel.patches.iter().zip(&sel.chosen) {
                    if p.inner != chosen.inner || p.morph.inner == 0 {
                        continue;
                    }
                    let rho = TileRho::new(
                        &world,
                        p.tile,
                        &tables[&p.tile],
                        camera.position,
                        camera.lambda(),
                        world.max_depth(),
                        capped.policy,
                    );
                    let (k, i, j) = node(&world, p);
                    let l = p.inner.trailing_zeros();
                    let (rn, rh) = (rho.rho(k + l, k, i, j), rho.rho(k + l - 1, k, i, j));
                    let f = f64::from(p.morph.inner) / f64::from(FULL);
                    assert!((1.0 - f) * rn + f * rh <= limit * capped.tau + 1e-9);
                    refining += 1;
                    at_limit += usize::from(
                        p.morph.inner < FULL
                            && p.morph.inner == limit_factor(limit * capped.tau, rn, rh),
                    );
                }
            }
        }
        // Without the limit, transitions drew more; with it, some were cut short
        // and others ran as before.
        assert!(
            over >= 3 && at_limit >= 3 && refining > at_limit,
            "limit {limit}: {over} frames over it without it; {at_limit} of {refining} refinements at it"
        );
    }

    /// The coarseness each patch is drawn at, by its place and size.
    fn drawn(world: &World, patches: &[Patch]) -> HashMap<(TileId, [u32; 2], u32), u32> {
        patches
            .iter()
            .map(|p| {
                let s = edge_lod::global(world, p).0;
                (
                    (p.tile, p.origin, p.size),
                    coarseness(s, p.inner, p.morph.inner),
                )
            })
            .collect()
    }

    #[test]
    fn a_transition_takes_its_time_and_only_moves_as_time_passes() {
        let (world, tables, heights) = scene();
        let params = SelectParams::default();
        let full = u32::from(FULL);
        let dt = params.morph_seconds / 5.0;
        let per_step = step(&params, dt);
        let (mut refined, mut raised, mut drawn_worse) = (0, 0, 0);
        for yaw in [0.3, 1.9, 4.0] {
            let mut selector = Selector::new(world, params);
            selector.select_at(&descent(yaw, 0), &tables, 0.0);
            // The selection changes at t = 1 s, then the camera stays.
            let camera = descent(yaw, 6);
            let t = 1.0;
            // The targets: selection's LODs at their distance factors, for the
            // same layout (no clock: no transition).
            let target = drawn(&world, &selector.clone().select(&camera, &tables).patches);
            let sel = selector.select_at(&camera, &tables, t);
            let first = drawn(&world, &sel.patches);
            // The error of the surface as drawn is never below that of the
            // selected LODs, and a refinement's transition shows in it.
            let (selected, as_drawn) =
                (sel.stats.max_rho.unwrap(), sel.stats.drawn_max_rho.unwrap());
            assert!(as_drawn >= selected, "{as_drawn} < {selected}");
            drawn_worse += usize::from(as_drawn > selected);
            assert_eq!(
                first.keys().collect::<HashSet<_>>(),
                target.keys().collect()
            );
            // Selecting again at the same time (a settled frame) changes nothing.
            let again = selector.select_at(&camera, &tables, t).patches;
            assert_eq!(drawn(&world, &again), first);
            let (_, _, differ) = shared_points(&world, &again, &heights);
            assert_eq!(differ, 0);
            refined += first.iter().filter(|&(k, &c)| c > target[k]).count();
            raised += first.iter().filter(|&(k, &c)| c < target[k]).count();
            let mut last = first.clone();
            let mut arrived: HashMap<_, u32> = first
                .iter()
                .filter(|&(k, &c)| c == target[k])
                .map(|(k, _)| (*k, 0))
                .collect();
            for n in 1..=20 {
                let at = t + f64::from(n) * dt;
                let sel = selector.select_at(&camera, &tables, at);
                if n == 20 {
                    // Every transition done: the surface drawn is the one selected.
                    assert_eq!(sel.stats.drawn_max_rho, sel.stats.max_rho);
                }
                let now = drawn(&world, &sel.patches);
                assert_eq!(
                    drawn(&world, &selector.select_at(&camera, &tables, at).patches),
                    now
                );
                for (k, &c) in &now {
                    // Towards the target, never past it.
                    let (goal, was) = (target[k], last[k]);
                    assert!(
                        c == goal
                            || (c.abs_diff(goal) < was.abs_diff(goal)
                                && (c > goal) == (was > goal)),
                        "{k:?} at step {n}: {was} → {c}, target {goal}"
                    );
                    if c == goal {
                        arrived.entry(*k).or_insert(n);
                    }
                }
                last = now;
            }
            assert_eq!(last, target, "not at the targets after 4 durations");
            for (k, &c) in &first {
                // One grid per duration, in steps of a fifth of it (rounded up):
                // a refinement by one grid arrives by the end of the duration,
                // and nothing arrives before its steps are done.
                let away = c.abs_diff(target[k]);
                let n = arrived[k];
                assert_eq!(n, away.div_ceil(per_step), "{k:?}: {c} → {}", target[k]);
                assert!(away > full || n <= 5, "{k:?}: {n} steps");
            }
        }
        // Both kinds were exercised: refinements (coming down from above) and
        // raised patches (coming up from below).
        assert!(
            refined >= 5 && raised >= 5 && drawn_worse >= 1,
            "{refined} refinements, {raised} raised, {drawn_worse} frames drawn worse than selected"
        );
    }

    #[test]
    fn steps_cross_a_grid_in_the_duration_and_stand_still_without_time() {
        let p = SelectParams::default();
        let full = u32::from(FULL);
        assert_eq!(step(&p, 0.0), 0);
        assert_eq!(step(&p, -1.0), 0);
        assert_eq!(step(&p, p.morph_seconds), full);
        assert_eq!(step(&p, 2.0 * p.morph_seconds), 2 * full);
        assert!(step(&p, p.morph_seconds / 4.0) * 4 >= full);
        assert!(step(&p, p.morph_seconds / 4.0) < full / 2);
        let off = SelectParams {
            morph_seconds: 0.0,
            ..p
        };
        assert_eq!(step(&off, 0.0), u32::MAX);
        assert!(!off.transitions());
        assert_eq!(coarseness(10, 64, 0), 4 * full);
        assert_eq!(coarseness(10, 64, FULL), coarseness(10, 32, 0));
    }

    #[test]
    fn the_factor_is_one_and_zero_where_selection_switches_and_keeps_tau() {
        let h = 0.15;
        let f = |rn: f64, rh: Option<f64>| patch_factor(1.0, h, rn, rh);
        // n = 1 has nothing coarser.
        assert_eq!(f(0.5, None), 0);
        // n/2 meets τ (selection switches there, or keeps n by hysteresis): n/2.
        assert_eq!(f(0.2, Some(1.0)), FULL);
        assert_eq!(f(0.2, Some(0.9)), FULL);
        // n is about to be refined (where 2n, had it been drawn, is at 0): n.
        assert!(f(0.85, Some(3.0)) < FULL / 8);
        assert_eq!(f(1.0, Some(1.05)), 0);
        assert_eq!(f(1.2, Some(3.0)), 0);
        // Errors too close for both zones (0.9 > 1 − h): from 1 to 0 between the
        // switches coming closer.
        assert!(f(0.9, Some(1.01)) > FULL * 8 / 10);
        assert!(f(0.99, Some(1.1)) < FULL / 8);
        assert_eq!(f(f64::INFINITY, Some(f64::INFINITY)), 0);
        assert_eq!(f(0.0, Some(f64::NAN)), 0);
        // In between: strictly inside, falling as the eye comes closer (ρ ∝ 1/d,
        // errors 1 and 3), and the mixed bound within τ.
        let mut last = FULL;
        for k in 1..60 {
            let x = 1.0 / 3.0 + f64::from(k) * (0.85 - 1.0 / 3.0) / 60.0;
            let m = f(x, Some(3.0 * x));
            assert!(m <= last && m < FULL, "{x}: {m}");
            let g = f64::from(m) / f64::from(FULL);
            assert!((1.0 - g) * x + g * 3.0 * x <= 1.0 + 1e-12, "{x}: {g}");
            last = m;
        }
        assert!(last < FULL / 8, "{last}");
        assert!(f(0.34, Some(1.02)) > FULL * 9 / 10);
    }

    #[test]
    fn the_limit_factor_keeps_the_mixed_bound_within_the_limit() {
        assert_eq!(limit_factor(2.0, 0.5, 2.0), FULL);
        assert_eq!(limit_factor(2.0, 2.0, 5.0), 0);
        assert_eq!(limit_factor(2.0, f64::NAN, 5.0), 0);
        assert_eq!(limit_factor(2.0, 0.5, f64::INFINITY), 0);
        assert_eq!(limit_factor(f64::INFINITY, 0.5, 1e300), FULL);
        // Half-way: 1 + ½·(3 − 1) = 2.
        assert_eq!(limit_factor(2.0, 1.0, 3.0), FULL / 2);
        for (rn, rh) in [(0.3, 2.5), (0.9, 7.0), (1.99, 2.01)] {
            let f = limit_factor(2.0, rn, rh);
            let mixed = |f: u16| {
                let f = f64::from(f) / f64::from(FULL);
                (1.0 - f) * rn + f * rh
            };
            assert!(f < FULL && mixed(f) <= 2.0, "{rn} {rh}: {f}");
            assert!(mixed(f + 1) > 2.0, "{rn} {rh}: {f} is not the largest");
        }
    }

    #[test]
    fn heights_mix_exactly() {
        assert_eq!(mix(100, 7, 9, 0), 100 * HEIGHT_UNITS);
        assert_eq!(mix(100, 40, 60, FULL), 50 * HEIGHT_UNITS);
        assert_eq!(mix(100, 40, 61, FULL), 101 * FULL as u32);
        assert_eq!(mix(0, 0, 65535, FULL / 2), 65535 * 128);
        assert_eq!(mix(65535, 65535, 65535, 17), 65535 * HEIGHT_UNITS);
        assert!(Morph::new(FULL, [0, FULL, 3, 4]).is_some());
        assert!(Morph::new(FULL + 1, [0; 4]).is_none());
        assert!(Morph::new(0, [0, 0, 0, 300]).is_none());
    }
}
