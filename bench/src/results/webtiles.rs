//! Standard-grid web tiles against TiTiler: throughput rows (`webtiles.jsonl`) and
//! landmark pixels decoded from both (`webtiles_check.jsonl`).

use super::jsonl::{Record, RecordError, positive};
use serde::Deserialize;

/// `webtiles.jsonl`: one measurement of `bench/webtiles.sh` — Web Mercator 512 px
/// Terrarium tiles from Tessera (`mode` "cold", "source-warm", "warm") or TiTiler
/// ("cold": its first pass; "warm": wrk afterwards). `client` is "curl -Z" for a
/// single pass over the tile list, "wrk" for a fixed duration cycling through it.
#[derive(Clone, Debug, Deserialize)]
pub struct WebTile {
    pub dataset: String,
    pub server: String,
    pub mode: String,
    pub run: u32,
    pub client: String,
    /// Tiles in the list.
    pub tiles: u32,
    pub connections: u32,
    pub duration_s: f64,
    /// Completed requests (non-2xx included).
    pub requests: f64,
    /// Socket errors (connect, read, write, timeout).
    pub errors: f64,
    pub non2xx: f64,
    pub p50_ms: f64,
    pub p99_ms: f64,
    pub mean_tile_bytes: f64,
    /// Peak RSS (VmHWM) of the server, all its processes.
    pub rss_mib: f64,
    /// Tessera's made-tile cache lookups during the measurement (`/metrics`).
    #[serde(default)]
    pub tile_cache_hits: Option<f64>,
    #[serde(default)]
    pub tile_cache_misses: Option<f64>,
    pub titiler_workers: u32,
    pub titiler_version: String,
    /// When (UTC) and on which commit ("+dirty": with uncommitted changes), since
    /// this section may be rerun alone (`KEEP_RESULTS=1 bench/all.sh webtiles`).
    #[serde(default)]
    pub measured: Option<String>,
    #[serde(default)]
    pub commit: Option<String>,
    /// The machine's 1-minute load average when the row ended (others may share it).
    #[serde(default)]
    pub loadavg_1m: Option<f64>,
}

impl WebTile {
    /// Tiles delivered (2xx responses) per second.
    pub fn tiles_per_s(&self) -> f64 {
        (self.requests - self.non2xx).max(0.0) / self.duration_s
    }
}

impl Record for WebTile {
    const FILE: &'static str = "webtiles.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!("{} {} {}", self.dataset, self.server, self.mode)
    }
    fn check(&self) -> Result<(), RecordError> {
        positive(&[("duration_s", self.duration_s)])
    }
}

/// `webtiles_check.jsonl`: one landmark pixel of one web tile, decoded from both
/// servers' Terrarium PNGs (`null` where the pixel is transparent: no data).
#[derive(Clone, Debug, Deserialize)]
pub struct WebTileCheck {
    pub dataset: String,
    pub landmark: String,
    pub lon: f64,
    pub lat: f64,
    /// "z/x/y".
    pub tile: String,
    pub pixel: [u32; 2],
    pub tessera_m: Option<f64>,
    pub titiler_m: Option<f64>,
    /// TiTiler's tile size as gdalinfo writes it ("512, 512").
    pub titiler_size: String,
    pub run: u32,
}

impl Record for WebTileCheck {
    const FILE: &'static str = "webtiles_check.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!("{} {}", self.dataset, self.landmark)
    }
}
