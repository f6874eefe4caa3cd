//! The results directory that `./run bench` writes, read into typed records.
//!
//! The runner is bash; this is where its output meets a schema. Each record type
//! names only the fields the report uses, so the runner may add more, but a
//! missing or mistyped field is an error naming the file and line. A missing file
//! is not an error: that benchmark was not run, and its section says so.
//! Every record carries the 1-based `run` it belongs to; two records for the same
//! measurement and run are an error (a runner that appended twice).

use anyhow::{Context, bail};
use serde::Deserialize;
use serde::de::DeserializeOwned;
use std::collections::HashMap;
use std::path::Path;

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
    /// bench/load.sh's peer (absent from results older than issue 18).
    #[serde(default)]
    pub oha: Option<String>,
    /// The wgpu adapter the rendering benchmarks ran on.
    pub renderer: Option<String>,
    /// Repeats per measurement.
    pub runs: u32,
    /// A shortened smoke run: the numbers are not comparable with a full one.
    pub quick: bool,
}

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

/// `serve.jsonl`: one wrk row against Tessera or nginx.
#[derive(Clone, Debug, Deserialize)]
pub struct Serve {
    /// "tessera" or "nginx".
    pub server: String,
    /// "batch", "single" or "static".
    pub request: String,
    pub tiles_per_request: u32,
    pub connections: u32,
    pub run: u32,
    pub duration_s: f64,
    /// Completed requests.
    pub requests: f64,
    /// Socket errors plus non-2xx responses.
    pub errors: f64,
    pub p50_ms: f64,
    pub p99_ms: f64,
    pub mean_tile_bytes: f64,
    /// Bytes wrk read during the row, headers and responses still in flight at its
    /// end included (wrk counts every read).
    #[serde(default)]
    pub wrk_bytes: Option<f64>,
    /// User + system CPU seconds of the server's processes during the row (nginx:
    /// master and workers); absent in results from before it was recorded.
    #[serde(default)]
    pub server_cpu_s: Option<f64>,
    /// wrk's own CPU seconds.
    #[serde(default)]
    pub wrk_cpu_s: Option<f64>,
    /// Busy CPU seconds of the whole machine during the row (every process).
    #[serde(default)]
    pub machine_cpu_s: Option<f64>,
}

impl Serve {
    pub fn requests_per_s(&self) -> f64 {
        self.requests / self.duration_s
    }

    pub fn tiles_per_s(&self) -> f64 {
        self.requests_per_s() * f64::from(self.tiles_per_request)
    }

    /// Tile payload in MB (10⁶ bytes) per second, headers not counted.
    pub fn payload_mb_per_s(&self) -> f64 {
        self.tiles_per_s() * self.mean_tile_bytes / 1e6
    }

    /// GB (10⁹ bytes) the CPU of the row was spent on: what wrk read (responses
    /// still in flight when the row ends count; with megabyte responses at 1024
    /// connections that is most of them), else the completed requests' tile payload.
    /// Headers are under 0.3% of either.
    fn delivered_gb(&self) -> f64 {
        self.wrk_bytes.unwrap_or_else(|| {
            self.requests * f64::from(self.tiles_per_request) * self.mean_tile_bytes
        }) / 1e9
    }

    /// The server's CPU seconds per GB delivered; `None` where not recorded or
    /// nothing was delivered.
    pub fn server_cpu_s_per_gb(&self) -> Option<f64> {
        let gb = self.delivered_gb();
        self.server_cpu_s.filter(|_| gb > 0.0).map(|s| s / gb)
    }

    /// wrk's CPU seconds per GB delivered.
    pub fn wrk_cpu_s_per_gb(&self) -> Option<f64> {
        let gb = self.delivered_gb();
        self.wrk_cpu_s.filter(|_| gb > 0.0).map(|s| s / gb)
    }

