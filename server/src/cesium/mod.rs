//! Cesium terrain (DECISIONS.md "Cesium terrain", docs/ARCHITECTURE.md#derived-outputs):
//! quantized-mesh-1.0 tiles over the EPSG:4326 TMS grid ([`tiling`]), meshed adaptively
//! from the pyramid and its error tables ([`mesh`]), heights on the body's ellipsoid
//! ([`tessera_shared::ellipsoid`], and the geoid in [`crate::geoid`]), encoded as the
//! format says ([`quantized_mesh`], with the header's bounds and the normals' codes in
//! [`header_geometry`]); [`terrain`] puts one tile together.

pub mod greedy;
pub mod header_geometry;
pub mod mesh;
pub mod quantized_mesh;
pub mod side;
pub mod surface;
pub mod terrain;
pub mod tiles3d;
pub mod tiling;
