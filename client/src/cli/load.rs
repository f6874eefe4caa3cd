//! `tessera load` and `tessera-load`: the load tester's command line (one definition
//! for both binaries) and its runner: the full clients ([`crate::app::load_test`]),
//! a trace's replay ([`crate::loadtest::replay`]) and `merge`.

use super::args::{SourceArgs, parse_duration, parse_viewport};
use crate::app::load_test;
use crate::loadtest::merge::merge_files;
use crate::loadtest::pacing::{Pacing, RampStages, RateArg};
use crate::loadtest::replay::{self, ReplayOptions};
use crate::loadtest::replay_report::ReplayReport;
use crate::loadtest::trace::{Shard, Trace};
use crate::output;
use crate::stream::{OpenArgs, RequestMode, TileSource};
use anyhow::Context;
use clap::{Parser, Subcommand};
use std::path::PathBuf;

/// Load-test a server (or a static host serving a pyramid file, --pyramid): N
/// simulated clients fly the built-in paths (staggered) through the real selection
/// and streaming code, without rendering.
///
/// Or, with --replay TRACE, send a recorded trace's requests on a schedule (as
/// recorded, --rate, --ramp, or --rate max) without selection or decoding, checking
/// every answer, with latency from each request's scheduled start; `tessera-load
/// merge` adds up the reports of --shard K/N processes.
///
/// `tessera-load` is `tessera load` of the Tessera client, built without its
/// renderer.
#[derive(Debug, Parser)]
#[command(
    name = "tessera-load",
    version,
    args_conflicts_with_subcommands = true,
    subcommand_negates_reqs = true
)]
pub struct LoadCli {
    #[command(flatten)]
    pub load: LoadArgs,
}

/// The arguments of `tessera load` (and of `tessera-load`).
#[derive(Debug, clap::Args)]
pub struct LoadArgs {
    #[command(flatten)]
    source: LoadSourceArgs,
    #[arg(long, default_value_t = 16, conflicts_with = "replay")]
    clients: u32,
    /// How long, e.g. 30s, 2m (with --replay: how long --rate N or --rate max
    /// runs; a recorded replay or a --ramp takes as long as it takes).
    #[arg(long, default_value = "30s", value_parser = parse_duration)]
    duration: std::time::Duration,
    /// Request Morton-range batches, or one tile per request.
    #[arg(long, value_enum, default_value_t = Mode::Ranges, conflicts_with = "replay")]
    mode: Mode,
    /// Simulated frames per second per client.
    #[arg(long, default_value_t = 30.0, conflicts_with = "replay")]
    fps: f64,
    #[arg(long, default_value_t = 1.0, conflicts_with = "replay")]
    tau: f64,
    #[arg(long, default_value = "1280x720", conflicts_with = "replay")]
    viewport: String,
    /// Metres between samples, east–west and north–south alike (default: the dataset's
    /// ground spacing, measured by the server for each axis; else 100).
    #[arg(long, conflicts_with = "replay")]
    spacing: Option<f64>,
    /// Also write the clients' requests to TRACE (JSON Lines, FORMAT.md "Request
    /// traces"), with each completed answer's status, tiles, bytes and digest,
    /// for --replay. Needs --server.
    #[arg(long, value_name = "TRACE")]
    record: Option<PathBuf>,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    open: OpenArgs,
    #[command(flatten)]
    replay: ReplayArgs,
    #[command(subcommand)]
    action: Option<LoadAction>,
}

/// `tessera load`'s source: as [`SourceArgs`], but none is required by itself, since
/// `--replay` takes its server from the trace (`--server` overrides it) and needs no
/// `--dataset`; `run` checks the combinations.
#[derive(Debug, clap::Args)]
struct LoadSourceArgs {
    /// Server base URL, e.g. http://127.0.0.1:8080 (with --replay: instead of the
    /// server the trace was recorded against).
    #[arg(long)]
    server: Option<String>,
    /// Dataset name on the server (not with --replay: the trace names it).
    #[arg(long, conflicts_with = "replay")]
    dataset: Option<String>,
    /// Read a pyramid file straight from a static host, CDN or object store with
    /// HTTP Range requests, no Tessera server: http(s)://host/path/file.tess (or
    /// file:///path/file.tess). The host must answer Range requests with 206.
    #[arg(long, value_name = "URL", conflicts_with_all = ["server", "dataset", "replay"])]
    pyramid: Option<String>,
}

impl LoadSourceArgs {
    fn source(self) -> anyhow::Result<TileSource> {
        SourceArgs {
            server: self.server,
            dataset: self.dataset,
            pyramid: self.pyramid,
        }
        .source()
    }
}

