//! Screen-space error (docs/ARCHITECTURE.md#selection, Yang §4.2): `ρ = ε·λ/d`, with `d`
//! the distance from the eye to the block's cuboid (its min/max height box, widened by
//! `ε`).
//!
//! For one tile and one frame, [`TileRho`] holds `ρ` for every within-tile level and
//! every 8×8 block, max-pooled up the tile's quadtree, so choosing a node's inner
//! LOD is a handful of lookups. Level `m`'s value bounds every level `≥ m` too.

use super::params::Policy;
use super::world::World;
use glam::DVec3;
use tessera_shared::tile::BLOCKS;
use tessera_shared::{ErrorTable, TileId};

/// The tile's box in world space, `None` when every block is empty (beyond the DEM).
/// Heights are widened by the largest error of any level, so the box holds whatever
/// mesh is drawn.
pub fn tile_box(world: &World, tile: TileId, table: &ErrorTable) -> Option<(DVec3, DVec3)> {
    let (qmin, qmax) = table.tile_range();
    if qmin > qmax {
        return None;
    }
    let eps = (0..=table.tile_log2())
        .flat_map(|n| table.level_errors(n).iter().copied())
        .fold(0f32, f32::max);
    let (origin, size) = world.tile_extent(tile);
    Some((
        DVec3::new(
            origin.x,
            world.quant.height(qmin) - f64::from(eps),
            origin.y,
        ),
        DVec3::new(
            origin.x + size.x,
            world.quant.height(qmax) + f64::from(eps),
            origin.y + size.y,
        ),
    ))
}

/// `ρ` per within-tile level `m` and quadtree node, for one tile and one eye.
#[derive(Clone, Debug)]
pub struct TileRho {
    /// `levels × nodes`, nodes numbered depth-first by depth: depth `k` starts at
    /// `(4^k − 1)/3`, row-major within the depth.
    rho: Vec<f64>,
    nodes: usize,
    /// Depths with one node per block or coarser (`≤ 3`).
    block_depth: u32,
    max_depth: u32,
}

/// Index of node `(k, i, j)` in a depth-major layout.
pub const fn node_index(k: u32, i: u32, j: u32) -> usize {
    (((1usize << (2 * k)) - 1) / 3) + (j as usize) * (1usize << k) + i as usize
}

