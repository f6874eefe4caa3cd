//! The server under load: wrk rows (`serve.jsonl`), `tessera load` runs
//! (`load.jsonl`) and replayed traces (`loadreplay.jsonl`).

use super::jsonl::{Record, RecordError, positive};
use serde::Deserialize;

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
    fn check(&self) -> Result<(), RecordError> {
        positive(&[("duration_s", self.duration_s)])
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

impl Record for Load {
    const FILE: &'static str = "load.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        self.mode.clone()
    }
}

/// `loadreplay.jsonl` (bench/load.sh;
/// DECISIONS.md "Load testing: the proof around the tool"): one load generator replaying
/// the targets of one recorded trace, at saturation (`phase` "saturation": closed loop,
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

impl Record for LoadReplay {
    const FILE: &'static str = "loadreplay.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!("{} {}", self.tool, self.phase)
    }
    fn check(&self) -> Result<(), RecordError> {
        positive(&[("seconds", self.seconds)])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