    /// CPU seconds of everything but the server and wrk during the row, per second:
    /// the other load on the machine (cores' worth).
    pub fn other_cores(&self) -> Option<f64> {
        let other = self.machine_cpu_s? - self.server_cpu_s? - self.wrk_cpu_s?;
        Some((other / self.duration_s).max(0.0))
    }
}

/// `load.jsonl`: one `tessera load --json` run (`mode` "ranges" or "single").
#[derive(Clone, Debug, Deserialize)]
pub struct Load {
    pub mode: String,
    pub run: u32,
    pub clients: u32,
    pub requests_per_s: f64,
    pub tiles_per_s: f64,
    pub mb_per_s: f64,
    pub latency_ms_p50: f64,
    pub latency_ms_p90: f64,
    pub latency_ms_p99: f64,
    pub latency_ms_max: f64,
    pub errors: f64,
    /// Fraction (0–1) of all clients' frames within 2τ.
    pub frames_within_2tau: f64,
}

/// `loadreplay.jsonl` (bench/load.sh, issue 18): one load generator replaying the
/// targets of one recorded trace, at saturation (`phase` "saturation": closed loop,
/// `--rate max`) or at a constant arrival rate (`phase` "half": half of Tessera's
/// saturation requests/s in the same run).
#[derive(Clone, Debug, Deserialize)]
pub struct LoadReplay {
    /// "tessera" (`tessera load --replay`), "wrk", "oha".
    pub tool: String,
    pub phase: String,
    pub run: u32,
    pub connections: u32,
    pub seconds: f64,
    pub requests_per_s: f64,
    /// Tessera's own count; for wrk and oha requests/s × the trace's mean tiles per
    /// request.
    pub tiles_per_s: f64,
    pub latency_ms_p50: f64,
    pub latency_ms_p99: f64,
    pub latency_ms_p999: Option<f64>,
    /// "closed loop" (from the actual send) or "scheduled" (from the scheduled start:
    /// coordinated omission corrected).
    pub latency_from: String,
    /// The arrival rate asked for (phase "half").
    #[serde(default)]
    pub target_rate: Option<f64>,
    #[serde(default)]
    pub rate_held: Option<bool>,
    pub errors: f64,
    /// User + system CPU seconds of the load generator over the run (GNU time).
    #[serde(default)]
    pub tool_cpu_s: Option<f64>,
    /// The replayed requests (the trace's with a recorded 200 answer) and their mean
    /// tiles per request.
    pub trace_requests: u64,
    pub trace_mean_tiles: f64,
}

/// One line of a rendered flight's `stats.jsonl` (only what the report uses).
#[derive(Clone, Debug, Deserialize)]
pub struct Frame {
    pub triangles: u64,
    pub draw_calls: u32,
    pub render_ms: f64,
    /// Drawing what the policy asks for (no stand-ins); absent counts as yes.
    #[serde(default)]
    pub converged: Option<bool>,
    /// On measured frames only (`--quality`).
    #[serde(default)]
    pub mse: Option<f64>,
    #[serde(default)]
    pub psnr: Option<f64>,
}

impl Frame {
    /// Something was drawn.
    pub fn drawn(&self) -> bool {
        self.triangles > 0
    }

    /// Compared against the full-resolution reference while drawing what the
    /// policy asks for.
    pub fn measured(&self) -> bool {
        self.psnr.is_some() && self.converged != Some(false)
    }
}

/// `policy.jsonl`: one rendered flight with the screen-error or distance policy.
#[derive(Clone, Debug, Deserialize)]
pub struct PolicyFlight {
    pub dataset: String,
    /// Flight path ("canyon", "pass").
    pub path: String,
    /// "screen-error" or "distance".
    pub policy: String,
    pub tau: f64,
    pub run: u32,
    pub frames: Vec<Frame>,
}

/// `gonzalez.jsonl`: one rendered flight with a parallax mode.
#[derive(Clone, Debug, Deserialize)]
pub struct Gonzalez {
    pub dataset: String,
    pub path: String,
    pub tau: f64,
    /// "none", "offset", "iterative" or "binary".
    pub parallax: String,
    pub run: u32,
    pub frames: Vec<Frame>,
}

