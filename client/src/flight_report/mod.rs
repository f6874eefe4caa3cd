//! Pictures of a headless fly-through, for people to look at: a contact sheet of
//! rendered frames, line plots of per-frame statistics and an animated PNG of the
//! frames ([`animation`]).
//!
//! Everything here is plain CPU raster code on RGBA8 buffers (no GPU, no
//! dependencies): functions return `(rgba, width, height)` and the caller writes
//! the PNG, normally with [`tessera_charts::png::write_png`].
//!
//! - [`contact_sheet()`]: frames downscaled by area averaging and tiled in a grid,
//!   each labelled with its frame number; [`pick_evenly`] chooses which frames.
//! - [`plot`]: one panel per [`Series`] ("triangles", "draw calls", …), stacked
//!   over a shared x axis of frame numbers.
//! - [`font`]: the 5×7 bitmap font both use for labels.
//!
//! Writing `stats.png` and `frames.png` after a flight:
//!
//! ```no_run
//! use std::path::Path;
//! use tessera_charts::png::write_png;
//! use tessera_client::flight_report::{Series, contact_sheet_labelled, pick_evenly_indices, plot_panels};
//!
//! # fn main() -> anyhow::Result<()> {
//! # let (triangles, draw_calls, frame_ms) = (vec![0.0], vec![0.0], vec![0.0]);
//! # let frames: Vec<(Vec<u8>, u32, u32)> = Vec::new();
//! // One value per frame; NaN where a frame has no measurement.
//! let series = [
//!     Series::new("triangles", "", triangles),
//!     Series::new("draw calls", "", draw_calls),
//!     Series::new("frame time", "ms", frame_ms),
//! ];
//! let (rgba, w, h) = plot_panels(&series, "frame", 1200, 200);
//! write_png(Path::new("stats.png"), &rgba, w, h)?;
//!
//! // Twelve frames spread over the flight, labelled with their frame numbers.
//! let picked = pick_evenly_indices(frames.len(), 12);
//! let thumbs: Vec<_> = picked.iter().map(|&i| frames[i].clone()).collect();
//! let labels: Vec<String> = picked.iter().map(|i| format!("#{i}")).collect();
//! let (rgba, w, h) = contact_sheet_labelled(&thumbs, &labels, 4, 320);
//! write_png(Path::new("frames.png"), &rgba, w, h)?;
//! # Ok(())
//! # }
//! ```

pub mod animation;
pub mod contact_sheet;
pub mod flight;
pub mod popping;
// The raster, font and plots live in `tessera-charts`, shared with the benchmarks.
pub use tessera_charts::{canvas, font, plot};

pub use contact_sheet::{contact_sheet, contact_sheet_labelled, pick_evenly, pick_evenly_indices};
pub use font::{draw_text, text_width};
pub use plot::{Series, format_compact, plot_panels};
