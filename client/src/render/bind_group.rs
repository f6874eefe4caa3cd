//! The terrain bind group (group 0 of `terrain.wgsl`): globals, the height, normal,
//! cell-mask and imagery arrays, the globe's tables and a sampler; built again when
//! a texture is replaced.

use super::drape_textures::ImageryTextures;
use super::renderer::Renderer;

/// The terrain bind group's resources (group 0 of `terrain.wgsl`).
pub(super) struct BindParts<'a> {
    pub globals: &'a wgpu::Buffer,
    pub heights: &'a wgpu::Texture,
    pub normals: &'a wgpu::Texture,
    pub sampler: &'a wgpu::Sampler,
    pub masks: &'a wgpu::Texture,
    pub globe_tables: &'a [wgpu::Buffer; 2],
    pub imagery: &'a ImageryTextures,
}

pub(super) fn bind_group(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    p: &BindParts<'_>,
) -> wgpu::BindGroup {
    fn view(binding: u32, view: &wgpu::TextureView) -> wgpu::BindGroupEntry<'_> {
        wgpu::BindGroupEntry {
            binding,
            resource: wgpu::BindingResource::TextureView(view),
        }
    }
    let array_view = |t: &wgpu::Texture| {
        t.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        })
    };
    let flags = p.imagery.flags.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2),
        ..Default::default()
    });
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("terrain"),
        layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: p.globals.as_entire_binding(),
            },
            view(1, &array_view(p.heights)),
            view(2, &array_view(p.normals)),
            wgpu::BindGroupEntry {
                binding: 3,
                resource: wgpu::BindingResource::Sampler(p.sampler),
            },
            view(4, &array_view(p.masks)),
            wgpu::BindGroupEntry {
                binding: 5,
                resource: p.globe_tables[0].as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 6,
                resource: p.globe_tables[1].as_entire_binding(),
            },
            view(7, &array_view(&p.imagery.texels)),
            view(8, &flags),
        ],
    })
}

impl Renderer {
    /// Builds the terrain bind group again (after a texture was replaced).
    pub(super) fn rebuild_bind_group(&mut self) {
        self.bind_group = bind_group(
            &self.gpu.device,
            &self.layout,
            &BindParts {
                globals: &self.globals,
                heights: &self.heights,
                normals: &self.normals,
                sampler: &self.sampler,
                masks: &self.masks,
                globe_tables: &self.globe_tables,
                imagery: &self.imagery,
            },
        );
    }
}
