//! Small fixtures for tests in every crate (enabled, like [`crate::testdata`], by
//! the `testdata` feature).

use crate::metadata::{Metadata, Quantization};
use crate::tile::TileGeometry;

/// Plausible metadata of a `width × height` DEM cut into `tile_size`-cell tiles: the
/// level count follows the geometry, heights are stored exactly (`h = q − 1000`,
/// 0.5 m steps), no georeferencing, and a well-formed content hash. Tests change the
/// fields they care about with struct-update syntax.
pub fn metadata(width: u32, height: u32, tile_size: u32) -> Metadata {
    let levels = TileGeometry::new(width, height, tile_size)
        .expect("a valid test geometry")
        .level_count();
    Metadata {
        width,
        height,
        tile_size,
        levels,
        quantization: Quantization {
            offset: -1000.0,
            scale: 0.5,
            max_error: 0.0,
        },
        min_height: -1000.0,
        max_height: 3500.0,
        nodata_count: 0,
        nodata_fill: "none".into(),
        georef: None,
        ground_spacing: None,
        vertical_datum: crate::metadata::VerticalDatum::Unknown,
        level_counts: Vec::new(),
        source: "test".into(),
        generator: "test".into(),
        content_hash: "0123456789abcdef".into(),
        sources: Vec::new(),
    }
}
