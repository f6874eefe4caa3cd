//! One standard-grid tile's heights, resampled on the fly from the pyramid
//! (docs/ARCHITECTURE.md#derived-outputs, DECISIONS.md "Standard-grid web tiles"): the
//! pyramid stays in the dataset's own grid, and each output pixel is read from the level
//! whose sample spacing best matches the pixel's.
//!
//! 1. **Window.** Only pixels inside the dataset's bounding box in the grid's CRS
//!    (and [`APRON`] pixels around it) are computed; the rest are no-data.
//! 2. **Level.** At the point of the tile nearest the dataset's centre, one pixel
//!    step east and south is carried to the dataset's samples; the level whose
//!    stride is nearest (in log₂) to that footprint is read — the finest when the
//!    map zooms in beyond the data, the coarsest (level 0) when it zooms out beyond
//!    it. There a pixel can span many samples, and a dataset smaller than a pixel
//!    (a 1° SRTM tile is 0.7 px of a zoom-0 tile) may hold no pixel centre at all:
//!    a pixel then reads the dataset where it is nearest the pixel's centre when it
//!    lies within half a pixel of it (`Plan::reach`), so a zoom-0 tile shows the
//!    data in its small footprint instead of nothing.
//! 3. **Coordinates.** Every pixel centre is carried to the level's sample
//!    coordinates through the projection library. Where the grid's axes map to the
//!    dataset's (a longitude/latitude dataset in either grid), exactly: one
//!    transform per column and per row. Elsewhere approximately
//!    ([`crate::approx_transform::over_grid`], within [`TOLERANCE`] of a sample).
//! 4. **Heights.** Bilinear on the stored (quantized) heights of the cell the point
//!    falls in — exact where the point is a sample. Each sample stands for its
//!    pixel, as in GDAL: a point is terrain when its nearest sample is, and a
//!    sample is terrain when a cell it is a corner of is (the mask is per cell,
//!    format v2). So a point half a sample beyond the DEM's edge still reads the
//!    edge, and a valid summit beside a void is served, interpolated over the
//!    void's fill (nearest valid heights).
//! 5. **Apron.** Pixels within [`APRON`] pixels of a terrain pixel (this tile's or
//!    a neighbour's) carry the fill's height (clamped to the grid at the DEM's outer
//!    edge) and count as data. Web clients interpolate elevation tiles bilinearly
//!    and ignore alpha (MapLibre reads pixels up to 1.5 px east and south of a
//!    point): without the apron, a lookup at the edge of the data would mix in the
//!    fill beyond it.
//! 6. **No-data.** Every other pixel still carries a plausible height, never
//!    −32768 m (docs/ARCHITECTURE.md#heights-and-no-data): a void inside the DEM's extent
//!    its fill (the nearest valid sample's height, stored by the build), anything beyond
//!    the DEM the dataset's lowest height, flat ([`crate::web::encoding::NoData`]). Flat,
//!    so hillshading draws nothing beyond the data; the lowest height, so 3D terrain
//!    stands on a plinth no deeper than the dataset's own relief instead of on
//!    walls 32 km deep. Alpha marks it only when asked (`nodata=transparent`):
//!    browsers read tiles through a premultiplied canvas, where a transparent
//!    pixel loses its colour and decodes as −32768 m again.

use super::footprint::Footprint;
use super::tile_matrix::WebTile;
use crate::approx_transform::over_grid;
use tessera_shared::mask::CellMask;
use tessera_shared::{Level, Quantization, TileGeometry, TileId};

/// Largest error of an interpolated pixel position, in samples of the level read
/// (1/100 000 of a sample: on a 1:1 slope of 200 m samples, 2 mm of height).
pub const TOLERANCE: f64 = 1e-5;

/// Pixels around terrain that carry heights (see the module doc, step 5).
pub const APRON: i64 = 2;

/// A decoded pyramid tile, as the sampler reads it.
#[derive(Debug)]
pub struct SourceTile {
    /// `(T+1)²` quantized heights, row-major, north row first.
    pub heights: Vec<u16>,
    pub mask: CellMask,
    pub quantization: Quantization,
    /// The error table's row for the tile drawn at its own full resolution: the
    /// largest distance, in metres, of its triangulated surface from the finest
    /// stored samples in each of its 8 × 8 blocks (`by · 8 + bx`). `None` where
    /// unknown (a tile made by upsampling an ancestor). The elevation API's error
    /// bounds read it (elevation/bound.rs).
    pub block_errors: Option<Box<[f32; 64]>>,
}

