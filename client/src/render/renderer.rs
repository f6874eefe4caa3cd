//! The renderer: the device, the world it draws, its settings, the GPU slots of
//! its tiles and the device objects its parts (`pipeline`, `draw`, `upload`,
//! `imagery`, `capture`, `readback`) create and use.

use super::drape_textures::ImageryTextures;
use super::gpu::Gpu;
use super::gpu_normals;
use super::options::RenderOptions;
use super::slots::SlotTable;
use crate::select::World;

#[derive(Debug)]
pub struct Renderer {
    pub gpu: Gpu,
    pub world: World,
    pub opts: RenderOptions,
    pub slots: SlotTable,
    pub(super) height_range: (f64, f64),
    pub(super) heights: wgpu::Texture,
    pub(super) normals: wgpu::Texture,
    /// The compute pass building normal maps; `None` on the CPU path.
    pub(super) normal_pass: Option<gpu_normals::NormalPass>,
    pub(super) masks: wgpu::Texture,
    pub(super) globals: wgpu::Buffer,
    /// Eye-relative globe tables, rewritten each frame on the globe
    /// (`globe::tables`); one unused entry each on flat datasets.
    pub(super) globe_tables: [wgpu::Buffer; 2],
    pub(super) sampler: wgpu::Sampler,
    /// Draped imagery, a layer per slot (`imagery`).
    pub(super) imagery: ImageryTextures,
    pub(super) bind_group: wgpu::BindGroup,
    pub(super) layout: wgpu::BindGroupLayout,
    pub(super) capture_layout: wgpu::BindGroupLayout,
    pub(super) module: wgpu::ShaderModule,
    pub(super) pipeline: wgpu::RenderPipeline,
    pub(super) index: wgpu::Buffer,
    pub(super) lod_ranges: [std::ops::Range<u32>; 7],
    pub(super) instances: Option<(wgpu::Buffer, u64)>,
    pub(super) colour: wgpu::Texture,
    pub(super) depth: wgpu::Texture,
}

impl Renderer {
    pub fn width(&self) -> u32 {
        self.opts.width
    }

    /// The offscreen frame (RGBA8), for presenting to a window.
    pub fn colour(&self) -> &wgpu::Texture {
        &self.colour
    }

    pub fn height(&self) -> u32 {
        self.opts.height
    }
}