/// The streaming totals of a flight summary.
#[derive(Clone, Debug, Deserialize)]
pub struct StreamTotals {
    pub requests: f64,
    pub bytes: f64,
}

/// The parts of `tessera fly`'s summary that the streaming section uses.
#[derive(Clone, Debug, Deserialize)]
pub struct FlySummary {
    /// Fractions (0–1) of frames with deficit ≤ 1 and ≤ 2.
    pub within_tau: f64,
    pub within_2tau: f64,
    pub warmup_frames: u32,
    pub steady_within_2tau: f64,
    pub p99_stream_us: f64,
    pub stream: StreamTotals,
}

/// `stream.jsonl`: one `tessera fly --no-render` flight behind the delaying proxy.
#[derive(Clone, Debug, Deserialize)]
pub struct Stream {
    pub dataset: String,
    pub path: String,
    pub latency_ms: f64,
    pub prefetch: bool,
    pub run: u32,
    pub summary: FlySummary,
}

/// `select.jsonl`: one `tessera bench-select --json` run.
#[derive(Clone, Debug, Deserialize)]
pub struct Select {
    pub dataset: String,
    pub path: String,
    pub run: u32,
    pub width: u32,
    pub height: u32,
    pub tau: f64,
    pub median_us: f64,
    pub p90_us: f64,
    pub max_us: f64,
    pub median_triangles: f64,
    pub worst_deficit: f64,
}

/// `ingest.jsonl`: one timed command of `bench/ingest.sh` (`case` "mosaic" or
/// "reproject"; `samples` are the input's).
#[derive(Clone, Debug, Deserialize)]
pub struct Ingest {
    pub case: String,
    pub tool: String,
    pub run: u32,
    pub samples: f64,
    pub wall_s: f64,
    pub cpu_s: f64,
    pub rss_mib: f64,
}

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

/// `gpu.jsonl`: frames per second on a real GPU (only when one was lent).
#[derive(Clone, Debug, Deserialize)]
pub struct GpuRun {
    pub gpu: String,
    pub width: u32,
    pub height: u32,
    pub tau: f64,
    pub run: u32,
    pub fps_median: f64,
}

/// A record of a `.jsonl` file: its run and what it measured, for the checks.
pub trait Record: DeserializeOwned {
    const FILE: &'static str;
    fn run(&self) -> u32;
    /// What was measured, without the run ("tessera synthetic:16385").
    fn key(&self) -> String;
    /// Values the report cannot use (a zero duration) as an error message.
    fn check(&self) -> Result<(), String> {
        Ok(())
    }
}

impl Record for Build {
    const FILE: &'static str = "build.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!("{} {}", self.tool, self.input)
    }
    fn check(&self) -> Result<(), String> {
        positive(&[("wall_s", self.wall_s), ("samples", self.samples)])
    }
}

impl Record for Ingest {
    const FILE: &'static str = "ingest.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!("{} {}", self.case, self.tool)
    }
    fn check(&self) -> Result<(), String> {
        positive(&[("wall_s", self.wall_s), ("samples", self.samples)])
    }
}

impl Record for Serve {
    const FILE: &'static str = "serve.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!(
            "{} {} ×{} at {} connections",
            self.server, self.request, self.tiles_per_request, self.connections
        )
    }
    fn check(&self) -> Result<(), String> {
        positive(&[("duration_s", self.duration_s)])
    }
}

impl Record for Load {
    const FILE: &'static str = "load.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        self.mode.clone()
    }
}

impl Record for LoadReplay {
    const FILE: &'static str = "loadreplay.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!("{} {}", self.tool, self.phase)
    }
    fn check(&self) -> Result<(), String> {
        positive(&[("seconds", self.seconds)])
    }
}

