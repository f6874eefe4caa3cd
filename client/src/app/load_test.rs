//! `tessera load`: many simulated clients flying the built-in paths through the real
//! selection and streaming code (no rendering), to load-test a server, or a static
//! host serving a pyramid file (`--pyramid`).
//!
//! With `--record TRACE` the clients' requests are also written as a request trace
//! ([`crate::loadtest::record`]) for `tessera load --replay`, which sends them again
//! without selection or decoding.
//!
//! The clients do the selection and decoding of real clients, so on a small machine
//! they can use all of it before the server is busy: the report then says the run
//! was client-bound ([`crate::loadtest::cpu::CpuUse::client_bound`]: the process used at
//! least 80 % of the cores available to it), and its tiles/s measure the generator.

use super::fly::{FlyOptions, fly};
use crate::loadtest::cpu::CpuMeter;
use crate::loadtest::record::{RecordHook, Recorder};
use crate::stream::{RequestMode, StreamConfig, TileSource};
use std::path::PathBuf;
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
    /// `--record TRACE`: also write the clients' requests there (a server source only).
    pub record: Option<PathBuf>,
}

impl LoadOptions {
    /// `clients` flying over `source` for `duration` with the CLI's defaults: range
    /// requests, 30 fps, τ = 1 px, 1280×720, the dataset's spacing, no progress line,
    /// no recording.
    pub fn new(source: TileSource, clients: u32, duration: Duration) -> Self {
        Self {
            source,
            clients,
            duration,
            mode: RequestMode::Ranges,
            fps: 30.0,
            tau: 1.0,
            width: 1280,
            height: 720,
            spacing: None,
            progress: false,
            open: crate::stream::OpenArgs::default(),
            record: None,
        }
    }
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
    /// The load process's CPU seconds per wall second over the run (cores' worth);
    /// `null` where it cannot be measured (not Linux: `/proc/self/stat`).
    pub client_cpu_cores: Option<f64>,
    /// Cores available to the load process.
    pub client_cores_available: u32,
    /// The process used at least 80 % of its cores: the clients, not the server, set
    /// the pace, and the figures measure the load generator.
    pub client_bound: bool,
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
        )?;
        if self.client_bound {
            write!(
                f,
                "\nclient-bound: the load generator used {:.1} of {} cores; use --record and --replay to measure the server",
                self.client_cpu_cores.unwrap_or(0.0),
                self.client_cores_available
            )?;
        }
        Ok(())
    }
}

/// Where a run's trace goes, checked before the run: `--record` needs a Tessera
/// server (a static host's Range requests are not its routes), and a directory to
/// write the trace in, so a long run does not end in an error.
fn recorder_for(opts: &LoadOptions) -> anyhow::Result<Option<(Arc<Recorder>, PathBuf)>> {
    let Some(path) = &opts.record else {
        return Ok(None);
    };
    let TileSource::Server { url, .. } = &opts.source else {
        anyhow::bail!(
            "--record {} needs a --server source: a trace holds a Tessera server's requests, and --pyramid reads a file with Range requests",
            path.display()
        );
    };
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    anyhow::ensure!(
        dir.is_dir(),
        "--record {}: directory {} does not exist",
        path.display(),
        dir.display()
    );
    anyhow::ensure!(
        !path.is_dir(),
        "--record {}: is a directory, not a file",
        path.display()
    );
    Ok(Some((Recorder::new(url), path.clone())))
}

/// Refuses more clients than the open-file limit `fd_limit` lets this process
/// connect (each holds one connection at least), before any is started: past it they
/// fail one by one, and a million of them would be a million threads.
fn check_clients(clients: u32, fd_limit: Option<u64>) -> anyhow::Result<()> {
    let max = crate::loadtest::connections::max_connections(fd_limit);
    anyhow::ensure!(
        clients <= max,
        "--clients {clients}: each client holds a connection at least, and this process may open {max} ({}, less what it keeps for itself, at most {}); raise the limit (`ulimit -n`, up to `ulimit -Hn`) or use fewer clients",
        fd_limit.map_or_else(
            || "no open-file limit".to_string(),
            |l| format!("its open-file limit, RLIMIT_NOFILE, is {l}")
        ),
        crate::loadtest::connections::MAX_CONNECTIONS
    );
    Ok(())
}

