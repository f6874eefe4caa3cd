//! Uploading decoded tiles into their GPU slots: heights, the tile's validity
//! mask (one byte per cell, 255 = terrain), which the fragment shader reads to
//! discard non-terrain cells, and a normal map — computed on the GPU from the
//! slots' heights ([`super::gpu_normals`]), so that an upload is only texture
//! copies, or, with [`NormalSource::Cpu`], built here with the tile's decoded
//! neighbours ([`normals::normal_map`]).

use super::error::RenderError;
use super::gpu_normals::NORMAL_FORMAT;
use super::normals::{self, NormalSource};
use super::readback::read_layer;
use super::renderer::Renderer;
use crate::select::Wanted;
use crate::stream::pool::TilePool;
use std::time::{Duration, Instant};
use tessera_shared::TileId;

/// Writes one texture-array layer: `side × side` texels of `bytes_per_texel` each.
pub(super) fn write_layer(
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
    slot: u32,
    data: &[u8],
    side: u32,
    bytes_per_texel: u32,
) {
    queue.write_texture(
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
}

impl Renderer {
    /// Uploads a decoded tile (heights and cell mask; its normal map is computed
    /// on the GPU at the next flush, or here on the CPU path) into a slot. `false`
    /// when every slot is in use this frame.
    pub fn upload(&mut self, pool: &TilePool, tile: TileId) -> bool {
        let Some(resident) = pool.get(tile) else {
            return false;
        };
        let Some(slot) = self.slots.allocate(tile) else {
            return false;
        };
        self.imagery_slot_taken(slot, tile);
        let g = self.world.geometry;
        let side = g.tile_samples() as u32;
        let queue = &self.gpu.queue;
        write_layer(
            queue,
            &self.heights,
            slot,
            bytemuck::cast_slice(&resident.heights),
            side,
            2,
        );
        // T × T cells (one fewer per side than samples).
        debug_assert_eq!(resident.mask.side(), g.tile_size());
        write_layer(
            queue,
            &self.masks,
            slot,
            &resident.mask.to_bytes_per_cell(),
            g.tile_size(),
            1,
        );
        if let Some(pass) = self.normal_pass.as_mut() {
            pass.queue(queue, tile, slot, &resident.heights);
        } else {
            let map = self.cpu_normal_map(pool, tile, &resident.heights);
            let texel = NORMAL_FORMAT.block_copy_size(None).unwrap_or(4);
            write_layer(queue, &self.normals, slot, &map, side, texel);
        }
        true
    }

    /// The [`NormalSource::Cpu`] path: `tile`'s normal map from its heights and
    /// its decoded same-level neighbours, as texels of the normal texture.
    fn cpu_normal_map(&self, pool: &TilePool, tile: TileId, heights: &[u16]) -> Vec<u8> {
        let g = self.world.geometry;
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
        let map = normals::normal_map(
            heights,
            g.tile_samples(),
            &neighbours,
            metres,
            self.world.quant.scale,
        );
        // Rgba8Snorm texels: (x, z) as the shader reads them; y is implied.
        map.iter()
            .flat_map(|&[x, z]| [x as u8, z as u8, 0, 0])
            .collect()
    }

    /// Uploads the wanted tiles that are decoded but not on the GPU, within
    /// `budget` (at least one, so a slow frame still makes progress): coarse levels
    /// first so ancestors arrive before descendants, then the most wanted. Their
    /// normal maps are computed in one GPU pass when the next frame is drawn
    /// ([`Renderer::flush_normals`]): submitted here, the pass's time showed up
    /// in the upload time on lavapipe (BENCHMARKS.md, "Tile uploads").
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

    /// Where this renderer builds normal maps.
    pub fn normal_source(&self) -> NormalSource {
        if self.normals_on_gpu() {
            NormalSource::Gpu
        } else {
            NormalSource::Cpu
        }
    }
}

impl Renderer {
    /// Whether normal maps are computed on the GPU (else on the CPU at upload).
    pub fn normals_on_gpu(&self) -> bool {
        self.normal_pass.is_some()
    }

    /// Computes the normal maps of the tiles uploaded since the last flush (and
    /// the border rings of their resident neighbours) in one submitted compute
    /// pass, without waiting for it. Nothing to do on the CPU path.
    pub fn flush_normals(&mut self) {
        if let Some(pass) = self.normal_pass.as_mut() {
            pass.flush(&self.gpu, &self.slots, &self.world);
        }
    }

    /// The normal map in `slot` as (x, z) signed bytes, row by row (what the
    /// fragment shader reads), after computing any queued normal maps.
    pub fn read_normals(&mut self, slot: u32) -> Result<Vec<[i8; 2]>, RenderError> {
        self.flush_normals();
        let n = self.world.geometry.tile_samples() as u32;
        let data = read_layer(&self.gpu, &self.normals, slot, (n, n), 4)?;
        let out = data
            .chunks_exact(4)
            .map(|texel| [texel[0] as i8, texel[1] as i8])
            .collect();
        Ok(out)
    }
}
