//! The contract between the Tessera server and client.
//!
//! Everything both sides must agree on lives here and nowhere else
//! (docs/ARCHITECTURE.md#crates). Its modules:
//!
//! - Tiles and their order: tile ids, levels and tile geometry ([`tile`]), Morton codes
//!   and ranges ([`morton`]), the `ranges=` query ([`range_query`]).
//! - The pyramid file: its format ([`format`](mod@format), written down in `FORMAT.md`),
//!   dataset metadata ([`metadata`]), the tile-record codec ([`codec`]), tile validity
//!   masks ([`mask`]), error tables ([`error_table`]), the surface a tile is
//!   triangulated into ([`triangulation`]), imagery pyramids ([`imagery`]) and a reader
//!   that works over any source of byte ranges ([`reader`]).
//! - The wire: the HTTP API's paths and documents ([`api`]), the tile stream ([`wire`])
//!   and its verification as it arrives ([`frame_scan`]), the bootstrap ([`bootstrap`])
//!   and its focus ([`focus`]).
//! - The body a dataset lies on ([`body`]) and its ellipsoid ([`ellipsoid`]).
//! - Fuzzing entry points for this crate's parsers ([`fuzzing`]).
//! - With the `testdata` feature, for tests in every crate: the real DEMs beside the
//!   repository (`testdata`), small fixtures (`fixtures`), a real S3 server on loopback
//!   (`s3_server`) and `--help` snapshots (`cli_help`).
pub mod api;
pub mod body;
pub mod bootstrap;
pub mod codec;
pub mod ellipsoid;
pub mod error_table;
pub mod focus;
pub mod format;
pub mod frame_scan;
pub mod fuzzing;
pub mod imagery;
pub mod mask;
pub mod metadata;
pub mod morton;
pub mod range_query;
pub mod reader;
pub mod tile;
pub mod triangulation;
pub mod wire;

#[cfg(feature = "testdata")]
pub mod cli_help;
#[cfg(feature = "testdata")]
pub mod fixtures;
#[cfg(feature = "testdata")]
pub mod s3_server;
#[cfg(feature = "testdata")]
pub mod testdata;

pub use error_table::ErrorTable;
pub use mask::CellMask;
pub use metadata::{
    GeoRef, GroundSpacing, LevelCounts, Metadata, Quantization, RasterType, SourceRecord,
    VerticalDatum,
};
pub use morton::{Morton, MortonRange};
pub use reader::{ByteSource, FileSource, Pyramid};
pub use tile::{Level, TileGeometry, TileId};
