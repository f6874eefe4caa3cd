//! Finest tiles: read from the raster (the padding beyond the DEM repeats its edge),
//! measured against the coarse cells above them (docs/ARCHITECTURE.md#error-tables, Kang
//! §4.1), masked.

use super::mesh_error::{self, CoarseCorners};
use super::node::{Node, to_metres};
use crate::ingest::raster::Raster;
use tessera_shared::tile::BLOCKS;
use tessera_shared::{CellMask, Quantization, TileGeometry, TileId};

/// Corner heights of the coarse cells (spacing > T) enclosing the finest tile at
/// global `(gx0, gy0)`, on the padded grid (clamped to the DEM's edge).
pub(super) fn coarse_corners(
    raster: &dyn Raster,
    g: &TileGeometry,
    gx0: u64,
    gy0: u64,
    spacings: u32,
) -> anyhow::Result<CoarseCorners> {
    let (last_x, last_y) = (u64::from(g.width() - 1), u64::from(g.height() - 1));
    let mut cells = Vec::with_capacity(spacings.saturating_sub(g.tile_log2() + 1) as usize);
    for k in g.tile_log2() + 1..spacings {
        let s = 1u64 << k;
        let (cx, cy) = (gx0 / s * s, gy0 / s * s);
        let mut cell = [0u16; 4];
        for (c, (x, y)) in
            cell.iter_mut()
                .zip([(cx, cy), (cx + s, cy), (cx, cy + s), (cx + s, cy + s)])
        {
            let (x, y) = (x.min(last_x) as u32, y.min(last_y) as u32);
            raster.read_window(x, y, 1, 1, std::slice::from_mut(c))?;
        }
        cells.push(cell);
    }
    Ok(CoarseCorners { cells })
}

/// Reads a finest tile (clamping the padding to the DEM's edge) and measures it. Its
/// errors are kept as the metres its records and its ancestors' store (`node.rs`).
pub(super) fn finest_node(
    raster: &dyn Raster,
    g: &TileGeometry,
    tile: TileId,
    spacings: u32,
    quant: &Quantization,
) -> anyhow::Result<Node> {
    let side = g.tile_samples();
    let (gx0, gy0) = g.origin(tile);
    let (x0, y0) = (gx0 as u32, gy0 as u32);
    let w = (side as u32).min(g.width() - x0);
    let h = (side as u32).min(g.height() - y0);
    let mut window = vec![0u16; (w * h) as usize];
    raster.read_window(x0, y0, w, h, &mut window)?;
    let mut heights = vec![0u16; side * side];
    for r in 0..side {
        let src = r.min(h as usize - 1) * w as usize;
        let dst = &mut heights[r * side..(r + 1) * side];
        dst[..w as usize].copy_from_slice(&window[src..src + w as usize]);
        let edge = dst[w as usize - 1];
        dst[w as usize..].fill(edge);
    }
    let corners = coarse_corners(raster, g, gx0, gy0, spacings)?;
    let mut errors =
        mesh_error::finest_tile_errors(&heights, g.tile_log2(), gx0, gy0, &corners, spacings);
    for v in &mut errors.values {
        *v = f64::from(to_metres(*v, quant));
    }
    let (min, max) = block_ranges(&heights, side);
    // Samples beyond the DEM's width and height are padding, never terrain.
    let cells = side as u32 - 1;
    let mask = if raster.has_nodata() {
        let mut valid = vec![false; (w * h) as usize];
        raster.read_validity(x0, y0, w, h, &mut valid)?;
        CellMask::from_samples(cells, |x, y| x < w && y < h && valid[(y * w + x) as usize])
    } else {
        CellMask::from_samples(cells, |x, y| x < w && y < h)
    };
    Ok(Node {
        heights,
        errors,
        min,
        max,
        mask,
    })
}

/// Min/max over each block's closed sample range.
fn block_ranges(heights: &[u16], side: usize) -> ([u16; 64], [u16; 64]) {
    let b = (side - 1) / BLOCKS as usize;
    let (mut min, mut max) = ([u16::MAX; 64], [0u16; 64]);
    for by in 0..BLOCKS as usize {
        for bx in 0..BLOCKS as usize {
            let i = by * BLOCKS as usize + bx;
            for v in by * b..=(by + 1) * b {
                for &q in &heights[v * side + bx * b..=v * side + (bx + 1) * b] {
                    min[i] = min[i].min(q);
                    max[i] = max[i].max(q);
                }
            }
        }
    }
    (min, max)
}
