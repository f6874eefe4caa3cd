//! The client along a flight path: rendered frames (`policy.jsonl`,
//! `gonzalez.jsonl`, `gpu.jsonl`), streaming (`stream.jsonl`) and selection
//! (`select.jsonl`).

use super::jsonl::Record;
use serde::Deserialize;

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

impl Record for Select {
    const FILE: &'static str = "select.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!("{} {} τ={}", self.dataset, self.path, self.tau)
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

impl Record for GpuRun {
    const FILE: &'static str = "gpu.jsonl";
    fn run(&self) -> u32 {
        self.run
    }
    fn key(&self) -> String {
        format!("{} {}x{} τ={}", self.gpu, self.width, self.height, self.tau)
    }
}
