//! The Tessera client (docs/ARCHITECTURE.md#the-client): view-dependent selection,
//! streaming, the wgpu renderer, and the run modes built on them.
//!
//! - [`camera`]: a perspective camera and its frustum;
//! - [`globe`]: datasets drawn on their body's ellipsoid (ECEF, horizon culling);
//! - [`paths`]: the built-in camera paths and path files, and where they put the eye;
//! - [`select`]: pyramid refinement by screen-space error, Kang's per-tile
//!   quadtrees with power-of-two inner LODs, crack-free edge LODs;
//! - [`tessellate`]: the exact vertex positions a patch produces;
//! - [`stream`]: fetching, decoding and the CPU tile pool;
//! - [`lru`]: the recency list behind the tile pool and the GPU slots;
//! - `render`: the wgpu renderer (emulated tessellation, ≤ 7 terrain draws), with
//!   the default feature `render` only;
//! - [`flight_report`]: contact sheets, plots and animations of a flight, and its
//!   popping metric;
//! - [`loadtest`]: load testing: request traces, their replay on a schedule, the
//!   reports and their merge;
//! - [`app`]: the run modes — flights ([`app::fly`]), headless rendering
//!   (`app::headless`), the interactive window (`app::window`), load tests
//!   ([`app::load_test`]) and the selection benchmark ([`app::bench_select`]);
//! - [`cli`]: the command line of `tessera` and `tessera-load`;
//! - [`output`]: standard output that a closed pipe (`| head -1`) ends quietly;
//! - [`errors`]: an error shown with its causes, for log lines, and the charts
//!   crate's PNG errors.
//!
//! Without the default feature `render` the crate links no wgpu, winit or naga: the
//! load tester (`tessera-load`) is built that way (DECISIONS.md "Load tester and
//! client layout").

pub mod app;
pub mod camera;
pub mod cli;
pub mod errors;
pub mod flight_report;
pub mod globe;
pub mod loadtest;
pub mod lru;
pub mod output;
pub mod paths;
#[cfg(feature = "render")]
pub mod render;
pub mod select;
pub mod stream;
pub mod tessellate;