impl SourceTile {
    /// Heap bytes held (what a cache of these counts).
    pub fn bytes(&self) -> u64 {
        let errors = if self.block_errors.is_some() { 256 } else { 0 };
        (self.heights.len() * 2 + self.mask.encode().len().max(8) + errors) as u64
    }
}

/// The full-resolution row of a decoded record's error table, as
/// [`SourceTile::block_errors`] keeps it.
pub fn block_errors(table: &tessera_shared::error_table::ErrorTable) -> Option<Box<[f32; 64]>> {
    let row: [f32; 64] = table.level_errors(table.tile_log2()).try_into().ok()?;
    Some(Box::new(row))
}

/// What one output tile needs from the pyramid, and where each pixel reads it.
#[derive(Debug)]
pub struct Plan {
    pub tile: WebTile,
    pub px: u32,
    pub level: Level,
    /// Pixels `[i0, j0, i1, j1)` computed, in the tile's pixel coordinates; they
    /// may reach [`APRON`] pixels beyond the tile, into its neighbours.
    window: [i64; 4],
    /// The level's sample coordinates of the window's pixels.
    coords: Coords,
    /// The level's tiles the window reads: first column and row, columns, rows.
    tiles: [u32; 4],
    tile_size: u32,
    /// The DEM's last sample column and row in the level's sample coordinates: the
    /// grid beyond them is padding, not the DEM (see [`Sampled::heights`]).
    extent: [f64; 2],
    /// How far beyond the level's grid, in its samples along columns and rows, a
    /// point still reads it (clamped): half a sample, or half a pixel where a pixel
    /// spans more than one sample of the coarsest level (see the module doc, step 2).
    reach: [f64; 2],
}

/// Where a window's pixels fall among the level's samples.
#[derive(Debug)]
enum Coords {
    /// Every pixel's (column, row), row-major.
    Grid(Vec<[f64; 2]>),
    /// The column of each window column and the row of each window row, where the
    /// grid's axes map to the dataset's (a dataset in longitude and latitude, in
    /// either standard grid): a row and a column of transforms instead of a grid.
    Separable { cols: Vec<f64>, rows: Vec<f64> },
}

/// Whether `exact`'s columns depend on `i` alone and its rows on `j` alone, to
/// within a tenth of [`TOLERANCE`], on a 9 × 9 lattice of the `w × h` window.
fn separable(w: usize, h: usize, exact: &impl Fn(usize, usize) -> Option<[f64; 2]>) -> bool {
    let at = |k: usize, n: usize| k * (n - 1) / 8;
    let eps = TOLERANCE / 10.0;
    let lattice: Option<Vec<[f64; 2]>> = (0..9)
        .flat_map(|b| (0..9).map(move |a| (at(a, w), at(b, h))))
        .map(|(i, j)| exact(i, j))
        .collect();
    let Some(p) = lattice else { return false };
    (0..9).all(|b| {
        (0..9).all(|a| {
            let q = p[b * 9 + a];
            (q[0] - p[a][0]).abs() <= eps && (q[1] - p[b * 9][1]).abs() <= eps
        })
    })
}

/// One coordinate of a point among a level's `n` tiles of `t` cells (`limit` =
/// `n·t` cells in all).
#[derive(Clone, Copy, Debug)]
struct AxisPos {
    /// The coordinate itself, unclamped.
    raw: f64,
    /// Within half a sample of the grid (can be terrain).
    in_range: bool,
    /// Clamped to the grid.
    clamped: f64,
    tile: u32,
    /// The cell within the tile, and the fraction of the way across it.
    cell: u32,
    frac: f64,
}

impl AxisPos {
    /// `None` for a point that did not transform; `reach` is [`Plan::reach`]'s for
    /// this axis.
    fn new(v: f64, t: u32, n: u32, limit: f64, reach: f64) -> Option<Self> {
        if !v.is_finite() {
            return None;
        }
        let clamped = v.clamp(0.0, limit);
        let tile = tile_of(clamped, t, n);
        let u = clamped - f64::from(tile * t);
        let cell = (u as u32).min(t - 1);
        Some(Self {
            raw: v,
            in_range: (-reach..=limit + reach).contains(&v),
            clamped,
            tile,
            cell,
            frac: u - f64::from(cell),
        })
    }
}

