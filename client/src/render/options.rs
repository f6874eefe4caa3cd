//! The renderer's settings (what `tessera fly` chooses: view, parallax, backend,
//! normal maps, morphing, imagery) and what a frame reports.

use super::gpu::Backend;
use super::normals;

/// The colour distant terrain fades to (RGB, 0–1, as written to the frame); how
/// much of it a point takes follows the air between it and the eye (`terrain.wgsl`
/// `haze_amount`).
pub const HAZE_COLOUR: [f32; 3] = [0.74, 0.80, 0.88];

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
    /// Patches whose tile had no GPU slot (0 when selection used [`super::slots::OnGpu`]).
    pub skipped: u32,
    /// CPU time to encode and submit, and wait for the GPU, in milliseconds.
    pub render_ms: f64,
}
