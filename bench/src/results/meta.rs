//! `meta.json`: when, on what and with which tools the results were measured.

use serde::Deserialize;

/// `meta.json`: when, on what and with which tools the results were measured.
#[derive(Clone, Debug, Deserialize)]
pub struct Meta {
    pub started: String,
    pub finished: String,
    pub commit: String,
    pub dirty: bool,
    pub cpu: String,
    pub cores: u32,
    pub memory_gib: f64,
    pub os: String,
    pub rustc: String,
    /// Peer tools; `null` where one was not installed.
    pub gdal: Option<String>,
    pub nginx: Option<String>,
    pub wrk: Option<String>,
    /// bench/load.sh's peer (absent from results recorded before bench/load.sh ran oha).
    #[serde(default)]
    pub oha: Option<String>,
    /// The wgpu adapter the rendering benchmarks ran on.
    pub renderer: Option<String>,
    /// Repeats per measurement.
    pub runs: u32,
    /// A shortened smoke run: the numbers are not comparable with a full one.
    pub quick: bool,
}
