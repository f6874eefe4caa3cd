//! The results directory that `./run bench` writes, read into typed records.
//!
//! The runner is bash; this is where its output meets a schema. Each record type
//! names only the fields the report uses, so the runner may add more, but a
//! missing or mistyped field is an error naming the file and line. A missing file
//! is not an error: that benchmark was not run, and its section says so.
//! Every record carries the 1-based `run` it belongs to; two records for the same
//! measurement and run are an error (a runner that appended twice).

mod build;
pub(crate) mod flights;
mod jsonl;
mod meta;
mod serving;
mod terrain;
mod webtiles;

pub use build::{Build, Ingest};
pub use flights::{Frame, Gonzalez, GpuRun, PolicyFlight, Select, Stream};
pub use meta::Meta;
pub use serving::{Load, LoadReplay, Serve};
pub use terrain::{TerrainMesh, TerrainServe};
pub use webtiles::{WebTile, WebTileCheck};

use anyhow::{Context, bail};
use jsonl::load_jsonl;
use std::path::Path;

/// Everything in a results directory; `None` for a benchmark that was not run.
#[derive(Debug, Default)]
pub struct Results {
    pub meta: Option<Meta>,
    pub build: Option<Vec<Build>>,
    pub serve: Option<Vec<Serve>>,
    pub load: Option<Vec<Load>>,
    pub loadreplay: Option<Vec<LoadReplay>>,
    pub policy: Option<Vec<PolicyFlight>>,
    pub gonzalez: Option<Vec<Gonzalez>>,
    pub stream: Option<Vec<Stream>>,
    pub select: Option<Vec<Select>>,
    pub gpu: Option<Vec<GpuRun>>,
    pub ingest: Option<Vec<Ingest>>,
    pub webtiles: Option<Vec<WebTile>>,
    pub webtiles_check: Option<Vec<WebTileCheck>>,
    pub terrain_mesh: Option<Vec<TerrainMesh>>,
    pub terrain_serve: Option<Vec<TerrainServe>>,
}

impl Results {
    pub fn load(dir: &Path) -> anyhow::Result<Self> {
        if !dir.is_dir() {
            bail!("{}: not a directory of benchmark results", dir.display());
        }
        let meta_path = dir.join("meta.json");
        let meta = match std::fs::read_to_string(&meta_path) {
            Ok(text) => Some(
                serde_json::from_str(&text)
                    .with_context(|| format!("{}: not valid metadata", meta_path.display()))?,
            ),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
            Err(e) => {
                return Err(e).with_context(|| format!("{}: cannot read", meta_path.display()));
            }
        };
        Ok(Self {
            meta,
            build: load_jsonl(dir)?,
            serve: load_jsonl(dir)?,
            load: load_jsonl(dir)?,
            loadreplay: load_jsonl(dir)?,
            policy: load_jsonl(dir)?,
            gonzalez: load_jsonl(dir)?,
            stream: load_jsonl(dir)?,
            select: load_jsonl(dir)?,
            gpu: load_jsonl(dir)?,
            ingest: load_jsonl(dir)?,
            webtiles: load_jsonl(dir)?,
            webtiles_check: load_jsonl(dir)?,
            terrain_mesh: load_jsonl(dir)?,
            terrain_serve: load_jsonl(dir)?,
        })
    }
}
