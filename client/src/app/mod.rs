//! The client's run modes: what each `tessera` command does, built on the library
//! concepts beside `app` (camera, paths, select, stream, render, report). The
//! command line ([`crate::cli`]) parses the arguments and calls into these.
//!
//! - [`fly`]: a flight along a path in real time (`tessera fly`), its per-frame
//!   records and summary;
//! - [`frame_drawer`]: what a flight asks of a renderer, and the rendering figures
//!   it records;
//! - [`settle`]: waiting until the tiles a measured frame needs are resident;
//! - `headless` (feature `render`): rendering inside a flight (`tessera fly --out
//!   DIR`): uploads, PNGs and, with `--quality`, the reference and its comparison;
//! - `window` (feature `render`): the interactive winit client (`tessera fly`
//!   without `--out`);
//! - [`load_test`]: many flights at once against one server (`tessera load`);
//! - [`bench_select`]: the selection alone, timed over a local pyramid
//!   (`tessera bench-select`).

pub mod bench_select;
pub mod fly;
pub mod frame_drawer;
#[cfg(feature = "render")]
pub mod headless;
pub mod load_test;
pub mod settle;
#[cfg(feature = "render")]
pub mod window;
