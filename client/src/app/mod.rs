//! The client's run modes: what each `tessera` command does, built on the library
//! concepts beside `app` (camera, paths, select, stream, render, report). The
//! binary (`main.rs`) parses the command line and calls into these.
//!
//! - [`fly`]: a flight along a path in real time (`tessera fly`), its per-frame
//!   records and summary;
//! - [`headless`]: rendering inside a flight (`tessera fly --out DIR`): uploads,
//!   PNGs and, with `--quality`, the reference and its comparison;
//! - [`window`]: the interactive winit client (`tessera fly` without `--out`);
//! - [`load_test`]: many flights at once against one server (`tessera load`);
//! - [`bench_select`]: the selection alone, timed over a local pyramid
//!   (`tessera bench-select`).

pub mod bench_select;
pub mod fly;
pub mod headless;
pub mod load_test;
pub mod window;