impl Record for PolicyFlight {
    const FILE: &'static str = "policy.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!(
            "{} {} {} τ={}",
            self.dataset, self.path, self.policy, self.tau
        )
    }
}

impl Record for Gonzalez {
    const FILE: &'static str = "gonzalez.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!(
            "{} {} {} τ={}",
            self.dataset, self.path, self.parallax, self.tau
        )
    }
}

impl Record for Stream {
    const FILE: &'static str = "stream.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!(
            "{} {} {} ms prefetch {}",
            self.dataset, self.path, self.latency_ms, self.prefetch
        )
    }
}

impl Record for Select {
    const FILE: &'static str = "select.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!("{} {} τ={}", self.dataset, self.path, self.tau)
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
    fn check(&self) -> Result<(), String> {
        positive(&[("duration_s", self.duration_s)])
    }
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

impl Record for TerrainMesh {
    const FILE: &'static str = "terrain_mesh.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!("{} {}", self.dataset, self.tile)
    }
    fn check(&self) -> Result<(), String> {
        positive(&[
            ("mesh_us", self.mesh_us),
            ("geometric_error_m", self.geometric_error_m),
            ("regular_triangles", self.regular_triangles),
        ])
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
    fn check(&self) -> Result<(), String> {
        positive(&[("duration_s", self.duration_s)])
    }
}

impl Record for GpuRun {
    const FILE: &'static str = "gpu.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!("{} {}x{} τ={}", self.gpu, self.width, self.height, self.tau)
    }
}

fn positive(fields: &[(&str, f64)]) -> Result<(), String> {
    match fields.iter().find(|(_, v)| v.is_nan() || *v <= 0.0) {
        Some((name, v)) => Err(format!("`{name}` must be positive, not {v}")),
        None => Ok(()),
    }
}

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

/// Reads `dir/T::FILE`: `None` if it does not exist, else one record per
/// non-blank line, checked.
pub fn load_jsonl<T: Record>(dir: &Path) -> anyhow::Result<Option<Vec<T>>> {
    let path = dir.join(T::FILE);
    let text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e).with_context(|| format!("{}: cannot read", path.display())),
    };
    parse_jsonl(&text)
        .map(Some)
        .with_context(|| path.display().to_string())
}

/// The records of a JSON Lines text; errors name the line.
pub fn parse_jsonl<T: Record>(text: &str) -> anyhow::Result<Vec<T>> {
    let mut records = Vec::new();
    let mut seen: HashMap<(String, u32), usize> = HashMap::new();
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        if line.trim().is_empty() {
            continue;
        }
        let r: T = serde_json::from_str(line).with_context(|| format!("line {n}"))?;
        if r.run() == 0 {
            bail!("line {n}: `run` counts from 1");
        }
        r.check().map_err(|e| anyhow::anyhow!("line {n}: {e}"))?;
        if let Some(first) = seen.insert((r.key(), r.run()), n) {
            bail!(
                "line {n}: run {} of {} again (first on line {first})",
                r.run(),
                r.key()
            );
        }
        records.push(r);
    }
    Ok(records)
}

#[cfg(test)]
mod tests {
    use super::*;

    const BUILD: &str = r#"{"tool":"tessera","input":"synthetic:16385","run":1,"wall_s":4.8,"cpu_s":8.9,"rss_mib":72,"bytes":367000000,"samples":268468225,"extra":"ignored"}"#;

    #[test]
    fn parses_records_and_ignores_extra_fields_and_blank_lines() {
        let text = format!("{BUILD}\n\n{}\n", BUILD.replace("\"run\":1", "\"run\":2"));
        let r: Vec<Build> = parse_jsonl(&text).expect("valid");
        assert_eq!(r.len(), 2);
        assert_eq!(r[1].run, 2);
        assert_eq!(r[0].rss_mib, 72.0);
    }