/// `tessera load --replay`'s settings.
#[derive(Debug, clap::Args)]
struct ReplayArgs {
    /// Replay the requests of TRACE (written by --record) instead of flying clients:
    /// only HTTP and the frames' checksums, no selection or decoding. Without --rate
    /// or --ramp, every request once at its recorded time.
    #[arg(long, value_name = "TRACE", conflicts_with = "record")]
    replay: Option<PathBuf>,
    /// With --replay: a constant arrival rate, requests/s (all --shard processes
    /// together, at most 1000000/s for each), for --duration, cycling through the
    /// trace; or `max`: saturation, each of --connections sending its next request
    /// when its last one finished.
    #[arg(long, value_name = "N|max", requires = "replay")]
    rate: Option<RateArg>,
    /// With --replay: ramping arrival rate, stages DURATION:RATE,… (e.g.
    /// 10s:100,20s:400): over each stage the rate moves linearly from the previous
    /// stage's (the first from --rate, else 0) to its own; --duration is not used.
    #[arg(long, value_name = "STAGES", requires = "replay")]
    ramp: Option<RampStages>,
    /// With --replay: HTTP/1.1: at most C requests in flight, on C keep-alive
    /// connections; with --http2: C connections, each carrying up to 100 requests.
    /// When all are busy, a request waits, and the wait counts in its latency. At
    /// most the open-file limit (`ulimit -n`) less 64, and 65536.
    #[arg(long, value_name = "C", default_value_t = 64, requires = "replay",
          value_parser = clap::value_parser!(u32).range(1..))]
    connections: u32,
    /// With --replay: this process is shard K of N (K from 0): it replays the
    /// clients c with c % N == K at 1/N of --rate.
    #[arg(long, value_name = "K/N", default_value = "0/1", requires = "replay")]
    shard: Shard,
    /// With --replay: a request's limit (at most 1h), and how long to wait for the
    /// requests still in flight when the schedule ends (those count as timeout
    /// errors). The run stops then, whatever the rate: requests not yet sent are
    /// not sent, and reported as unsent.
    #[arg(long, default_value = "10s", value_parser = parse_duration, requires = "replay")]
    timeout: std::time::Duration,
    /// With --replay: runtime threads (1: everything on one core).
    #[arg(long, default_value_t = 1, requires = "replay",
          value_parser = clap::value_parser!(u32).range(1..256))]
    threads: u32,
    /// With --replay: write DIR/load.json (the report) and DIR/latency.png.
    #[arg(long, value_name = "DIR", requires = "replay")]
    out: Option<PathBuf>,
}

#[derive(Debug, Subcommand)]
enum LoadAction {
    /// Add up the reports (load.json) of the --shard K/N processes of one replay:
    /// counts and errors add, latency histograms add exactly (percentiles from the
    /// sums), seconds are the longest shard's and rates are totals over them.
    Merge {
        /// Reports (DIR/load.json of --out DIR, or --json's output), or their DIRs.
        #[arg(required = true, value_name = "REPORT")]
        reports: Vec<PathBuf>,
        /// Print the merged report as JSON.
        #[arg(long)]
        json: bool,
        /// Write DIR/load.json and DIR/latency.png.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
    },
}

/// Prints a replay's report (JSON or the summary) and writes it under `out`.
fn emit_replay(r: &ReplayReport, json: bool, out: Option<&std::path::Path>) -> anyhow::Result<()> {
    // Printed first, so that a directory that cannot be written loses no results;
    // written even when stdout has gone away (`| head -1`), which is said after.
    let printed = if json {
        output::print_line(serde_json::to_string_pretty(r)?)
    } else {
        output::print_line(r)
    };
    if let Some(dir) = out {
        r.write_dir(dir)?;
    }
    Ok(printed?)
}

/// `tessera load --replay TRACE …`.
fn load_replay(
    trace: &std::path::Path,
    server: Option<String>,
    args: ReplayArgs,
    duration: std::time::Duration,
    http2: bool,
    json: bool,
) -> anyhow::Result<()> {
    let pacing = match (args.rate, args.ramp) {
        (Some(RateArg::Max), Some(_)) => {
            anyhow::bail!("--ramp needs a starting --rate N, not --rate max")
        }
        (Some(RateArg::Max), None) => Pacing::Saturation { duration },
        (Some(RateArg::PerSecond(rate)), None) => Pacing::Constant { rate, duration },
        (rate, Some(stages)) => Pacing::Ramp {
            start: match rate {
                Some(RateArg::PerSecond(r)) => r.per_second(),
                _ => 0.0,
            },
            stages,
        },
        (None, None) => Pacing::Recorded,
    };
    let opts = ReplayOptions {
        server,
        pacing,
        connections: args.connections,
        http2,
        shard: args.shard,
        timeout: args.timeout,
        threads: args.threads as usize,
        progress: !json,
        ..ReplayOptions::new(Trace::read(trace)?)
    };
    let r = replay::replay(&opts)?;
    emit_replay(&r, json, args.out.as_deref())
}

/// `tessera load merge REPORT…`.
fn load_merge(
    reports: &[PathBuf],
    json: bool,
    out: Option<&std::path::Path>,
) -> anyhow::Result<()> {
    // Each file once: the same shard twice would count its requests twice.
    let merged = merge_files(reports).with_context(|| {
        format!(
            "cannot merge {}",
            reports
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        )
    })?;
    emit_replay(&merged, json, out)
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum Mode {
    Ranges,
    Single,
}

/// Runs `tessera load …` (or `tessera-load …`): `merge`, a `--replay`, or the full
/// clients, printing the report.
pub fn run(args: LoadArgs) -> anyhow::Result<()> {
    let LoadArgs {
        source,
        clients,
        duration,
        mode,
        fps,
        tau,
        viewport,
        spacing,
        record,
        json,
        open,
        replay,
        action,
    } = args;
    if let Some(LoadAction::Merge { reports, json, out }) = action {
        return load_merge(&reports, json, out.as_deref());
    }
    if let Some(trace) = replay.replay.clone() {
        return load_replay(&trace, source.server, replay, duration, open.http2, json);
    }
    let (width, height) = parse_viewport(&viewport)?;
    let opts = load_test::LoadOptions {
        source: source.source()?,
        clients,
        duration,
        mode: match mode {
            Mode::Ranges => RequestMode::Ranges,
            Mode::Single => RequestMode::Single,
        },
        fps,
        tau,
        width,
        height,
        spacing,
        progress: !json,
        open,
        record,
    };
    let r = load_test::load(&opts)?;
    if json {
        output::print_line(serde_json::to_string_pretty(&r)?)?;
    } else {
        output::print_line(&r)?;
    }
    Ok(())
}
