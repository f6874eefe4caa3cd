//! The Tessera server: builds tile pyramids from DEMs ([`build`], reading inputs
//! through [`ingest`]), checks them ([`verify`]), describes them ([`info`]), draws
//! them ([`preview`]) and serves them over HTTP ([`serve`], API.md). [`fuzzing`]
//! holds the parsers' fuzz entry points (`./run fuzz`, RELIABILITY.md).

pub mod approx_transform;
pub mod build;
pub mod cesium;
pub mod crs;
pub mod fuzzing;
pub mod geoid;
pub mod http;
pub mod imagery;
pub mod info;
pub mod ingest;
pub mod preview;
pub mod serve;
pub mod storage;
pub mod verify;
pub mod web;