impl TileRho {
    /// `max_depth`: the deepest quadtree level that will be asked about.
    pub fn new(
        world: &World,
        tile: TileId,
        table: &ErrorTable,
        eye: DVec3,
        lambda: f64,
        max_depth: u32,
        policy: Policy,
    ) -> Self {
        let t = table.tile_log2();
        let block_depth = BLOCKS.trailing_zeros().min(max_depth);
        let nodes = node_index(block_depth + 1, 0, 0);
        let levels = t as usize + 1;
        let mut rho = vec![0f64; levels * nodes];
        let (origin, size) = world.tile_extent(tile);
        // A block's size east–west and north–south.
        let bsz = size / f64::from(BLOCKS);
        // The cuboid of each block, widened by its largest error over all levels
        // (conservative: a nearer box can only raise ρ).
        let mut inv_d = [0f64; 64];
        let distance = world.distances_from(eye);
        for by in 0..BLOCKS {
            for bx in 0..BLOCKS {
                let (qmin, qmax) = table.block_range(bx, by);
                let i = (by * BLOCKS + bx) as usize;
                if qmin > qmax {
                    continue; // empty block: beyond the DEM, nothing drawn
                }
                let eps = (0..=t).map(|n| table.error(n, bx, by)).fold(0f32, f32::max);
                let min = DVec3::new(
                    origin.x + f64::from(bx) * bsz.x,
                    world.quant.height(qmin) - f64::from(eps),
                    origin.y + f64::from(by) * bsz.y,
                );
                let max = DVec3::new(
                    min.x + bsz.x,
                    world.quant.height(qmax) + f64::from(eps),
                    min.z + bsz.y,
                );
                // With the eye inside the box, `ε·λ/d` has no bound: infinite, not the
                // 1e12-odd a clamped distance would make of it (reported as missing, not
                // as a huge number: docs/ARCHITECTURE.md#the-client-never-goes-blind).
                // Comparisons with τ are unchanged.
                let d = distance.to(min, max);
                inv_d[i] = if d > 0.0 { 1.0 / d } else { f64::INFINITY };
            }
        }
        let fine = BLOCKS.trailing_zeros(); // depth of one block per node
        // Errors are not monotonic in mesh spacing (a finer mesh can miss a bump a
        // coarser one happens to hit), and the edge pass may raise an inner LOD; so
        // level m is judged by the largest error of m and every finer level.
        let mut suffix = [0f64; 64];
        for m in (0..=t).rev() {
            match policy {
                Policy::ScreenError => {
                    for (s, e) in suffix.iter_mut().zip(table.level_errors(m)) {
                        *s = s.max(f64::from(*e));
                    }
                }
                // The brute-force policy Kang compares against (González Fig. 2):
                // detail from distance alone, as if every cell were off by its own
                // size (its longer side where cells are not square), whatever the
                // terrain does.
                Policy::Distance => suffix = [size.max_element() / f64::from(1u32 << m); 64],
            }
            let base = m as usize * nodes;
            // On the globe a mesh of level m also misses the curved surface by the
            // sag of its cells' chords, `s²/8R` for a cell diagonal `s` (the body's
            // polar radius: the smaller, the more sag); the error tables only hold
            // heights' errors. Errors are against the finest mesh, whose own chords
            // sag by `f²/8R` for the finest cell `f`: the excess is `(s² − f²)/8R`,
            // 0 for the finest mesh, which is then exact wherever the eye is (with
            // the eye inside a block's box, any error at all makes ρ infinite).
            let sag = match (&world.globe, policy) {
                (Some(g), Policy::ScreenError) => {
                    let cell = size.length() / f64::from(1u32 << m);
                    let fine = world.spacing.length();
                    let excess = cell * cell - fine * fine;
                    if excess <= 1e-9 * fine * fine {
                        0.0
                    } else {
                        excess / (8.0 * g.ellipsoid.polar_radius())
                    }
                }
                _ => 0.0,
            };
            // Blocks at depth `fine`, then pool up to the root.
            let mut grid: Vec<f64> = (0..64)
                .map(|i| {
                    if suffix[i] + sag == 0.0 || inv_d[i] == 0.0 {
                        0.0
                    } else {
                        (suffix[i] + sag) * lambda * inv_d[i]
                    }
                })
                .collect();
            let mut side = BLOCKS;
            for k in (0..=fine).rev() {
                if k <= block_depth {
                    for j in 0..side {
                        for i in 0..side {
                            rho[base + node_index(k, i, j)] = grid[(j * side + i) as usize];
                        }
                    }
                }
                if k > 0 {
                    let half = side / 2;
                    grid = (0..half * half)
                        .map(|c| {
                            let (i, j) = (c % half, c / half);
                            let g = |a: u32, b: u32| grid[(b * side + a) as usize];
                            g(2 * i, 2 * j)
                                .max(g(2 * i + 1, 2 * j))
                                .max(g(2 * i, 2 * j + 1))
                                .max(g(2 * i + 1, 2 * j + 1))
                        })
                        .collect();
                    side = half;
                }
            }
        }
        Self {
            rho,
            nodes,
            block_depth,
            max_depth,
        }
    }

