//! The full-resolution reference (DECISIONS.md "Rendering",
//! docs/ARCHITECTURE.md#measuring): every finest sample a vertex. Finest tiles are cut
//! into 64-cell patches drawn at inner LOD 64 with all edges at 64, so no vertex is
//! snapped and nothing is simplified.

use crate::camera::Frustum;
use crate::select::metric::tile_box;
use crate::select::{Patch, TileTables, World};
use glam::DVec3;
use tessera_shared::TileId;
use tessera_shared::tile::BLOCKS;

/// Finest tiles whose column (the dataset's whole height range) meets the frustum:
/// every one the geometry places inside the DEM, including those that turn out to
/// be absent (wholly no-data), which callers skip once the server has said so.
pub fn finest_tiles_in_view(world: &World, frustum: &Frustum, heights: (f64, f64)) -> Vec<TileId> {
    let g = world.geometry;
    g.present_tiles(g.finest())
        .filter(|&t| {
            let (origin, size) = world.tile_extent(t);
            frustum.intersects_box(
                DVec3::new(origin.x, heights.0, origin.y),
                DVec3::new(origin.x + size.x, heights.1, origin.y + size.y),
            )
        })
        .collect()
}

/// Full-resolution patches of the given finest tiles, culled against the frustum
/// by their blocks' min/max boxes. Tiles without a table are skipped.
pub fn full_resolution_patches(
    world: &World,
    tiles: &[TileId],
    tables: &dyn TileTables,
    frustum: &Frustum,
) -> Vec<Patch> {
    let t = world.geometry.tile_size();
    let size = t.min(64);
    let block = t / BLOCKS;
    let mut out = Vec::new();
    for &tile in tiles {
        let Some(table) = tables.table(tile) else {
            continue;
        };
        let Some((lo, hi)) = tile_box(world, tile, table) else {
            continue;
        };
        if !frustum.intersects_box(lo, hi) {
            continue;
        }
        let (origin, size_m) = world.tile_extent(tile);
        // Metres per tile cell, east–west and north–south.
        let metres = size_m / f64::from(t);
        for py in (0..t).step_by(size as usize) {
            for px in (0..t).step_by(size as usize) {
                // Height range of the blocks under this patch.
                let (mut qmin, mut qmax) = (u16::MAX, 0);
                let blocks = |p: u32| p / block..(p + size).div_ceil(block);
                for by in blocks(py) {
                    for bx in blocks(px) {
                        let (a, b) = table.block_range(bx, by);
                        qmin = qmin.min(a);
                        qmax = qmax.max(b);
                    }
                }
                if qmin > qmax {
                    continue;
                }
                let lo = DVec3::new(
                    origin.x + f64::from(px) * metres.x,
                    world.quant.height(qmin),
                    origin.y + f64::from(py) * metres.y,
                );
                let hi = DVec3::new(
                    origin.x + f64::from(px + size) * metres.x,
                    world.quant.height(qmax),
                    origin.y + f64::from(py + size) * metres.y,
                );
                if frustum.intersects_box(lo, hi) {
                    out.push(Patch {
                        tile,
                        origin: [px, py],
                        size,
                        inner: size,
                        edges: [size; 4],
                        morph: crate::select::morph::Morph::NONE,
                        fade: crate::select::fade::Fade::NONE,
                    });
                }
            }
        }
    }
    out
}
