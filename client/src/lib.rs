//! The Tessera client (DESIGN §5): view-dependent selection, streaming, the wgpu
//! renderer, headless fly-throughs and the load generator.
//!
//! - [`camera`]: a perspective camera and its frustum;
//! - [`select`]: pyramid refinement by screen-space error, Kang's per-tile
//!   quadtrees with power-of-two inner LODs, crack-free edge LODs;
//! - [`tessellate`]: the exact vertex positions a patch produces;
//! - [`stream`]: fetching, decoding and the CPU tile pool;
//! - [`lru`]: the recency list behind the tile pool and the GPU slots;
//! - [`render`]: the wgpu renderer (emulated tessellation, ≤ 7 terrain draws);
//! - [`fly`], [`headless`], [`load`]: flights, headless rendering, load tests;
//! - [`paths`]: the built-in camera paths and path files, and where they put the eye;
//! - [`report`]: contact sheets and plots of a flight;
//! - [`window`]: the interactive winit client.

pub mod camera;
pub mod fly;
pub mod headless;
pub mod load;
pub mod lru;
pub mod paths;
pub mod render;
pub mod report;
pub mod select;
pub mod stream;
pub mod tessellate;
pub mod window;
