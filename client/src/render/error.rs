//! The renderer's errors: no adapter or device, a viewport or tiles the GPU cannot
//! hold, an error the device reported, and readbacks that failed.

use tessera_shared::TileId;

/// Why the renderer could not be made, draw or read back.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(
        "no GPU adapter for {tries}; on Debian/Ubuntu install a software one with `apt-get install --no-install-recommends mesa-vulkan-drivers libegl1 libegl-mesa0 libgl1-mesa-dri`"
    )]
    NoAdapter { tries: String },
    #[error("GPU adapter {name:?} lacks 16-bit normalized textures (R16Unorm)")]
    No16BitTextures { name: String },
    #[error("cannot open the GPU device")]
    Device(#[source] wgpu::RequestDeviceError),
    #[error("GPU error log poisoned")]
    LogPoisoned,
    /// An error the device reported (uncaptured, or the device lost).
    #[error("GPU error on {adapter}: {error}")]
    Reported { adapter: String, error: String },
    #[error("GPU wait failed on {adapter}: {error}")]
    Wait { adapter: String, error: String },
    #[error("viewport {width}x{height} is empty")]
    EmptyViewport { width: u32, height: u32 },
    #[error("viewport {width}x{height} exceeds this GPU's {dim}-pixel limit")]
    ViewportTooLarge { width: u32, height: u32, dim: u32 },
    #[error("{samples}-sample tiles exceed this GPU's {dim}-texel limit")]
    TilesTooLarge { samples: u32, dim: u32 },
    #[error("creating the renderer")]
    Creating(#[source] Box<RenderError>),
    #[error("rendering a frame")]
    Frame(#[source] Box<RenderError>),
    #[error("GPU readback was dropped")]
    ReadbackDropped(#[source] std::sync::mpsc::RecvError),
    #[error("GPU readback failed: {error}")]
    Readback { error: String },
    #[error("tile {tile} has no GPU slot")]
    NoSlot { tile: TileId },
    #[error("no vertices to capture")]
    NothingToCapture,
    #[error("too many vertices to capture at once ({vertices})")]
    TooManyVertices { vertices: usize },
    #[error("imagery of {side} texels per tile side does not fit this GPU's {dim}-texel limit")]
    ImageryTooLarge { side: u32, dim: u32 },
}
