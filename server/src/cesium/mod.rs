//! Cesium terrain (DECISIONS.md "Cesium terrain", docs/ARCHITECTURE.md#derived-outputs):
//! quantized-mesh-1.0 tiles over the EPSG:4326 TMS grid ([`tiling`]), meshed adaptively
//! from the pyramid and its error tables ([`mesh`]), heights on the body's ellipsoid
//! ([`ellipsoid`], and the geoid in [`crate::geoid`]), encoded as the format says
//! ([`quantized_mesh`]); [`terrain`] puts one tile together.

pub mod ellipsoid;
pub mod mesh;
pub mod quantized_mesh;
pub mod terrain;
pub mod tiling;