/// The plan for `tile` at `px` pixels, or `None` when no pixel can hold data.
pub fn plan(fp: &Footprint, geometry: &TileGeometry, tile: WebTile, px: u32) -> Option<Plan> {
    if !fp.meets(tile) {
        return None;
    }
    let window = window(fp, tile, px)?;
    let finest = geometry.finest();
    let pixel = pixel_steps(fp, tile, px);
    let k = stride_log2(pixel).min(u32::from(finest.get()));
    let level = Level::new(finest.get() - k as u8)?;
    let stride = f64::from(1u32 << k);
    // Half a sample, or half a pixel where pixels are coarser than level 0's samples:
    // the half-extent of the pixel's parallelogram along each axis.
    let reach = pixel.map_or([0.5, 0.5], |[e, s]| {
        let half = |a: usize| ((e[a].abs() + s[a].abs()) / stride / 2.0).max(0.5);
        [half(0), half(1)]
    });
    let [i0, j0, i1, j1] = window;
    let (w, h) = ((i1 - i0) as usize, (j1 - j0) as usize);
    let exact = |i: usize, j: usize| {
        let [x, y] = tile.pixel_centre(px, (i0 + i as i64) as f64, (j0 + j as i64) as f64);
        let [c, r] = fp.to_samples(tile.tms, x, y)?;
        Some([c / stride, r / stride])
    };
    let t = geometry.tile_size();
    let n = level.tiles_per_side();
    let limit = f64::from(n) * f64::from(t);
    // The bounding box of the finite coordinates, clamped to the grid (apron pixels
    // read it clamped), and whether any point can be terrain.
    let (mut c0, mut r0, mut c1, mut r1) = (
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    );
    let mut terrain_possible = false;
    let coords = if separable(w, h, &exact) {
        // Every column and row transformed exactly: a few hundred transforms, so
        // these tiles are as exact as the projection library.
        let axis = |len: usize, f: &dyn Fn(usize) -> Option<f64>| -> Vec<f64> {
            (0..len).map(|k| f(k).unwrap_or(f64::NAN)).collect()
        };
        let cols = axis(w, &|i| exact(i, h / 2).map(|p| p[0]));
        let rows = axis(h, &|j| exact(w / 2, j).map(|p| p[1]));
        let within = |reach: f64| move |v: &f64| (-reach..=limit + reach).contains(v);
        terrain_possible = cols.iter().any(within(reach[0])) && rows.iter().any(within(reach[1]));
        for &c in cols.iter().filter(|v| v.is_finite()) {
            c0 = c0.min(c);
            c1 = c1.max(c);
        }
        for &r in rows.iter().filter(|v| v.is_finite()) {
            r0 = r0.min(r);
            r1 = r1.max(r);
        }
        Coords::Separable { cols, rows }
    } else {
        let grid = over_grid(w, h, TOLERANCE, &exact);
        for &[c, r] in &grid {
            if !(c.is_finite() && r.is_finite()) {
                continue;
            }
            terrain_possible |= in_range(c, r, limit, reach);
            c0 = c0.min(c);
            r0 = r0.min(r);
            c1 = c1.max(c);
            r1 = r1.max(r);
        }
        Coords::Grid(grid)
    };
    if !terrain_possible {
        return None;
    }
    // Terrain also needs the cells around its nearest sample (see the module doc).
    let lo = |v: f64| tile_of((v.clamp(0.0, limit) - 1.0).max(0.0), t, n);
    let hi = |v: f64| tile_of((v.clamp(0.0, limit) + 1.0).min(limit), t, n);
    let (tx0, ty0, tx1, ty1) = (lo(c0), lo(r0), hi(c1), hi(r1));
    Some(Plan {
        tile,
        px,
        level,
        window,
        coords,
        tiles: [tx0, ty0, tx1 - tx0 + 1, ty1 - ty0 + 1],
        tile_size: t,
        extent: [
            f64::from(geometry.width() - 1) / stride,
            f64::from(geometry.height() - 1) / stride,
        ],
        reach,
    })
}

