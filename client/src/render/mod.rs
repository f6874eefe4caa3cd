//! The wgpu renderer (DESIGN §5): emulated tessellation with at most 7 instanced
//! terrain draws per frame.
//!
//! - Heights live in an `R16Unorm` 2-D texture array, one layer ("slot") per
//!   resident tile ([`slots`]), with a normal map ([`normals`]) and the tile's
//!   cell mask (`R8Unorm`, `T × T`, 1 = terrain) beside it; the fragment shader
//!   discards fragments of cells that are not terrain (no-data and the padding
//!   beyond the DEM), or shows them in a colour of their own in
//!   [`DebugView::Mask`].
//! - One index buffer range per inner LOD `n ∈ {1, 2, …, 64}`; the vertex shader
//!   derives grid coordinates from the vertex index and reads heights with integer
//!   texel loads, snapping edge vertices as the reference tessellator does
//!   (`terrain.wgsl`, [`crate::tessellate`]).
//! - Parallax in the fragment shader (González §2.2–2.4) moves where the normal
//!   and height maps are read.
//!
//! Rendering is offscreen into an RGBA8 target; [`Renderer::read_rgba`] reads it
//! back for PNGs and quality measures, and the windowed client copies it to the
//! window.
//!
//! The renderer's parts, one concept each, are `impl Renderer` blocks in private
//! modules: `pipeline` (the device objects and the terrain pipeline, drawing a
//! frame, resizing), `upload` (tiles into their GPU slots), `capture` (the
//! vertex shader's vertices read back for comparison with the reference
//! tessellator) and `readback` (frames and buffers copied back to the CPU).

mod capture;
pub mod gpu;
mod gpu_normals;
mod imagery;
pub mod instances;
pub mod normals;
mod pipeline;
/// PNG files (the charts crate writes them for the reports too).
pub use tessera_charts::png as png_out;
pub mod present;
pub mod quality;
mod readback;
pub mod reference;
pub mod slots;
mod upload;

/// The colour distant terrain fades to (RGB, 0–1, as written to the frame); how
/// much of it a point takes follows the air between it and the eye (`terrain.wgsl`
/// `haze_amount`).
pub const HAZE_COLOUR: [f32; 3] = [0.74, 0.80, 0.88];

use crate::select::World;
use gpu::{Backend, Gpu};
use slots::SlotTable;

/// What the fragment shader shows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DebugView {
    /// Lambert lighting with a hypsometric tint.
    #[default]
    Shaded,
    /// Colour by inner LOD.
    Lod,
    /// Colour by pyramid level.
    Level,
    /// Shaded, with the triangles drawn over it.
    Wireframe,
    /// Shaded, with the cells that are not terrain (no-data, padding beyond the
    /// DEM) drawn in red instead of discarded.
    Mask,
}

/// Parallax mapping over the tessellated base surface (González §2.2–2.4).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Parallax {
    #[default]
    None,
    /// Offset limiting (threshold 0.5).
    Offset,
    /// Two iterations of offset parallax.
    Iterative,
    /// Binary search, 3 steps, then a secant step.
    Binary,
}

#[derive(Clone, Copy, Debug)]
pub struct RenderOptions {
    pub width: u32,
    pub height: u32,
    /// Tiles the GPU holds at once (texture-array layers).
    pub slots: u32,
    pub view: DebugView,
    pub parallax: Parallax,
    pub backend: Backend,
    /// Where normal maps are built (GPU unless asked otherwise).
    pub normals: normals::NormalSource,
    /// Draw patches morphed as selection says ([`crate::select::morph`]); off
    /// (`tessera fly --no-morph`), every patch at its own LOD, and LOD changes pop.
    pub morph: bool,
    /// Drape the dataset's imagery when it has some; off (`--no-imagery`), the
    /// hypsometric tint.
    pub imagery: bool,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            width: 1280,
            height: 720,
            slots: 256,
            view: DebugView::Shaded,
            parallax: Parallax::None,
            backend: Backend::Auto,
            normals: normals::NormalSource::Gpu,
            morph: true,
            imagery: true,
        }
    }
}

/// What one frame cost and drew.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct DrawStats {
    pub draw_calls: u32,
    pub instances: u32,
    /// Patches whose tile had no GPU slot (0 when selection used [`slots::OnGpu`]).
    pub skipped: u32,
    /// CPU time to encode and submit, and wait for the GPU, in milliseconds.
    pub render_ms: f64,
}

#[derive(Debug)]
pub struct Renderer {
    pub gpu: Gpu,
    pub world: World,
    pub opts: RenderOptions,
    pub slots: SlotTable,
    height_range: (f64, f64),
    heights: wgpu::Texture,
    normals: wgpu::Texture,
    /// The compute pass building normal maps; `None` on the CPU path.
    normal_pass: Option<gpu_normals::NormalPass>,
    masks: wgpu::Texture,
    globals: wgpu::Buffer,
    /// Eye-relative globe tables, rewritten each frame on the globe
    /// (`globe::tables`); one unused entry each on flat datasets.
    globe_tables: [wgpu::Buffer; 2],
    sampler: wgpu::Sampler,
    /// Draped imagery, a layer per slot (`imagery`).
    imagery: imagery::ImageryTextures,
    bind_group: wgpu::BindGroup,
    layout: wgpu::BindGroupLayout,
    capture_layout: wgpu::BindGroupLayout,
    module: wgpu::ShaderModule,
    pipeline: wgpu::RenderPipeline,
    index: wgpu::Buffer,
    lod_ranges: [std::ops::Range<u32>; 7],
    instances: Option<(wgpu::Buffer, u64)>,
    colour: wgpu::Texture,
    depth: wgpu::Texture,
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
