//! A height read from one pyramid level, and how far it can be from the same
//! interpolation of the finest data (API.md "Elevation queries", DECISIONS.md
//! "Elevation queries: the error bound").
//!
//! Level `L` keeps every `s = 2^k`-th finest sample (decimation, so its samples are
//! finest samples). Its error table says, per 8 × 8 block of each tile, how far its
//! *triangulated* surface `T_L` (each cell split north-west to south-east) is from
//! every finest sample in the block: `|T_L(c) − f(c)| ≤ E(c)`. The answer the
//! finest data would give at a point `p` is `Σ wᵢ f(cᵢ)` over the finest samples `cᵢ`
//! the kernel reads, so it lies within `Σ wᵢ T_L(cᵢ) ± Σ |wᵢ| E(cᵢ)`, and the level's
//! own answer `I_L(p)` is within
//!
//! ```text
//! |I_L(p) − Σ wᵢ T_L(cᵢ)| + Σ |wᵢ| (E(cᵢ) + q)
//! ```
//!
//! of the source DEM interpolated the same way, where `q` is the dataset's
//! quantization error (stored heights are within `q` of the input's). The first
//! term is computed exactly from the level's own samples; only the error table's
//! block maxima make the bound loose, and where a block's worst sample is read the
//! bound is met. At the finest level (`k = 0`) it is `Σ |wᵢ| q`.

use super::kernel::{Interpolation, Stencil};
use crate::web::resample::SourceTile;
use std::cell::Cell;
use tessera_shared::Quantization;

/// Added to every bound: the floating-point arithmetic of the two interpolations
/// and the answers' rounding to micrometres (elevation/output.rs), ten micrometres
/// in all, far below any DEM's precision.
pub const ROUNDING: f64 = 1e-5;

/// A level's grid: stride `2^k` finest samples, tiles of `t` cells, `n` tiles a side.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelGrid {
    /// `log₂` of the level's stride in finest samples.
    pub k: u32,
    /// Cells per tile side.
    pub t: u32,
    /// Tiles per side.
    pub n: u32,
}

/// One level of the pyramid as far as a point needs it.
pub struct LevelView<'a> {
    pub grid: LevelGrid,
    /// The tile `(x, y)` of the level, if stored and loaded.
    pub tile: &'a dyn Fn(u32, u32) -> Option<&'a SourceTile>,
    /// The tile the last sample came from: most reads fall in it (a quarter of a
    /// 100-point request's time went to looking tiles up).
    last_tile: Cell<Option<(i64, i64, &'a SourceTile)>>,
}

impl std::fmt::Debug for LevelView<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LevelView")
            .field("grid", &self.grid)
            .finish_non_exhaustive()
    }
}

/// A height and its bound.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Evaluated {
    /// Metres, in the dataset's vertical datum.
    pub value: f64,
    /// Metres: the most the value can differ from the source DEM interpolated the
    /// same way at the point (module doc).
    pub bound: f64,
}

/// The tiles that hold sample `i` of an axis of `n` tiles of `span` samples (two on
/// a shared border: the one before first).
fn owners(i: i64, span: i64, n: u32) -> [Option<u32>; 2] {
    let last = i64::from(n) - 1;
    let before = ((i - 1).max(0) / span).min(last);
    let after = (i / span).min(last);
    [
        Some(before as u32),
        (after != before).then_some(after as u32),
    ]
}

impl LevelGrid {
    /// The last sample index of the level's (padded) grid.
    pub fn last(&self) -> i64 {
        i64::from(self.n) * i64::from(self.t)
    }

    /// The level sample nearest finest position `p`.
    pub fn nearest(&self, p: [f64; 2]) -> [i64; 2] {
        let s = f64::from(1u32 << self.k);
        p.map(|v| (v / s + 0.5).floor() as i64)
    }

    /// The level samples (columns and rows, inclusive) that [`LevelView::evaluate`]
    /// and [`LevelView::is_terrain`] at finest position `p` read.
    pub fn reach(&self, method: Interpolation, p: [f64; 2]) -> [i64; 4] {
        let s = f64::from(1u32 << self.k);
        let last = self.last();
        let level = Stencil::new(method, [p[0] / s, p[1] / s], [last, last]);
        let (mut c0, mut c1) = level.cols.span();
        let (mut r0, mut r1) = level.rows.span();
        // The terrain test's cells around the nearest sample.
        let [nc, nr] = self.nearest(p);
        c0 = c0.min(nc - 1);
        c1 = c1.max(nc + 1);
        r0 = r0.min(nr - 1);
        r1 = r1.max(nr + 1);
        if self.k > 0 {
            let fine = Stencil::new(method, p, [last << self.k; 2]);
            let (g0, g1) = fine.cols.span();
            let (h0, h1) = fine.rows.span();
            c0 = c0.min(g0 >> self.k);
            c1 = c1.max((g1 >> self.k) + 1);
            r0 = r0.min(h0 >> self.k);
            r1 = r1.max((h1 >> self.k) + 1);
        }
        [c0.max(0), r0.max(0), c1.min(last), r1.min(last)]
    }

    /// The tiles `[x0, y0, x1, y1]` (inclusive) holding the samples [`Self::reach`]
    /// reads: from the first owner of the first sample to the last of the last.
    pub fn tiles_reached(&self, method: Interpolation, p: [f64; 2]) -> [u32; 4] {
        let [c0, r0, c1, r1] = self.reach(method, p);
        let span = i64::from(self.t);
        let first = |i: i64| owners(i, span, self.n)[0].expect("a sample has an owner");
        let last = |i: i64| {
            let [a, b] = owners(i, span, self.n);
            b.or(a).expect("a sample has an owner")
        };
        [first(c0), first(r0), last(c1), last(r1)]
    }
}

