//! Timed commands that write pyramids: builds (`build.jsonl`) and ingest steps
//! (`ingest.jsonl`).

use super::jsonl::{Record, RecordError, positive};
use serde::Deserialize;

/// `build.jsonl`: one pyramid build (`tool` is "tessera" or "gdal").
#[derive(Clone, Debug, Deserialize)]
pub struct Build {
    pub tool: String,
    pub input: String,
    pub run: u32,
    pub wall_s: f64,
    pub cpu_s: f64,
    pub rss_mib: f64,
    /// The output file(s), all levels.
    pub bytes: f64,
    /// DEM samples in the input.
    pub samples: f64,
}

impl Record for Build {
    const FILE: &'static str = "build.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!("{} {}", self.tool, self.input)
    }
    fn check(&self) -> Result<(), RecordError> {
        positive(&[("wall_s", self.wall_s), ("samples", self.samples)])
    }
}

/// `ingest.jsonl`: one timed command of `bench/ingest.sh` (`case` "mosaic",
/// "reproject" or "mixed"; `samples` are the input's).
#[derive(Clone, Debug, Deserialize)]
pub struct Ingest {
    pub case: String,
    pub tool: String,
    pub run: u32,
    pub samples: f64,
    pub wall_s: f64,
    pub cpu_s: f64,
    pub rss_mib: f64,
    /// The build's `--memory` budget in MiB, where the case sets one.
    #[serde(default)]
    pub memory_mib: Option<f64>,
}

impl Record for Ingest {
    const FILE: &'static str = "ingest.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!("{} {}", self.case, self.tool)
    }
    fn check(&self) -> Result<(), RecordError> {
        positive(&[("wall_s", self.wall_s), ("samples", self.samples)])
    }
}