    #[test]
    fn errors_name_the_line_and_the_problem() {
        let missing = BUILD.replace("\"wall_s\":4.8,", "");
        let e = parse_jsonl::<Build>(&format!("{BUILD}\n{missing}")).expect_err("no wall_s");
        let msg = format!("{e:#}");
        assert!(msg.contains("line 2") && msg.contains("wall_s"), "{msg}");

        let e = parse_jsonl::<Build>(&format!("{BUILD}\n{BUILD}")).expect_err("duplicate");
        let msg = format!("{e:#}");
        assert!(
            msg.contains("line 2") && msg.contains("first on line 1"),
            "{msg}"
        );

        let zero = BUILD.replace("\"run\":1", "\"run\":0");
        assert!(parse_jsonl::<Build>(&zero).is_err());
        let no_time = BUILD.replace("\"wall_s\":4.8", "\"wall_s\":0");
        let e = parse_jsonl::<Build>(&no_time).expect_err("zero wall time");
        assert!(format!("{e:#}").contains("wall_s"));
    }

    #[test]
    fn a_missing_file_is_not_run_but_a_bad_one_is_an_error() {
        let dir = tempfile::tempdir().expect("tempdir");
        assert!(load_jsonl::<Serve>(dir.path()).expect("absent").is_none());
        std::fs::write(dir.path().join("serve.jsonl"), "{not json\n").expect("write");
        let e = load_jsonl::<Serve>(dir.path()).expect_err("bad json");
        let msg = format!("{e:#}");
        assert!(
            msg.contains("serve.jsonl") && msg.contains("line 1"),
            "{msg}"
        );
    }

    #[test]
    fn serve_derives_rates_from_counts() {
        let s: Serve = serde_json::from_str(
            r#"{"server":"tessera","request":"batch","tiles_per_request":16,"connections":64,"run":1,
               "duration_s":10,"requests":1000,"errors":0,"p50_ms":30,"p99_ms":50,"mean_tile_bytes":150000}"#,
        )
        .expect("valid");
        assert_eq!(s.requests_per_s(), 100.0);
        assert_eq!(s.tiles_per_s(), 1600.0);
        assert_eq!(s.payload_mb_per_s(), 240.0);
        // Older results have no CPU figures.
        assert_eq!(s.server_cpu_s_per_gb(), None);
        assert_eq!(s.other_cores(), None);
        let s: Serve = serde_json::from_str(
            r#"{"server":"nginx","request":"static","tiles_per_request":1,"connections":64,"run":1,
               "duration_s":10,"requests":20000,"errors":0,"p50_ms":3,"p99_ms":9,"mean_tile_bytes":150000,
               "server_cpu_s":0.9,"wrk_cpu_s":8,"machine_cpu_s":19.5}"#,
        )
        .expect("valid");
        // 20 000 tiles of 150 kB = 3 GB; 0.9 s ÷ 3 GB.
        assert!((s.server_cpu_s_per_gb().expect("recorded") - 0.3).abs() < 1e-12);
        assert!((s.wrk_cpu_s_per_gb().expect("recorded") - 8.0 / 3.0).abs() < 1e-12);
        assert!((s.other_cores().expect("recorded") - 1.06).abs() < 1e-12);
        // What wrk read, where recorded: 4.5 GB (responses in flight at the end).
        let s: Serve = serde_json::from_str(
            r#"{"server":"tessera","request":"batch","tiles_per_request":64,"connections":1024,"run":1,
               "duration_s":4,"requests":100,"errors":0,"p50_ms":3600,"p99_ms":4000,"mean_tile_bytes":150000,
               "wrk_bytes":4.5e9,"server_cpu_s":1.8,"wrk_cpu_s":2.7,"machine_cpu_s":8}"#,
        )
        .expect("valid");
        assert!((s.server_cpu_s_per_gb().expect("recorded") - 0.4).abs() < 1e-12);
        assert!((s.wrk_cpu_s_per_gb().expect("recorded") - 0.6).abs() < 1e-12);
    }
}