impl<'a> LevelView<'a> {
    /// The view of a level's grid through `tile`.
    pub fn new(grid: LevelGrid, tile: &'a dyn Fn(u32, u32) -> Option<&'a SourceTile>) -> Self {
        Self {
            grid,
            tile,
            last_tile: Cell::new(None),
        }
    }

    /// The tile holding level sample `(c, r)` and the sample's place in it.
    fn holder(&self, c: i64, r: i64) -> Option<(&'a SourceTile, usize)> {
        let span = i64::from(self.grid.t);
        let side = self.grid.t as usize + 1;
        // A sample two tiles share has the same height in both (decimation).
        if let Some((x0, y0, tile)) = self.last_tile.get()
            && (x0..=x0 + span).contains(&c)
            && (y0..=y0 + span).contains(&r)
        {
            return Some((tile, (r - y0) as usize * side + (c - x0) as usize));
        }
        for tx in owners(c, span, self.grid.n).into_iter().flatten() {
            for ty in owners(r, span, self.grid.n).into_iter().flatten() {
                if let Some(tile) = (self.tile)(tx, ty) {
                    let (x0, y0) = (i64::from(tx) * span, i64::from(ty) * span);
                    self.last_tile.set(Some((x0, y0, tile)));
                    return Some((tile, (r - y0) as usize * side + (c - x0) as usize));
                }
            }
        }
        None
    }

    /// The quantized height of level sample `(c, r)` (clamped to the grid).
    pub fn sample(&self, c: i64, r: i64) -> Option<u16> {
        let last = self.grid.last();
        let (tile, at) = self.holder(c.clamp(0, last), r.clamp(0, last))?;
        tile.heights.get(at).copied()
    }

    /// Whether level sample `(c, r)` is terrain: a corner of a valid cell (the
    /// mask is per cell), as the standard-grid tiles decide it (web/resample.rs).
    pub fn is_terrain(&self, c: i64, r: i64) -> bool {
        let cells = self.grid.last();
        let t = i64::from(self.grid.t);
        [(c - 1, r - 1), (c, r - 1), (c - 1, r), (c, r)]
            .into_iter()
            .filter(|&(x, y)| (0..cells).contains(&x) && (0..cells).contains(&y))
            .any(|(x, y)| {
                (self.tile)((x / t) as u32, (y / t) as u32)
                    .is_some_and(|s| s.mask.is_valid((x % t) as u32, (y % t) as u32))
            })
    }

    /// `T_L` at finest sample `(gx, gy)`, in quantization steps: the level's cell
    /// around it, triangulated north-west to south-east as the error tables measure
    /// it (builder/mesh_error.rs).
    fn triangulated(&self, gx: i64, gy: i64) -> Option<f64> {
        let (cx, cy) = (gx >> self.grid.k, gy >> self.grid.k);
        let s = f64::from(1u32 << self.grid.k);
        let (a, b) = (gx - (cx << self.grid.k), gy - (cy << self.grid.k));
        let q = |dc: i64, dr: i64| self.sample(cx + dc, cy + dr).map(f64::from);
        if a == 0 && b == 0 {
            return q(0, 0);
        }
        let (q00, q10, q01, q11) = (q(0, 0)?, q(1, 0)?, q(0, 1)?, q(1, 1)?);
        let (fa, fb) = (a as f64 / s, b as f64 / s);
        Some(if a >= b {
            q00 + (q10 - q00) * fa + (q11 - q10) * fb
        } else {
            q00 + (q11 - q01) * fa + (q01 - q00) * fb
        })
    }

    /// The error table's bound at finest sample `(gx, gy)`, metres (infinite where
    /// the tile's table is unknown).
    fn table_error(&self, gx: i64, gy: i64) -> Option<f64> {
        let span = i64::from(self.grid.t) << self.grid.k;
        let block = span / 8;
        for tx in owners(gx, span, self.grid.n).into_iter().flatten() {
            for ty in owners(gy, span, self.grid.n).into_iter().flatten() {
                if let Some(tile) = (self.tile)(tx, ty) {
                    let bx = ((gx - i64::from(tx) * span) / block).min(7) as usize;
                    let by = ((gy - i64::from(ty) * span) / block).min(7) as usize;
                    return Some(
                        tile.block_errors
                            .as_ref()
                            .map_or(f64::INFINITY, |e| f64::from(e[by * 8 + bx])),
                    );
                }
            }
        }
        None
    }

    /// The height at finest-sample position `p` (clamped to the DEM by the caller)
    /// and its bound; `None` when a sample it needs is in no stored tile.
    pub fn evaluate(
        &self,
        method: Interpolation,
        p: [f64; 2],
        quantization: &Quantization,
    ) -> Option<Evaluated> {
        let s = f64::from(1u32 << self.grid.k);
        let last = self.grid.last();
        let level = Stencil::new(method, [p[0] / s, p[1] / s], [last, last]);
        let mut steps = 0.0;
        for (c, r, w) in level.samples() {
            steps += w * f64::from(self.sample(c, r)?);
        }
        let scale = quantization.scale;
        let value = quantization.offset + scale * steps;
        let q = quantization.max_error;
        if self.grid.k == 0 {
            return Some(Evaluated {
                value,
                bound: level.abs_weight() * q,
            });
        }
        let fine = Stencil::new(method, p, [last << self.grid.k; 2]);
        let (mut reference, mut spread) = (0.0, 0.0);
        for (gx, gy, w) in fine.samples() {
            reference += w * self.triangulated(gx, gy)?;
            spread += w.abs() * (self.table_error(gx, gy)? + q);
        }
        Some(Evaluated {
            value,
            bound: (steps - reference).abs() * scale + spread + ROUNDING,
        })
    }
}

#[cfg(test)]
mod tests;