/// The pixel window of `tile` that the dataset's bounding box covers, with a
/// margin of one pixel and the [`APRON`], reaching beyond the tile by the apron;
/// `None` when it covers no pixel of the tile.
fn window(fp: &Footprint, tile: WebTile, px: u32) -> Option<[i64; 4]> {
    let [x0, _, _, y1] = fp.tile_bounds(tile);
    let [bx0, by0, bx1, by1] = fp.data_bounds(tile.tms);
    let c = tile.tms.cell_size(tile.z, px);
    let side = f64::from(px);
    let a = APRON as f64;
    let clamp = |v: f64| v.clamp(-a, side + a) as i64;
    let i0 = clamp(((bx0 - x0) / c).floor() - 1.0 - a);
    let i1 = clamp(((bx1 - x0) / c).ceil() + 1.0 + a);
    let j0 = clamp(((y1 - by1) / c).floor() - 1.0 - a);
    let j1 = clamp(((y1 - by0) / c).ceil() + 1.0 + a);
    let px = i64::from(px);
    (i0 < i1.min(px) && j0 < j1.min(px) && i1 > 0 && j1 > 0).then_some([i0, j0, i1, j1])
}

/// One pixel step east and one south in finest samples (column, row), at the point
/// of `tile` nearest the dataset's centre; `None` where the projection fails there.
fn pixel_steps(fp: &Footprint, tile: WebTile, px: u32) -> Option<[[f64; 2]; 2]> {
    let [x0, y0, x1, y1] = fp.tile_bounds(tile);
    let [bx0, by0, bx1, by1] = fp.data_bounds(tile.tms);
    let c = tile.tms.cell_size(tile.z, px);
    let cx = f64::midpoint(bx0, bx1).clamp(x0 + c, x1 - c);
    let cy = f64::midpoint(by0, by1).clamp(y0 + c, y1 - c);
    let at = |x: f64, y: f64| fp.to_samples(tile.tms, x, y);
    let (Some(p), Some(e), Some(s)) = (at(cx, cy), at(cx + c, cy), at(cx, cy - c)) else {
        return None;
    };
    let step = |to: [f64; 2]| [to[0] - p[0], to[1] - p[1]];
    Some([step(e), step(s)])
}

/// log₂ of the finest-level stride that best matches a pixel of `steps` (the
/// geometric mean of the steps' lengths, in finest samples), rounded in log₂ (0 when
/// the pixel is finer than a sample or unknown).
fn stride_log2(steps: Option<[[f64; 2]; 2]>) -> u32 {
    let k = steps.map_or(0.0, |[e, s]| {
        (e[0].hypot(e[1]) * s[0].hypot(s[1])).sqrt().log2().round()
    });
    if k.is_finite() && k > 0.0 {
        k.min(31.0) as u32
    } else {
        0
    }
}

/// Whether a point is within `reach` samples (along columns, rows) of the level's
/// grid (of `limit` cells).
fn in_range(c: f64, r: f64, limit: f64, [rc, rr]: [f64; 2]) -> bool {
    c >= -rc && r >= -rr && c <= limit + rc && r <= limit + rr
}

/// The tile (of `n` per side, `t` cells each) holding level coordinate `v ≥ 0`; a
/// point on a shared border goes to the tile before it only at the grid's end.
/// (Truncation is `floor` for `v ≥ 0`, without a libm call.)
fn tile_of(v: f64, t: u32, n: u32) -> u32 {
    ((v / f64::from(t)) as u32).min(n - 1)
}

impl Plan {
    /// The level's tiles to read, row-major over the plan's tile rectangle; the
    /// sampler takes them back in this order.
    pub fn source_tiles(&self) -> Vec<TileId> {
        let [tx0, ty0, cols, rows] = self.tiles;
        (0..rows)
            .flat_map(|dy| (0..cols).map(move |dx| (tx0 + dx, ty0 + dy)))
            .filter_map(|(x, y)| TileId::new(self.level, x, y))
            .collect()
    }

    /// The tile's `px × px` heights (see [`Sampled`]). `sources[k]` is the `k`-th
    /// of [`Self::source_tiles`], `None` when the pyramid has no such tile (outside
    /// the DEM, or wholly no-data).
    pub fn sample<T: AsRef<SourceTile>>(&self, sources: &[Option<T>]) -> Sampled {
        self.sample_bordered(sources, 0)
    }

