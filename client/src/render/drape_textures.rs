//! The draped imagery's textures (module `drape`): one `Rgba8Unorm` layer per GPU
//! slot, and the one-row `Rg32Uint` texture of flags saying where each slot's
//! imagery is, with what each slot's layer holds.

use super::textures::texture_array;
use tessera_shared::TileId;

pub(super) const IMAGERY_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

/// The imagery textures and which tile each slot's layer holds.
#[derive(Debug)]
pub(super) struct ImageryTextures {
    pub texels: wgpu::Texture,
    /// `layers × 1`, `Rg32Uint`: where each slot's imagery is (module docs).
    pub flags: wgpu::Texture,
    /// Texels per layer side (1 until `Renderer::enable_imagery`).
    pub side: u32,
    holds: Vec<Option<TileId>>,
    /// What each slot's flag texel says now.
    source: Vec<[u32; 2]>,
}

pub(super) const FLAGS_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rg32Uint;

impl ImageryTextures {
    /// Textures of `side²` texels for `layers` slots, every flag 0.
    pub fn new(device: &wgpu::Device, layers: u32, side: u32) -> Self {
        let texels = texture_array(
            device,
            "imagery",
            IMAGERY_FORMAT,
            (side, layers),
            wgpu::TextureUsages::empty(),
        );
        // Zero-initialised by wgpu: no slot has imagery.
        let flags = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("imagery flags"),
            size: wgpu::Extent3d {
                width: layers,
                height: 1,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: FLAGS_FORMAT,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        Self {
            texels,
            flags,
            side,
            holds: vec![None; layers as usize],
            source: vec![[0, 0]; layers as usize],
        }
    }

    /// The layers: one per GPU slot.
    pub(super) fn layers(&self) -> u32 {
        self.holds.len() as u32
    }

    /// Whose imagery the layer of `slot` holds (`None`: none, or no such slot).
    pub(super) fn holds(&self, slot: u32) -> Option<TileId> {
        self.holds.get(slot as usize).copied().flatten()
    }

    /// The slot's layer now holds `tile`'s imagery (or nothing).
    pub(super) fn set_holds(&mut self, queue: &wgpu::Queue, slot: u32, tile: Option<TileId>) {
        if let Some(h) = self.holds.get_mut(slot as usize) {
            *h = tile;
            let own = if tile.is_some() {
                [slot + 1, 0]
            } else {
                [0, 0]
            };
            self.set_source(queue, slot, own);
        }
    }

    pub(super) fn set_source(&mut self, queue: &wgpu::Queue, slot: u32, source: [u32; 2]) {
        let Some(s) = self.source.get_mut(slot as usize) else {
            return;
        };
        if *s == source {
            return;
        }
        *s = source;
        queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &self.flags,
                mip_level: 0,
                origin: wgpu::Origin3d {
                    x: slot,
                    y: 0,
                    z: 0,
                },
                aspect: wgpu::TextureAspect::All,
            },
            bytemuck::cast_slice(&source),
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: None,
                rows_per_image: None,
            },
            wgpu::Extent3d {
                width: 1,
                height: 1,
                depth_or_array_layers: 1,
            },
        );
    }
}
