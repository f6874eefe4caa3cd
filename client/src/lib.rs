//! The Tessera client (DESIGN §5): view-dependent selection, streaming, the wgpu
//! renderer, and the run modes built on them.
//!
//! - [`camera`]: a perspective camera and its frustum;
//! - [`paths`]: the built-in camera paths and path files, and where they put the eye;
//! - [`select`]: pyramid refinement by screen-space error, Kang's per-tile
//!   quadtrees with power-of-two inner LODs, crack-free edge LODs;
//! - [`tessellate`]: the exact vertex positions a patch produces;
//! - [`stream`]: fetching, decoding and the CPU tile pool;
//! - [`lru`]: the recency list behind the tile pool and the GPU slots;
//! - [`render`]: the wgpu renderer (emulated tessellation, ≤ 7 terrain draws);
//! - [`report`]: contact sheets and plots of a flight;
//! - [`app`]: the run modes — flights ([`app::fly`]), headless rendering
//!   ([`app::headless`]), the interactive window ([`app::window`]), load tests
//!   ([`app::load_test`]) and the selection benchmark ([`app::bench_select`]).

pub mod app;
pub mod camera;
pub mod globe;
pub mod load;
pub mod lru;
pub mod paths;
pub mod render;
pub mod report;
pub mod select;
pub mod stream;
pub mod tessellate;