/// Runs the clients (staggered along the built-in paths) and sums their traffic.
pub fn load(opts: &LoadOptions) -> anyhow::Result<LoadReport> {
    anyhow::ensure!(opts.clients > 0, "--clients must be at least 1");
    check_clients(
        opts.clients,
        crate::loadtest::connections::open_file_limit(),
    )?;
    let recording = recorder_for(opts)?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let tiles = Arc::new(AtomicU64::new(0));
    let frames = (opts.duration.as_secs_f64() * opts.fps).ceil() as u32;
    let started = Instant::now();
    let cpu = CpuMeter::start();
    let done = Arc::new(AtomicU64::new(0));
    let progress = opts.progress.then(|| {
        let (tiles, done, clients) = (tiles.clone(), done.clone(), u64::from(opts.clients));
        std::thread::spawn(move || {
            while done.load(Ordering::Relaxed) < clients {
                std::thread::sleep(Duration::from_millis(500));
                let t = tiles.load(Ordering::Relaxed);
                let s = started.elapsed().as_secs_f64();
                // Best-effort: a closed stderr must not end the run.
                crate::output::progress(format_args!(
                    "\r{s:6.1} s  {t:>8} tiles  {:>8.0} tiles/s   ",
                    t as f64 / s.max(1e-9)
                ));
            }
            crate::output::progress('\n');
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
                morph_seconds: crate::select::MORPH_SECONDS,
                morph_by_distance: false,
                morph_error_limit: crate::select::MORPH_ERROR_LIMIT,
                width: opts.width,
                height: opts.height,
                spacing: opts.spacing,
                prefetch: true,
                pool_tiles: 512,
                stream: StreamConfig {
                    mode: opts.mode,
                    record: recording
                        .as_ref()
                        .map(|(r, _)| RecordHook::new(r.clone(), i)),
                    ..opts.open.config()
                },
                // Staggered starts: each client begins at a different point of its path.
                t_offset: f64::from(i) * 1.7,
                runtime: Some(rt.handle().clone()),
                progress: Some(tiles.clone()),
                #[cfg(feature = "render")]
                render: None,
                globe: crate::globe::GlobeMode::Off,
            };
            let done = done.clone();
            // A thread the system refuses is an error, not a panic (as spawn's).
            std::thread::Builder::new()
                .name(format!("load-client-{i}"))
                .spawn(move || {
                    let r = fly(&fly_opts, None);
                    done.fetch_add(1, Ordering::Relaxed);
                    r
                })
                .map_err(|e| {
                    anyhow::anyhow!("--clients {}: cannot start client {i}: {e}", opts.clients)
                })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
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
    let cpu = cpu.finish();
    let mode = match opts.mode {
        RequestMode::Ranges => "ranges",
        RequestMode::Single => "single",
    };
    if let Some((recorder, path)) = &recording {
        // The fetches still in flight when the clients stopped end with the runtime;
        // theirs stay without an expectation.
        drop(rt);
        recorder
            .trace(opts.source.name(), opts.clients, seconds, mode)
            .write(path)?;
    }
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
        mode: mode.into(),
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
        client_cpu_cores: cpu.map(|c| c.cores_used),
        client_cores_available: crate::loadtest::cpu::available_cores(),
        client_bound: cpu.is_some_and(|c| c.client_bound()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report(client_cpu_cores: Option<f64>, client_bound: bool) -> LoadReport {
        LoadReport {
            clients: 64,
            mode: "ranges".into(),
            seconds: 20.0,
            requests: 1000,
            responses: 990,
            tiles: 9000,
            bytes: 90_000_000,
            errors: 0,
            requests_per_s: 50.0,
            tiles_per_s: 450.0,
            mb_per_s: 4.5,
            latency_ms_p50: 10.0,
            latency_ms_p90: 100.0,
            latency_ms_p99: 1000.0,
            latency_ms_max: 1500.0,
            frames_within_2tau: 0.2,
            client_cpu_cores,
            client_cores_available: 2,
            client_bound,
        }
    }

    #[test]
    fn the_summary_labels_client_bound_runs() {
        let bound = report(Some(1.9), true).to_string();
        assert!(
            bound.contains(
                "client-bound: the load generator used 1.9 of 2 cores; use --record and --replay"
            ),
            "{bound}"
        );
        let free = report(Some(0.4), false).to_string();
        assert!(!free.contains("client-bound"), "{free}");
        let json = serde_json::to_value(report(None, false)).unwrap();
        assert_eq!(json["client_cpu_cores"], serde_json::Value::Null);
        assert_eq!(json["client_bound"], false);
    }

    #[test]
    fn more_clients_than_the_open_file_limit_holds_are_refused() {
        assert!(check_clients(960, Some(1024)).is_ok());
        let e = check_clients(1_000_000, Some(1024))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--clients 1000000")
                && e.contains("RLIMIT_NOFILE, is 1024")
                && e.contains("ulimit -n"),
            "{e}"
        );
        let e = check_clients(1_000_000, None).unwrap_err().to_string();
        assert!(e.contains("65536"), "{e}");
        // The run itself refuses it before starting anything.
        let e = load(&LoadOptions::new(
            TileSource::server("http://127.0.0.1:1/", "moon"),
            1_000_000,
            Duration::from_secs(1),
        ))
        .unwrap_err();
        assert!(e.to_string().contains("--clients 1000000"), "{e}");
    }

    #[test]
    fn record_needs_a_server_and_a_directory() {
        let opts = |source: TileSource, record: &str| LoadOptions {
            source,
            clients: 1,
            duration: Duration::from_secs(1),
            mode: RequestMode::Ranges,
            fps: 30.0,
            tau: 1.0,
            width: 64,
            height: 64,
            spacing: None,
            progress: false,
            open: crate::stream::OpenArgs::default(),
            record: Some(record.into()),
        };
        let err = |o: &LoadOptions| format!("{:#}", recorder_for(o).unwrap_err());
        let pyramid = err(&opts(TileSource::pyramid("file:///x.tess"), "t.jsonl"));
        assert!(
            pyramid.contains("--record t.jsonl needs a --server source"),
            "{pyramid}"
        );
        let server = TileSource::server("http://127.0.0.1:1/", "moon");
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("nope/t.jsonl");
        assert!(err(&opts(server.clone(), missing.to_str().unwrap())).contains("does not exist"));
        assert!(
            err(&opts(server.clone(), dir.path().to_str().unwrap())).contains("is a directory")
        );
        let ok = recorder_for(&opts(server, "t.jsonl")).unwrap().unwrap();
        assert_eq!(ok.0.base(), "http://127.0.0.1:1");
    }
}