    /// `ρ` of node `(k, i, j)` drawn at within-tile level `m`. Nodes smaller than a
    /// block use their block's value (conservative).
    pub fn rho(&self, m: u32, k: u32, i: u32, j: u32) -> f64 {
        debug_assert!(k <= self.max_depth);
        let (k, i, j) = if k > self.block_depth {
            let s = k - self.block_depth;
            (self.block_depth, i >> s, j >> s)
        } else {
            (k, i, j)
        };
        self.rho[m as usize * self.nodes + node_index(k, i, j)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::{Level, Quantization, TileGeometry};

    /// One 512-cell root tile of 10 m cells, heights stored exactly.
    fn root_world() -> World {
        World {
            geometry: TileGeometry::new(513, 513, 512).unwrap(),
            quant: Quantization {
                offset: 0.0,
                scale: 1.0,
                max_error: 0.0,
            },
            spacing: glam::DVec2::splat(10.0),
            globe: None,
        }
    }

    #[test]
    fn an_eye_inside_a_block_box_has_no_bound_except_at_zero_error() {
        let world = root_world();
        let tile = TileId::new(Level::ROOT, 0, 0).unwrap();
        let mut table = ErrorTable::empty(9);
        for n in 0..=9 {
            for b in 0..64 {
                table.set_error(n, b % 8, b / 8, if n == 9 { 0.0 } else { 5.0 });
                table.set_block_range(b % 8, b / 8, 100, 200);
            }
        }
        let inside = DVec3::new(2560.0, 150.0, 2560.0);
        let rho = TileRho::new(&world, tile, &table, inside, 1000.0, 3, Policy::ScreenError);
        for m in 0..9 {
            assert_eq!(rho.rho(m, 0, 0, 0), f64::INFINITY, "level {m}");
        }
        // Full resolution is exact: no error, whatever the distance.
        assert_eq!(rho.rho(9, 0, 0, 0), 0.0);
        // Just above the box, the bound is finite again: ε·λ/d.
        let above = DVec3::new(2560.0, 205.0 + 1.0, 2560.0);
        let rho = TileRho::new(&world, tile, &table, above, 1000.0, 3, Policy::ScreenError);
        assert!((rho.rho(0, 0, 0, 0) - 5.0 * 1000.0 / 1.0).abs() < 1e-6);
    }

    #[test]
    fn on_the_globe_the_finest_mesh_is_exact_and_coarser_ones_sag() {
        // The same 512-cell root tile, 1″ cells in the Alps on WGS 84.
        let spacing = glam::DVec2::new(21.1, 30.9);
        let world = World {
            globe: Some(crate::globe::fixtures::alps(3600.0, spacing)),
            spacing,
            ..root_world()
        };
        let tile = TileId::new(Level::ROOT, 0, 0).unwrap();
        let mut table = ErrorTable::empty(9);
        for n in 0..=9 {
            for b in 0..64 {
                table.set_error(n, b % 8, b / 8, 0.0);
                table.set_block_range(b % 8, b / 8, 100, 200);
            }
        }
        // The eye inside a block's box: the finest mesh has no error against
        // itself, so ρ is 0 there, not infinite (a canyon flight on the globe
        // reported every frame "missing" when the finest mesh was charged its own
        // chords' sag).
        let inside = DVec3::new(5400.0, 150.0, 7900.0);
        let rho = TileRho::new(&world, tile, &table, inside, 1000.0, 3, Policy::ScreenError);
        assert_eq!(rho.rho(9, 0, 0, 0), 0.0);
        assert_eq!(rho.rho(8, 0, 0, 0), f64::INFINITY);
        // From above, coarser meshes miss the curve by their chords' excess sag
        // even where the heights are exact: (s² − f²)/8R, seen from ≤ 2 km.
        let above = DVec3::new(5400.0, 2200.0, 7900.0);
        let rho = TileRho::new(&world, tile, &table, above, 1000.0, 3, Policy::ScreenError);
        let f = world.spacing.length();
        for m in [0u32, 4, 8] {
            let s = f * f64::from(1u32 << (9 - m));
            let sag = (s * s - f * f) / (8.0 * 6_356_752.314_245);
            assert!(rho.rho(m, 0, 0, 0) >= sag * 1000.0 / 2000.0, "level {m}");
        }
        assert_eq!(rho.rho(9, 0, 0, 0), 0.0);
    }

    #[test]
    fn the_distance_policy_ignores_roughness_and_the_error_policy_does_not() {
        let world = root_world();
        let tile = TileId::new(Level::ROOT, 0, 0).unwrap();
        let table = |err: f32| {
            let mut t = ErrorTable::empty(9);
            for n in 0..=9 {
                for b in 0..64 {
                    t.set_error(n, b % 8, b / 8, if n == 9 { 0.0 } else { err });
                    t.set_block_range(b % 8, b / 8, 100, 200);
                }
            }
            t
        };
        let (flat, rough) = (table(0.1), table(50.0));
        let eye = DVec3::new(2560.0, 3000.0, 2560.0);
        let rho = |t: &ErrorTable, p| TileRho::new(&world, tile, t, eye, 1000.0, 3, p);
        let (fe, re) = (
            rho(&flat, Policy::ScreenError),
            rho(&rough, Policy::ScreenError),
        );
        let (fd, rd) = (rho(&flat, Policy::Distance), rho(&rough, Policy::Distance));
        for m in 0..9 {
            assert!(re.rho(m, 0, 0, 0) > 100.0 * fe.rho(m, 0, 0, 0));
            // Distance: only the boxes differ (the rough one widened 50 m towards
            // the eye, ~2.8 km away), so ρ differs by a couple of percent at most.
            let ratio = rd.rho(m, 0, 0, 0) / fd.rho(m, 0, 0, 0);
            assert!((1.0..1.03).contains(&ratio), "level {m}: {ratio}");
            // A cell of 2^(9−m) samples of 10 m, seen from ~2.7 km by λ = 1000.
            assert!(fd.rho(m, 0, 0, 0) >= 5120.0 / f64::from(1u32 << m) * 1000.0 / 3100.0);
            // Finer levels always have smaller cells.
            assert!(fd.rho(m + 1, 0, 0, 0) < fd.rho(m, 0, 0, 0));
        }
    }
}
