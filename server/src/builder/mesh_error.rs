//! Exact mesh errors of one finest tile, for every mesh spacing (Kang §4.1).
//!
//! Within-tile level `n` of a level-`L` tile is the global mesh with cells of
//! `2^k` finest samples, `k = t − n + L_max − L` (decimation makes every level's
//! meshes sub-meshes of one global family). So a finest tile can measure, for
//! every `k` from 0 up to the root's coarsest mesh, the largest vertical distance
//! between the `2^k` mesh and its own samples in each of its 8×8 blocks; a coarse
//! tile's table is then the maximum over the blocks of its finest descendants.
//! That makes the tables exact maxima against the finest data (tight,
//! docs/ARCHITECTURE.md#exact-error-tables) while every finest sample is read once.
//!
//! Errors are kept in quantization steps as `f64`: `|s·z − s·q| / s` with integer
//! numerator and power-of-two `s` is exact.

use tessera_shared::tile::BLOCKS;

/// Per-block maxima for every mesh spacing `k`: `values[k · 64 + by · 8 + bx]`.
#[derive(Clone, Debug, PartialEq)]
pub struct BlockErrors {
    pub values: Vec<f64>,
}

impl BlockErrors {
    pub fn zeros(spacings: usize) -> Self {
        Self {
            values: vec![0.0; spacings * (BLOCKS * BLOCKS) as usize],
        }
    }

    pub fn get(&self, k: u32, bx: u32, by: u32) -> f64 {
        self.values[(k * BLOCKS * BLOCKS + by * BLOCKS + bx) as usize]
    }

    pub fn slot_mut(&mut self, k: u32, bx: u32, by: u32) -> &mut f64 {
        &mut self.values[(k * BLOCKS * BLOCKS + by * BLOCKS + bx) as usize]
    }

    /// Pools a child's blocks into this (parent) table: child quadrant `(qx, qy)`'s
    /// block `(cbx, cby)` lies in parent block `(4qx + cbx/2, 4qy + cby/2)`.
    pub fn pool_child(&mut self, child: &BlockErrors, qx: u32, qy: u32) {
        let spacings = self.values.len() / (BLOCKS * BLOCKS) as usize;
        for k in 0..spacings as u32 {
            for cby in 0..BLOCKS {
                for cbx in 0..BLOCKS {
                    let v = child.get(k, cbx, cby);
                    let s = self.slot_mut(k, qx * BLOCKS / 2 + cbx / 2, qy * BLOCKS / 2 + cby / 2);
                    *s = s.max(v);
                }
            }
        }
    }
}

/// The corner heights of the coarse mesh cells (spacing `2^k > T`) that enclose one
/// finest tile: `cells[k − t − 1]` is `[top-left, top-right, bottom-left, bottom-right]`.
///
/// Read per tile from the raster rather than kept as a grid over the whole DEM, so
/// the build's memory does not grow with the DEM's area (`--memory` bounds every
/// allocation: docs/ARCHITECTURE.md#bad-input-is-an-error).
#[derive(Clone, Debug, Default)]
pub struct CoarseCorners {
    pub cells: Vec<[u16; 4]>,
}

/// Largest vertical error of each spacing `k = 0..spacings` over each 8×8 block
/// (closed sample ranges) of a finest tile whose first sample is at global `(gx0, gy0)`.
pub fn finest_tile_errors(
    heights: &[u16],
    tile_log2: u32,
    gx0: u64,
    gy0: u64,
    corners: &CoarseCorners,
    spacings: u32,
) -> BlockErrors {
    finest_tile_errors_at(heights, tile_log2, gx0, gy0, corners, spacings, |_| true)
}

/// [`finest_tile_errors`] for the spacings `k` that `wanted` accepts only (the others
/// are left 0): what `build --update` measures again for a tile whose samples did not
/// change but some of whose coarse cells' corners did.
pub fn finest_tile_errors_at(
    heights: &[u16],
    tile_log2: u32,
    gx0: u64,
    gy0: u64,
    corners: &CoarseCorners,
    spacings: u32,
    wanted: impl Fn(u32) -> bool,
) -> BlockErrors {
    let t = 1usize << tile_log2;
    let side = t + 1;
    let block = t / BLOCKS as usize;
    let mut out = BlockErrors::zeros(spacings as usize);
    let mut row = vec![0f64; side];
    let h = |u: usize, v: usize| f64::from(heights[v * side + u]);
    // k = 0 is the data itself: error 0.
    for k in (1..spacings).filter(|&k| wanted(k)) {
        let s = 1usize << k;
        let sf = s as f64;
        for v in 0..side {
            if s <= t {
                // Cells inside the tile; the last row/column belongs to the last cell.
                let cy = (v / s).min(t / s - 1);
                let b = (v - cy * s) as f64;
                for cx in 0..t / s {
                    let (u0, v0) = (cx * s, cy * s);
                    let cell = [h(u0, v0), h(u0 + s, v0), h(u0, v0 + s), h(u0 + s, v0 + s)];
                    let end = if cx + 1 == t / s { s + 1 } else { s };
                    cell_row_errors(&cell, sf, b, 0.0, v, u0, end, heights, side, &mut row);
                }
            } else {
                // One coarse cell holds the whole tile; its corners were read for it.
                let cell = corners.cells[(k - tile_log2 - 1) as usize].map(f64::from);
                let a0 = (gx0 % s as u64) as f64;
                let b = (gy0 % s as u64 + v as u64) as f64;
                cell_row_errors(&cell, sf, b, a0, v, 0, side, heights, side, &mut row);
            }
            // Reduce the row into blocks; border samples count in both blocks.
            let by_hi = (v / block).min(BLOCKS as usize - 1);
            let by_lo = if v > 0 && v % block == 0 {
                v / block - 1
            } else {
                by_hi
            };
            for bx in 0..BLOCKS as usize {
                let m = row[bx * block..=(bx + 1) * block]
                    .iter()
                    .copied()
                    .fold(0.0, f64::max);
                for by in by_lo..=by_hi {
                    let s = out.slot_mut(k, bx as u32, by as u32);
                    *s = s.max(m);
                }
            }
        }
    }
    out
}

