//! The Tessera server: builds tile pyramids from DEMs ([`build`], reading inputs
//! through [`ingest`]), checks them ([`verify`]), describes them ([`info`]) and draws them ([`preview`]).
//! HTTP serving arrives in the next issue.

pub mod build;
pub mod fuzzing;
pub mod info;
pub mod ingest;
pub mod preview;
pub mod serve;
pub mod verify;
