//! Geomorphing (CDLOD, Strugar 2009; Kang §4.4): how far each patch has slid from
//! its own inner LOD `n` towards the `n/2` grid, so that a change of LOD is a
//! continuous motion instead of a jump.
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
//! **Edges** (DESIGN §6 invariant 3 at every factor): a vertex on a patch side is
//! shared with the patches across it, so its factor must be something both sides
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
//! **Tiles and their children**: a child tile's level `m` grid is its parent's
//! level `m + 1` grid, on the same samples (the pyramid decimates), so a child
//! patch at factor 1 is its parent's surface one level coarser; and since factors
//! come from the errors of the surface drawn and the distance, the same surface
//! gets about the same factor on either side of a refinement.

use super::metric::TileRho;
use super::{Patch, SelectParams, World, edge_lod};
use std::collections::HashMap;
use tessera_shared::TileId;

/// A factor of 1: the surface is the `n/2` surface. Factors are integers in
/// `0..=FULL`, so that mixing heights is exact integer arithmetic.
pub const FULL: u16 = 256;

/// How far a patch has morphed: its interior, and each side (north, east, south,
/// west), in `1/FULL` steps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Morph {
    pub inner: u16,
    pub edges: [u16; 4],
}

impl Morph {
    /// No morphing: every vertex at its own LOD's height (`--no-morph`).
    pub const NONE: Self = Self {
        inner: 0,
        edges: [0; 4],
    };

    /// A morph with every factor in `0..=FULL`; `None` otherwise.
    pub fn new(inner: u16, edges: [u16; 4]) -> Option<Self> {
        (inner <= FULL && edges.iter().all(|&e| e <= FULL)).then_some(Self { inner, edges })
    }
}

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
    if rho_half <= tau {
        return FULL;
    }
    // n itself misses τ (selection refines it, or it is forced), or NaN: as itself.
    if rho_n.is_nan() || rho_half.is_nan() || rho_n >= tau {
        return 0;
    }
    // Here ρ_n < τ < ρ_{n/2}: in (0, 1).
    let keeps_tau = (tau - rho_n) / (rho_half - rho_n);
    let (u, v) = (rho_n / (tau * (1.0 - hysteresis)), rho_half / tau);
    // Whether the two hysteresis zones are apart (ε_n < (1 − h)·ε_{n/2}): a ratio
    // of errors, the same at any distance, so the choice never flips as the eye
    // moves.
    let f = if rho_n < (1.0 - hysteresis) * rho_half {
        // Then u < v, and the band runs from 1 (v = 1) to 0 (u = 1).
        keeps_tau.min(v * (1.0 - u) / (v - u)).max(0.0)
    } else {
        // They overlap: no factor suits both; LOD n lives only between
        // ρ_{n/2} = τ and ρ_n = τ coming closer, and the cap alone runs from 1 to
        // 0 across exactly that.
        keeps_tau
    };
    (f * f64::from(FULL)).floor().clamp(0.0, f64::from(FULL)) as u16
}

/// Depth `k` and node `(i, j)` of a patch in its tile's quadtree.
fn node(world: &World, p: &Patch) -> (u32, u32, u32) {
    let k = (world.geometry.tile_size() / p.size).trailing_zeros();
    (k, p.origin[0] / p.size, p.origin[1] / p.size)
}

/// Sets every patch's [`Morph`], after the edge LODs are final
/// ([`edge_lod::assign`]); `rhos` are this frame's `ρ` tables of the drawn tiles.
pub fn assign(
    world: &World,
    params: &SelectParams,
    patches: &mut [Patch],
    rhos: &HashMap<TileId, TileRho>,
) {
    for p in patches.iter_mut() {
        let f = match rhos.get(&p.tile) {
            Some(rho) => {
                let (k, i, j) = node(world, p);
                let l = p.inner.trailing_zeros();
                let half = (l > 0).then(|| rho.rho(k + l - 1, k, i, j));
                patch_factor(params.tau, params.hysteresis, rho.rho(k + l, k, i, j), half)
            }
            None => 0,
        };
        p.morph.inner = f;
    }
    share_edges(world, patches);
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
        for yaw in [0.3, 1.9, 4.0] {
            let mut selector = Selector::new(world, SelectParams::default());
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
