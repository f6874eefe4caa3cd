//! The Tessera server: builds tile pyramids from DEMs, checks, describes and draws
//! them, and serves them over HTTP (API.md). Its modules:
//!
//! - [`builder`]: a `.tess` pyramid from DEM rasters, out of core (`tessera-server
//!   build`), reading inputs through [`ingest`] and reprojecting with [`crs`] and
//!   [`approx_transform`]; [`imagery`] builds the imagery pyramid beside it.
//! - [`verify`], [`info`], [`preview`]: `tessera-server verify`, `info` and
//!   `preview` of a built pyramid.
//! - [`serve`]: the API (`tessera-server serve`): datasets, routes, computed-response
//!   admission, the built-in viewer, on the HTTP plumbing of [`http`], reading
//!   pyramids from local files or object stores through [`storage`].
//! - Derived outputs the routes compute: [`web`] (standard web-map tiles),
//!   [`cesium`] (quantized-mesh terrain) with [`geoid`] heights, and
//!   [`elevation`] (heights of points and profiles with their error bounds), which
//!   [`query`] (`tessera-server query`) answers on the command line; [`export`]
//!   (`tessera-server export`) writes the standard-grid tiles into PMTiles archives.
//! - [`fuzzing`]: the parsers' fuzz entry points (`./run fuzz`, RELIABILITY.md).

pub mod approx_transform;
pub mod builder;
pub mod cesium;
pub mod crs;
pub mod elevation;
pub mod export;
pub mod fuzzing;
pub mod geoid;
pub mod http;
pub mod imagery;
pub mod info;
pub mod ingest;
pub mod preview;
pub mod query;
pub mod serve;
pub mod storage;
pub mod verify;
pub mod web;