    /// The tile's heights with a border of `border` pixels (at most [`APRON`]) read
    /// from the neighbouring tiles' pixels: `(px + 2·border)²` values, row-major from
    /// the border's north-west corner. Each border pixel is the one its neighbour
    /// tile computes there when it reads the same level (rendered tiles' 3 × 3
    /// windows, web/render/).
    pub fn sample_bordered<T: AsRef<SourceTile>>(
        &self,
        sources: &[Option<T>],
        border: u32,
    ) -> Sampled {
        assert!(
            i64::from(border) <= APRON,
            "the border lies within the apron's window"
        );
        let [i0, j0, i1, j1] = self.window;
        let w = (i1 - i0) as usize;
        let [tx0, ty0, cols, rows] = self.tiles;
        let t = self.tile_size;
        let n = self.level.tiles_per_side();
        let limit = f64::from(n) * f64::from(t);
        let side = t as usize + 1;
        let tile_at = |tx: u32, ty: u32| -> Option<&SourceTile> {
            if tx < tx0 || ty < ty0 || tx - tx0 >= cols || ty - ty0 >= rows {
                return None;
            }
            let slot = ((ty - ty0) * cols + (tx - tx0)) as usize;
            sources.get(slot)?.as_ref().map(AsRef::as_ref)
        };
        // Whether level cell (gx, gy) is terrain.
        let cell = |gx: i64, gy: i64| -> bool {
            let cells = i64::from(n) * i64::from(t);
            if gx < 0 || gy < 0 || gx >= cells || gy >= cells {
                return false;
            }
            let (gx, gy) = (gx as u32, gy as u32);
            tile_at(gx / t, gy / t).is_some_and(|s| s.mask.is_valid(gx % t, gy % t))
        };
        // Heights of every window pixel that has a source (terrain or not), and
        // which are terrain.
        let len = (w as i64 * (j1 - j0)) as usize;
        let mut heights = vec![f64::NAN; len];
        let mut terrain = vec![false; len];
        // Within half a sample of the DEM's own extent (not the padded grid).
        let mut in_dem = vec![false; len];
        let [ex, ey] = self.extent;
        // Neighbouring pixels mostly read the same tile: look it up once per run.
        let mut last: Option<((u32, u32), Option<&SourceTile>)> = None;
        let mut pixel = |k: usize, a: &AxisPos, b: &AxisPos| {
            let src = match last {
                Some((at, s)) if at == (a.tile, b.tile) => s,
                _ => {
                    let s = tile_at(a.tile, b.tile);
                    last = Some(((a.tile, b.tile), s));
                    s
                }
            };
            let Some(src) = src else {
                return;
            };
            in_dem[k] = (-0.5..=ex + 0.5).contains(&a.raw) && (-0.5..=ey + 0.5).contains(&b.raw);
            terrain[k] = a.in_range
                && b.in_range
                && (src.mask.is_valid(a.cell, b.cell) || {
                    let (nx, ny) = ((a.clamped + 0.5) as i64, (b.clamped + 0.5) as i64);
                    cell(nx - 1, ny - 1) || cell(nx, ny - 1) || cell(nx - 1, ny) || cell(nx, ny)
                });
            let q = &src.quantization;
            let base = b.cell as usize * side + a.cell as usize;
            let hs = &src.heights;
            let at = |o: usize| q.height(hs[base + o]);
            let top = lerp(at(0), at(1), a.frac);
            let bottom = lerp(at(side), at(side + 1), a.frac);
            heights[k] = lerp(top, bottom, b.frac);
        };
        let axis = |v: f64, reach: f64| AxisPos::new(v, t, n, limit, reach);
        match &self.coords {
            Coords::Grid(grid) => {
                for (k, &[c, r]) in grid.iter().enumerate() {
                    if let (Some(a), Some(b)) = (axis(c, self.reach[0]), axis(r, self.reach[1])) {
                        pixel(k, &a, &b);
                    }
                }
            }
            Coords::Separable { cols, rows } => {
                let cols: Vec<Option<AxisPos>> =
                    cols.iter().map(|&c| axis(c, self.reach[0])).collect();
                for (j, &r) in rows.iter().enumerate() {
                    let Some(b) = axis(r, self.reach[1]) else {
                        continue;
                    };
                    for (i, a) in cols.iter().enumerate() {
                        if let Some(a) = a {
                            pixel(j * w + i, a, &b);
                        }
                    }
                }
            }
        }
        let px = i64::from(self.px);
        let b = i64::from(border);
        let side = px + 2 * b;
        let mut out = vec![f64::NAN; (side * side) as usize];
        let mut data = vec![false; (side * side) as usize];
        let mut is_terrain = vec![false; (side * side) as usize];
        // Window pixels with a terrain pixel within the apron: a square dilation,
        // done as a pass along rows and one down columns.
        let hi = (j1 - j0) as usize;
        let a = APRON as usize;
        let mut along = vec![false; len];
        for j in 0..hi {
            let row = &terrain[j * w..(j + 1) * w];
            for i in 0..w {
                along[j * w + i] = row[i.saturating_sub(a)..=(i + a).min(w - 1)].contains(&true);
            }
        }
        for j in j0.max(-b)..j1.min(px + b) {
            let jj = (j - j0) as usize;
            let (top, bottom) = (jj.saturating_sub(a), (jj + a).min(hi - 1));
            for i in i0.max(-b)..i1.min(px + b) {
                let ii = (i - i0) as usize;
                let k = jj * w + ii;
                let h = heights[k];
                let near = || (top..=bottom).any(|r| along[r * w + ii]);
                let o = ((j + b) * side + i + b) as usize;
                is_terrain[o] = terrain[k];
                if terrain[k] || (h.is_finite() && near()) {
                    out[o] = h;
                    data[o] = true;
                } else if in_dem[k] {
                    // A void in the DEM: the build's fill (its nearest valid sample).
                    out[o] = h;
                }
            }
        }
        Sampled {
            heights: out,
            data,
            terrain: is_terrain,
        }
    }
}