/// Errors of samples `u0..u0+len` of row `v` against one cell `[q00, q10, q01, q11]`
/// of size `s`, where sample `u0` sits at offset `a0` across the cell and row `v` at `b`.
/// Same planes as [`tessera_shared::triangulation::Cell::scaled_height`], in `f64`
/// (exact for these integers).
#[allow(clippy::too_many_arguments)]
#[inline]
fn cell_row_errors(
    cell: &[f64; 4],
    s: f64,
    b: f64,
    a0: f64,
    v: usize,
    u0: usize,
    len: usize,
    heights: &[u16],
    side: usize,
    row: &mut [f64],
) {
    let [q00, q10, q01, q11] = *cell;
    // a ≥ b: s·z = s·q00 + (q10 − q00)·a + (q11 − q10)·b
    let (base_ne, slope_ne) = (s * q00 + (q11 - q10) * b, q10 - q00);
    // a < b: s·z = s·q00 + (q11 − q01)·a + (q01 − q00)·b
    let (base_sw, slope_sw) = (s * q00 + (q01 - q00) * b, q11 - q01);
    let src = &heights[v * side + u0..v * side + u0 + len];
    let dst = &mut row[u0..u0 + len];
    // Split at a = b so each part is one straight loop the compiler can vectorise.
    let split = ((b - a0).max(0.0) as usize).min(len);
    for (i, (d, q)) in dst[..split].iter_mut().zip(&src[..split]).enumerate() {
        let a = a0 + i as f64;
        *d = (base_sw + slope_sw * a - s * f64::from(*q)).abs() / s;
    }
    for (i, (d, q)) in dst[split..].iter_mut().zip(&src[split..]).enumerate() {
        let a = a0 + (split + i) as f64;
        *d = (base_ne + slope_ne * a - s * f64::from(*q)).abs() / s;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::triangulation::Cell;

    /// Brute force over one tile with the reference planes: the fast path must give
    /// the same maxima for every spacing inside the tile.
    #[test]
    fn fast_path_equals_reference_inside_a_tile() {
        let tile_log2 = 6;
        let t = 64usize;
        let side = t + 1;
        // Rough deterministic heights with big jumps (tests both triangles hard).
        let heights: Vec<u16> = (0..side * side)
            .map(|i| ((i * 2_654_435_761usize) % 997 + (i % side) * 13) as u16)
            .collect();
        let corners = CoarseCorners::default();
        let fast = finest_tile_errors(&heights, tile_log2, 0, 0, &corners, 7);
        let block = t / 8;
        for k in 1..7u32 {
            let s = 1usize << k;
            for by in 0..8 {
                for bx in 0..8 {
                    let mut m = 0f64;
                    for v in by * block..=(by + 1) * block {
                        for u in bx * block..=(bx + 1) * block {
                            let cx = (u / s).min(t / s - 1);
                            let cy = (v / s).min(t / s - 1);
                            let g = |uu: usize, vv: usize| i64::from(heights[vv * side + uu]);
                            let cell = Cell {
                                q00: g(cx * s, cy * s),
                                q10: g(cx * s + s, cy * s),
                                q01: g(cx * s, cy * s + s),
                                q11: g(cx * s + s, cy * s + s),
                            };
                            let e = cell.vertical_error(
                                s as i64,
                                (u - cx * s) as i64,
                                (v - cy * s) as i64,
                                g(u, v),
                            );
                            m = m.max(e);
                        }
                    }
                    assert_eq!(
                        fast.get(k, bx as u32, by as u32),
                        m,
                        "k {k} block ({bx},{by})"
                    );
                }
            }
        }
        assert!(fast.values[..64].iter().all(|v| *v == 0.0));
    }
}
