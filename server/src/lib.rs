//! The Tessera server: builds tile pyramids from DEMs ([`build`], reading inputs
//! through [`ingest`]), checks them ([`verify`]) and describes them ([`info`]).
//! HTTP serving arrives in the next issue.

pub mod build;
pub mod info;
pub mod ingest;
pub mod verify;