/// One standard-grid tile's heights, as [`Plan::sample`] reads them.
#[derive(Debug)]
pub struct Sampled {
    /// `px × px` heights in metres, row-major: terrain, the apron, and voids inside
    /// the DEM's extent (the build's fill, the nearest valid sample's height); NaN
    /// elsewhere (beyond the DEM and its apron), which the encoder fills
    /// ([`crate::web::encoding::NoData`]).
    pub heights: Vec<f64>,
    /// Whether each pixel is terrain or its apron (module doc, step 5): what
    /// `nodata=transparent` leaves opaque.
    pub data: Vec<bool>,
    /// Whether each pixel is terrain itself (not the apron, not a void's fill): what
    /// rendered tiles draw.
    pub terrain: Vec<bool>,
}

impl Sampled {
    /// Whether no pixel holds data.
    pub fn is_empty(&self) -> bool {
        !self.data.contains(&true)
    }
}

/// `a + t·(b − a)`: exactly `a` at `t = 0`, so a point on a sample reads it exactly.
fn lerp(a: f64, b: f64, t: f64) -> f64 {
    if t == 0.0 { a } else { a + t * (b - a) }
}

impl AsRef<SourceTile> for SourceTile {
    fn as_ref(&self) -> &SourceTile {
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::web::tile_matrix::TileMatrixSet;
    use std::sync::Arc;
    use tessera_shared::Metadata;

    /// A 4326 dataset of `n × n` samples at `d`° whose heights are a plane in
    /// longitude and latitude, in one pyramid level of one tile.
    fn plane_dataset(n: u32, d: f64, tile_size: u32) -> (Metadata, TileGeometry) {
        // Sample (0, 0) centred on (10° E, 50° N).
        let gt = [10.0 - d / 2.0, d, 0.0, 50.0 + d / 2.0, 0.0, -d];
        let mut m = crate::web::footprint::tests::metadata(4326, gt, n, n);
        m.tile_size = tile_size;
        let g = TileGeometry::new(n, n, tile_size).unwrap();
        (m, g)
    }

    /// Height `3·col + 5·row` (quantized exactly), with cells 9..12 × 19..22
    /// masked: samples 10..=11 × 20..=21 have no valid cell around them.
    fn plane_tile(n: u32) -> SourceTile {
        let side = n as usize;
        let heights = (0..side * side)
            .map(|k| (3 * (k % side) + 5 * (k / side)) as u16)
            .collect();
        let mut mask = CellMask::all_valid(n - 1);
        for y in 19..22 {
            for x in 9..12 {
                mask.set(x, y, false);
            }
        }
        SourceTile {
            heights,
            mask,
            quantization: Quantization {
                offset: 0.0,
                scale: 1.0,
                max_error: 0.0,
            },
            block_errors: None,
        }
    }

    #[test]
    fn bilinear_heights_at_every_pixel_and_no_data_where_masked() {
        let d = 1.0 / 64.0;
        let (m, g) = plane_dataset(65, d, 64);
        let fp = Footprint::new(&m).unwrap();
        // CRS84 zoom 7: 180/128 = 1.406° per tile; (10°, 50°) is in tile x 135, y 28.
        let tile = WebTile::new(TileMatrixSet::WorldCrs84Quad, 7, 135, 28).unwrap();
        let plan = plan(&fp, &g, tile, 256).unwrap();
        assert_eq!(plan.level.get(), 0);
        assert_eq!(plan.source_tiles().len(), 1);
        let src = Arc::new(plane_tile(65));
        let out = plan.sample(&[Some(src)]);
        // Pixel centres fall at c = −10 + (i + ½)·45/128 samples (and likewise r):
        // never on a half sample, so "nearest sample" is never a tie.
        let at = |i: u32, j: u32| {
            let [lon, lat] = tile.pixel_centre(256, f64::from(i), f64::from(j));
            ((lon - 10.0) / d, (50.0 - lat) / d)
        };
        // Terrain: each sample stands for its pixel (half a sample beyond the edge
        // samples counts), except samples 10..=11 × 20..=21 (no valid cell).
        let is_terrain = |i: u32, j: u32| {
            let (c, r) = at(i, j);
            let in_pixels = (-0.5..64.5).contains(&c) && (-0.5..64.5).contains(&r);
            let (nc, nr) = (c.round(), r.round());
            in_pixels && !((10.0..=11.0).contains(&nc) && (20.0..=21.0).contains(&nr))
        };
        let (mut terrain, mut apron, mut void, mut none) = (0, 0, 0, 0);
        for j in 0..256u32 {
            for i in 0..256u32 {
                let (c, r) = at(i, j);
                let k = (j * 256 + i) as usize;
                let (h, data) = (out.heights[k], out.data[k]);
                // The plane is the fill too: apron pixels read it, clamped to the grid.
                let want = 3.0 * c.clamp(0.0, 64.0) + 5.0 * r.clamp(0.0, 64.0);
                let near = (j.saturating_sub(2)..=(j + 2).min(255)).any(|jj| {
                    (i.saturating_sub(2)..=(i + 2).min(255)).any(|ii| is_terrain(ii, jj))
                });
                let in_dem = (-0.5..=64.5).contains(&c) && (-0.5..=64.5).contains(&r);
                if is_terrain(i, j) {
                    terrain += 1;
                    assert!((h - want).abs() < 1e-6, "({i}, {j}): {h} vs {want}");
                    assert!(data, "({i}, {j}) is terrain");
                } else if near {
                    apron += 1;
                    assert!((h - want).abs() < 1e-6, "apron ({i}, {j}): {h} vs {want}");
                    assert!(data, "apron ({i}, {j}) counts as data");
                } else if in_dem {
                    // The masked samples, beyond the apron: the void's fill, no data.
                    void += 1;
                    assert!((h - want).abs() < 1e-6, "void ({i}, {j}): {h} vs {want}");
                    assert!(!data, "void ({i}, {j}) is no data");
                } else {
                    none += 1;
                    assert!(
                        h.is_nan() && !data,
                        "({i}, {j}) at ({c}, {r}) lies beyond the DEM: {h}"
                    );
                }
            }
        }
        assert!(
            terrain > 1000 && apron > 0 && void > 0 && none > 0,
            "{terrain} terrain, {apron} apron, {void} void, {none} none"
        );
    }

    #[test]
    fn the_separable_path_reads_what_the_grid_path_reads() {
        let d = 1.0 / 64.0;
        let (m, g) = plane_dataset(65, d, 64);
        let fp = Footprint::new(&m).unwrap();
        let src = [Some(Arc::new(plane_tile(65)))];
        for tile in [
            WebTile::new(TileMatrixSet::WorldCrs84Quad, 7, 135, 28).unwrap(),
            WebTile::new(TileMatrixSet::WebMercatorQuad, 8, 135, 86).unwrap(),
        ] {
            let mut p = plan(&fp, &g, tile, 256).unwrap();
            let Coords::Separable { cols, rows } = &p.coords else {
                panic!("{tile}: a longitude/latitude dataset maps axis to axis");
            };
            let grid = rows
                .iter()
                .flat_map(|&r| cols.iter().map(move |&c| [c, r]))
                .collect();
            let fast = p.sample(&src);
            p.coords = Coords::Grid(grid);
            let general = p.sample(&src);
            assert!(fast.heights.iter().any(|h| h.is_finite()), "{tile}");
            assert_eq!(fast.data, general.data, "{tile}");
            for (a, b) in fast.heights.iter().zip(&general.heights) {
                assert!(a == b || (a.is_nan() && b.is_nan()), "{tile}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn a_tile_far_from_the_dataset_needs_nothing() {
        let (m, g) = plane_dataset(65, 1.0 / 64.0, 64);
        let fp = Footprint::new(&m).unwrap();
        let far = WebTile::new(TileMatrixSet::WebMercatorQuad, 7, 0, 0).unwrap();
        assert!(plan(&fp, &g, far, 256).is_none());
    }

    #[test]
    fn a_dataset_smaller_than_a_pixel_shows_where_it_lies() {
        // 1° of samples at 10° E, 50° N: in a 256-px Web Mercator zoom-0 tile a pixel
        // is 1.4°, so no pixel centre falls inside the dataset (the tile was empty).
        let d = 1.0 / 64.0;
        let (m, g) = plane_dataset(65, d, 64);
        let fp = Footprint::new(&m).unwrap();
        let src = [Some(Arc::new(plane_tile(65)))];
        let tile = WebTile::new(TileMatrixSet::WebMercatorQuad, 0, 0, 0).unwrap();
        let plan = plan(&fp, &g, tile, 256).expect("the tile covers the dataset");
        assert_eq!(plan.level.get(), 0);
        let out = plan.sample(&src);
        let px = |lon: f64| ((lon + 180.0) / 360.0 * 256.0) as usize;
        let py = |lat: f64| {
            let y = (1.0 - f64::to_radians(lat).tan().asinh() / std::f64::consts::PI) / 2.0;
            (y * 256.0) as usize
        };
        // Every pixel the dataset's box covers is terrain, its height the plane's
        // (0 ..= 3·64 + 5·64 m) at the point nearest the pixel's centre; pixels
        // further than a pixel and the apron are no-data.
        let (cols, rows) = (
            px(10.0 - d / 2.0)..=px(11.0 + d / 2.0),
            py(50.0 + d / 2.0)..=py(49.0 - d / 2.0),
        );
        let mut terrain = 0;
        for (k, h) in out.heights.iter().enumerate() {
            let (i, j) = (k % 256, k / 256);
            if cols.contains(&i) && rows.contains(&j) {
                assert!((0.0..=512.0).contains(h), "({i}, {j}): {h}");
                assert!(out.data[k], "({i}, {j}) shows the dataset");
                terrain += 1;
            } else if h.is_finite() {
                // Half a pixel of reach (a pixel that touches the box), then the apron.
                let beyond = 1 + APRON as usize;
                let near = |v: usize, r: &std::ops::RangeInclusive<usize>| {
                    v + beyond >= *r.start() && v <= r.end() + beyond
                };
                assert!(near(i, &cols) && near(j, &rows), "({i}, {j}): {h}");
            }
        }
        assert!(terrain >= 1, "no pixel shows the dataset");
        // Where pixels are finer than the coarsest level's samples, a pixel's centre
        // still has to fall within half a sample of the grid (unchanged).
        let fine = WebTile::new(TileMatrixSet::WorldCrs84Quad, 7, 135, 28).unwrap();
        assert_eq!(super::plan(&fp, &g, fine, 256).unwrap().reach, [0.5, 0.5]);
    }

    #[test]
    fn the_level_follows_the_pixel_size() {
        // 8193 samples at 1/10 000°, in tiles of 256: levels 0..=5.
        let n = 8193;
        let (m, g) = plane_dataset(n, 1e-4, 256);
        let fp = Footprint::new(&m).unwrap();
        let [lon, lat] = fp.centre();
        let centre = |z: u8| {
            let (cols, rows) = TileMatrixSet::WorldCrs84Quad.matrix_size(z);
            let x = ((lon + 180.0) / 360.0 * f64::from(cols)) as u32;
            let y = ((90.0 - lat) / 180.0 * f64::from(rows)) as u32;
            WebTile::new(TileMatrixSet::WorldCrs84Quad, z, x, y).unwrap()
        };
        // At z, a 256-px pixel is 180/(256·2^z)° = 7031/2^z samples (log₂ 12.78):
        // z 13 → 0.86 → stride 1 (finest, level 5); z 12 → 1.7 → stride 2
        // (level 4); z 10 → 6.9 → stride 8 (level 2); z 5 → the root.
        let level = |z| plan(&fp, &g, centre(z), 256).unwrap().level.get();
        assert_eq!(level(13), 5);
        assert_eq!(level(16), 5);
        assert_eq!(level(12), 4);
        assert_eq!(level(10), 2);
        assert_eq!(level(5), 0);
    }
}
