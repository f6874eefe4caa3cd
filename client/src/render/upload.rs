//! Uploading decoded tiles into their GPU slots: heights, a normal map built with
//! the tile's decoded neighbours, and the tile's validity mask (one byte per cell,
//! 255 = terrain), which the fragment shader reads to discard non-terrain cells.

use super::{Renderer, normals};
use crate::select::Wanted;
use crate::stream::pool::TilePool;
use std::time::{Duration, Instant};
use tessera_shared::TileId;

impl Renderer {
    /// Uploads a decoded tile (heights, a normal map built with its decoded
    /// neighbours, and its cell mask) into a slot. `false` when every slot is in
    /// use this frame.
    pub fn upload(&mut self, pool: &TilePool, tile: TileId) -> bool {
        let Some(resident) = pool.get(tile) else {
            return false;
        };
        let Some(slot) = self.slots.allocate(tile) else {
            return false;
        };
        let g = self.world.geometry;
        let samples = g.tile_samples();
        let same_level = |dx: i64, dy: i64| {
            let (x, y) = (i64::from(tile.x()) + dx, i64::from(tile.y()) + dy);
            let t = TileId::new(tile.level(), u32::try_from(x).ok()?, u32::try_from(y).ok()?)?;
            pool.get(t).map(|r| r.heights.as_slice())
        };
        let neighbours = [
            same_level(0, -1),
            same_level(1, 0),
            same_level(0, 1),
            same_level(-1, 0),
        ];
        // Metres between this level's samples, east–west and north–south.
        let metres = self.world.spacing * g.spacing(tile.level()) as f64;
        let normal_map = normals::normal_map(
            &resident.heights,
            samples,
            &neighbours,
            metres,
            self.world.quant.scale,
        );
        let write = |texture: &wgpu::Texture, data: &[u8], side: u32, bytes_per_texel: u32| {
            self.gpu.queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d {
                        x: 0,
                        y: 0,
                        z: slot,
                    },
                    aspect: wgpu::TextureAspect::All,
                },
                data,
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(side * bytes_per_texel),
                    rows_per_image: Some(side),
                },
                wgpu::Extent3d {
                    width: side,
                    height: side,
                    depth_or_array_layers: 1,
                },
            );
        };
        let side = samples as u32;
        write(
            &self.heights,
            bytemuck::cast_slice(&resident.heights),
            side,
            2,
        );
        write(&self.normals, bytemuck::cast_slice(&normal_map), side, 2);
        // T × T cells (one fewer per side than samples).
        debug_assert_eq!(resident.mask.side(), g.tile_size());
        write(
            &self.masks,
            &resident.mask.to_bytes_per_cell(),
            g.tile_size(),
            1,
        );
        true
    }

    /// Uploads the wanted tiles that are decoded but not on the GPU, within
    /// `budget` (at least one, so a slow frame still makes progress): coarse levels
    /// first so ancestors arrive before descendants, then the most wanted.
    /// Returns how many were uploaded.
    pub fn upload_wanted(&mut self, pool: &TilePool, wanted: &[Wanted], budget: Duration) -> u32 {
        let started = Instant::now();
        let mut todo: Vec<&Wanted> = wanted
            .iter()
            .filter(|w| pool.contains(w.tile) && self.slots.get(w.tile).is_none())
            .collect();
        todo.sort_by(|a, b| {
            a.tile
                .level()
                .cmp(&b.tile.level())
                .then(b.rho.total_cmp(&a.rho))
        });
        let mut uploads = 0;
        for w in todo {
            if uploads > 0 && started.elapsed() >= budget {
                break;
            }
            if self.upload(pool, w.tile) {
                uploads += 1;
            }
        }
        uploads
    }
}
