//! The wgpu renderer (docs/ARCHITECTURE.md#rendering): emulated tessellation with at most
//! 7 instanced terrain draws per frame.
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
//! The renderer ([`Renderer`], in `renderer`) and its settings (`options`) have
//! modules of their own; its parts, one concept each, are `impl Renderer` blocks in
//! private modules: `pipeline` (the device objects and the terrain pipeline,
//! resizing), `draw` (the globals and a frame's draws), `bind_group` (the terrain
//! bind group), `textures` (slot arrays and offscreen targets), `upload` (tiles
//! into their GPU slots), `drape` (imagery draped on them, its textures in
//! `drape_textures`), `capture` (the vertex
//! shader's vertices read back for comparison with the reference tessellator) and
//! `readback` (frames and buffers copied back to the CPU); its errors are
//! [`RenderError`] (`error`).

mod bind_group;
mod capture;
mod drape;
mod drape_textures;
mod draw;
mod error;
pub mod gpu;
mod gpu_normals;
pub mod instances;
pub mod normals;
mod options;
mod pipeline;
pub mod present;
pub mod quality;
mod readback;
pub mod reference;
mod renderer;
pub mod slots;
mod textures;
mod upload;

pub use error::RenderError;
pub use options::{DebugView, DrawStats, HAZE_COLOUR, Parallax, RenderOptions};
pub use renderer::Renderer;
/// PNG files (the charts crate writes them for the reports too).
pub use tessera_charts::png as png_out;
