//! Pictures for Tessera's reports (`tessera report`) and benchmarks
//! (`tessera-bench report`), in one small crate that links neither the renderer nor
//! the network stack, so the benchmark report builds without wgpu or tokio.
//!
//! - [`canvas`]: an RGBA8 raster with rectangles, thick lines and text;
//! - [`font`]: a built-in 5×7 bitmap font;
//! - [`plot`]: stacked line plots of per-frame series, the palette and axis colours;
//! - [`png`]: writing (atomically) and reading RGBA8 PNG files;
//! - [`stats`]: the median, axis ranges and the "nice" axis steps both reports use.

pub mod canvas;
pub mod font;
pub mod plot;
pub mod png;
pub mod stats;

pub use font::{draw_text, text_width};
pub use plot::{Series, format_compact, plot_panels};
