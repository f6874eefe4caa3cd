//! The Tessera client: view-dependent selection of what to draw (DESIGN §5), and
//! the reference tessellator the renderer must match.
//!
//! - [`camera`]: a perspective camera and its frustum;
//! - [`select`]: pyramid refinement by screen-space error, Kang's per-tile
//!   quadtrees with power-of-two inner LODs, crack-free edge LODs;
//! - [`tessellate`]: the exact vertex positions a patch produces.
//!
//! Streaming, fly-through paths and the load generator come next (issue 4).

pub mod camera;
pub mod fly;
pub mod load;
pub mod paths;
pub mod render;
pub mod select;
pub mod stream;
pub mod tessellate;
