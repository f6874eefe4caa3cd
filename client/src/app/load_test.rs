//! `tessera load`: many simulated clients flying the built-in paths through the real
//! selection and streaming code (no rendering), to load-test a server, or a static
//! host serving a pyramid file (`--pyramid`).

use super::fly::{FlyOptions, fly};
use crate::stream::{RequestMode, StreamConfig, TileSource};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

#[derive(Clone, Debug)]
pub struct LoadOptions {
    /// The server and dataset, or the pyramid file's URL.
    pub source: TileSource,
    pub clients: u32,
    pub duration: Duration,
    pub mode: RequestMode,
    pub fps: f64,
    pub tau: f64,
    pub width: u32,
    pub height: u32,
    pub spacing: Option<f64>,
    pub progress: bool,
    /// `--no-bootstrap`, `--http2`.
    pub open: crate::stream::OpenArgs,
}

/// What the clients saw, together.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LoadReport {
    pub clients: u32,
    pub mode: String,
    pub seconds: f64,
    pub requests: u64,
    /// Requests answered in full (the rest were cancelled, failed or still in flight).
    pub responses: u64,
    pub tiles: u64,
    pub bytes: u64,
    pub errors: u64,
    pub requests_per_s: f64,
    pub tiles_per_s: f64,
    pub mb_per_s: f64,
    pub latency_ms_p50: f64,
    pub latency_ms_p90: f64,
    pub latency_ms_p99: f64,
    pub latency_ms_max: f64,
    pub frames_within_2tau: f64,
}

/// The one-line summary `tessera load` prints without `--json`.
impl std::fmt::Display for LoadReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} clients, {} mode, {:.1} s: {:.0} tiles/s, {:.1} MB/s, {:.0} requests/s; latency p50 {:.1} ms, p90 {:.1} ms, p99 {:.1} ms, max {:.1} ms; {} errors; {:.1}% of frames within 2τ",
            self.clients,
            self.mode,
            self.seconds,
            self.tiles_per_s,
            self.mb_per_s,
            self.requests_per_s,
            self.latency_ms_p50,
            self.latency_ms_p90,
            self.latency_ms_p99,
            self.latency_ms_max,
            self.errors,
            100.0 * self.frames_within_2tau
        )
    }
}

/// Runs the clients (staggered along the built-in paths) and sums their traffic.
pub fn load(opts: &LoadOptions) -> anyhow::Result<LoadReport> {
    anyhow::ensure!(opts.clients > 0, "--clients must be at least 1");
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let tiles = Arc::new(AtomicU64::new(0));
    let frames = (opts.duration.as_secs_f64() * opts.fps).ceil() as u32;
    let started = Instant::now();
    let done = Arc::new(AtomicU64::new(0));
    let progress = opts.progress.then(|| {
        let (tiles, done, clients) = (tiles.clone(), done.clone(), u64::from(opts.clients));
        std::thread::spawn(move || {
            while done.load(Ordering::Relaxed) < clients {
                std::thread::sleep(Duration::from_millis(500));
                let t = tiles.load(Ordering::Relaxed);
                let s = started.elapsed().as_secs_f64();
                eprint!(
                    "\r{s:6.1} s  {t:>8} tiles  {:>8.0} tiles/s   ",
                    t as f64 / s.max(1e-9)
                );
            }
            eprintln!();
        })
    });
    let paths = ["canyon", "pass", "orbit"];
    let handles: Vec<_> = (0..opts.clients)
        .map(|i| {
            let fly_opts = FlyOptions {
                source: opts.source.clone(),
                path: paths[i as usize % paths.len()].to_string(),
                frames,
                fps: opts.fps,
                tau: opts.tau,
                policy: crate::select::Policy::ScreenError,
                width: opts.width,
                height: opts.height,
                spacing: opts.spacing,
                prefetch: true,
                pool_tiles: 512,
                stream: StreamConfig {
                    mode: opts.mode,
                    ..opts.open.config()
                },
                // Staggered starts: each client begins at a different point of its path.
                t_offset: f64::from(i) * 1.7,
                runtime: Some(rt.handle().clone()),
                progress: Some(tiles.clone()),
                render: None,
                globe: crate::globe::GlobeMode::Off,
            };
            let done = done.clone();
            std::thread::spawn(move || {
                let r = fly(&fly_opts, None);
                done.fetch_add(1, Ordering::Relaxed);
                r
            })
        })
        .collect();
    let mut summaries = Vec::new();
    for h in handles {
        summaries.push(
            h.join()
                .map_err(|_| anyhow::anyhow!("a client thread panicked"))??,
        );
    }
    if let Some(p) = progress {
        let _ = p.join();
    }
    let seconds = started.elapsed().as_secs_f64();
    let mut lat: Vec<f64> = summaries
        .iter()
        .flat_map(|s| s.latencies_ms.iter().copied())
        .collect();
    lat.sort_by(f64::total_cmp);
    let pct = |q: f64| {
        lat.get(((lat.len().max(1) - 1) as f64 * q).round() as usize)
            .copied()
            .unwrap_or(0.0)
    };
    let sum = |f: &dyn Fn(&super::fly::FlySummary) -> u64| summaries.iter().map(f).sum::<u64>();
    let requests = sum(&|s| s.stream.requests);
    let responses = sum(&|s| s.stream.responses);
    let tiles_total = sum(&|s| s.stream.tiles);
    let bytes = sum(&|s| s.stream.bytes);
    let within: f64 =
        summaries.iter().map(|s| s.within_2tau).sum::<f64>() / f64::from(opts.clients);
    Ok(LoadReport {
        clients: opts.clients,
        mode: match opts.mode {
            RequestMode::Ranges => "ranges",
            RequestMode::Single => "single",
        }
        .into(),
        seconds,
        requests,
        responses,
        tiles: tiles_total,
        bytes,
        errors: sum(&|s| s.stream.failures + s.stream.corrupt),
        requests_per_s: requests as f64 / seconds,
        tiles_per_s: tiles_total as f64 / seconds,
        mb_per_s: bytes as f64 / seconds / 1e6,
        latency_ms_p50: pct(0.5),
        latency_ms_p90: pct(0.9),
        latency_ms_p99: pct(0.99),
        latency_ms_max: pct(1.0),
        frames_within_2tau: within,
    })
}
