//! Cesium terrain: tiles meshed (`terrain_mesh.jsonl`) and served
//! (`terrain_serve.jsonl`).

use super::jsonl::{Record, RecordError, positive};
use serde::Deserialize;

/// `terrain_mesh.jsonl`: one Cesium terrain tile meshed by
/// `tests/examples/terrain_mesh.rs` (`bench/terrain.sh`): times, size, triangles and
/// true worst error against every finest sample, beside a regular 65 × 65 heightmap
/// of the same tile and our mesh at that heightmap's error.
#[derive(Clone, Debug, Deserialize)]
pub struct TerrainMesh {
    pub dataset: String,
    pub zoom: u8,
    /// "z/x/y".
    pub tile: String,
    pub run: u32,
    /// Finest samples the tile covers.
    pub samples: f64,
    /// The first mesh, decoding its source tiles.
    pub cold_us: f64,
    /// Median of 5, sources decoded.
    pub mesh_us: f64,
    pub encode_us: f64,
    pub triangles: f64,
    /// True worst vertical error (m) against every finest sample.
    pub error_m: f64,
    /// CesiumJS's geometric error for the zoom (m): what the tile must keep within.
    pub geometric_error_m: f64,
    /// The regular 65 × 65 heightmap (8192 triangles) and its true worst error.
    pub regular_triangles: f64,
    pub regular_error_m: f64,
    /// Our mesh at the regular heightmap's error, and its true worst error.
    pub at_regular_triangles: f64,
    pub at_regular_error_m: f64,
    #[serde(default)]
    pub measured: Option<String>,
    #[serde(default)]
    pub commit: Option<String>,
    #[serde(default)]
    pub loadavg_1m: Option<f64>,
}

impl Record for TerrainMesh {
    const FILE: &'static str = "terrain_mesh.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!("{} {}", self.dataset, self.tile)
    }
    fn check(&self) -> Result<(), RecordError> {
        positive(&[
            ("mesh_us", self.mesh_us),
            ("geometric_error_m", self.geometric_error_m),
            ("regular_triangles", self.regular_triangles),
        ])
    }
}

/// `terrain_serve.jsonl`: one measurement of Cesium terrain tiles served at 64
/// connections (`bench/terrain.sh`): `mode` "cold" (a fresh server, each tile once,
/// `client` "curl -Z") or "warm" (made tiles cached, `client` "wrk").
#[derive(Clone, Debug, Deserialize)]
pub struct TerrainServe {
    pub dataset: String,
    pub zoom: u8,
    pub mode: String,
    pub run: u32,
    pub client: String,
    /// Tiles in the list.
    pub tiles: u32,
    pub connections: u32,
    pub duration_s: f64,
    /// Completed requests (non-2xx included).
    pub requests: f64,
    /// Socket errors.
    pub errors: f64,
    pub non2xx: f64,
    pub p50_ms: f64,
    pub p99_ms: f64,
    /// Mean tile as sent (gzipped when `content_encoding` says so).
    pub mean_tile_bytes: f64,
    /// Mean tile as made and cached (not compressed).
    #[serde(default)]
    pub mean_raw_bytes: Option<f64>,
    #[serde(default)]
    pub content_encoding: Option<String>,
    /// The Accept header sent (CesiumJS's).
    #[serde(default)]
    pub accept: Option<String>,
    /// Peak RSS (VmHWM) of the server.
    pub rss_mib: f64,
    /// The terrain cache's lookups during the measurement (`/metrics`).
    #[serde(default)]
    pub tile_cache_hits: Option<f64>,
    #[serde(default)]
    pub tile_cache_misses: Option<f64>,
    /// The machine's cores (nproc) and the CPUs the server may run on.
    #[serde(default)]
    pub cores: Option<u32>,
    #[serde(default)]
    pub server_cpus: Option<String>,
    #[serde(default)]
    pub measured: Option<String>,
    #[serde(default)]
    pub commit: Option<String>,
    #[serde(default)]
    pub loadavg_1m: Option<f64>,
}

impl TerrainServe {
    /// Tiles delivered (2xx responses) per second.
    pub fn tiles_per_s(&self) -> f64 {
        (self.requests - self.non2xx).max(0.0) / self.duration_s
    }
}

impl Record for TerrainServe {
    const FILE: &'static str = "terrain_serve.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!("{} zoom {} {}", self.dataset, self.zoom, self.mode)
    }
    fn check(&self) -> Result<(), RecordError> {
        positive(&[("duration_s", self.duration_s)])
    }
}
