//! The command line: `tessera`'s clap definitions and each command's runner, one
//! module per command. `tessera-load` is the `load` command alone ([`load::LoadCli`]),
//! which needs no renderer. The binaries (`main.rs`, `bin/tessera-load.rs`) parse
//! and call [`run`] or [`load::run`], and turn the result into an exit status
//! ([`exit_code`]).

pub mod bench_select;
#[cfg(feature = "render")]
pub mod fly;
pub mod inspect;
pub mod load;
pub mod report;

use crate::output;
use crate::stream::TileSource;
use anyhow::Context;
use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "tessera",
    version,
    about = "Tessera client: fly through DEM pyramids streamed from a Tessera server"
)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

// Parsed once per process: the size of its largest variant does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Subcommand)]
enum Command {
    /// Load-test a server (or a static host serving a pyramid file, --pyramid): N
    /// simulated clients fly the built-in paths (staggered) through the real
    /// selection and streaming code, without rendering.
    ///
    /// Or, with --replay TRACE, send a recorded trace's requests on a schedule (as
    /// recorded, --rate, --ramp, or --rate max) without selection or decoding,
    /// checking every answer, with latency from each request's scheduled start;
    /// `tessera load merge` adds up the reports of --shard K/N processes.
    #[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
    Load(load::LoadArgs),
    /// Fly a path over a dataset served by `tessera-server serve`, or over a pyramid
    /// file read straight from a static host (--pyramid): selection and streaming at
    /// a fixed frame rate, in real time, with per-frame statistics.
    #[cfg(feature = "render")]
    Fly(fly::FlyArgs),
    /// Time view-dependent selection on a local pyramid, with every error table
    /// resident: the camera flies a path as `tessera fly` does (the eye at the
    /// path's altitude above the finest ground under it), one selection per frame,
    /// the selector's state carried from frame to frame. The path is run forward
    /// and back until --frames frames are timed; the first frame, which builds every
    /// quadtree from nothing, is not timed. Reports the selector's own clock
    /// (median, mean, p90, max), the median triangle count and the worst deficit.
    BenchSelect(bench_select::BenchSelectArgs),
    /// Pictures of a headless flight: stats.png (plots over time), and with --frames
    /// contact_sheet.png (12 frames) and flight.png (an animated PNG of the frames,
    /// 480 px wide), plus a short summary.
    Report(report::ReportArgs),
    /// Print the size, levels and height range of a local pyramid file.
    Inspect(inspect::InspectArgs),
}

/// Runs the command `cli` names.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Load(args) => load::run(args),
        #[cfg(feature = "render")]
        Command::Fly(args) => fly::run(args),
        Command::BenchSelect(args) => bench_select::run(args),
        Command::Report(args) => report::run(args),
        Command::Inspect(args) => inspect::run(args),
    }
}

/// The exit status of a command that ended with `result`, its error printed.
pub fn exit_code(result: anyhow::Result<()>) -> std::process::ExitCode {
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        // The reader of our output went away (`| head -1`): not an error to report.
        Err(e) if output::is_stdout_closed(&e) => {
            std::process::ExitCode::from(output::STDOUT_CLOSED_EXIT)
        }
        Err(e) => {
            output::progress(format_args!("error: {e:#}\n"));
            std::process::ExitCode::FAILURE
        }
    }
}

/// Where the tiles come from: a server and dataset, or a pyramid file's URL.
#[derive(Debug, clap::Args)]
pub(crate) struct SourceArgs {
    /// Server base URL, e.g. http://127.0.0.1:8080.
    #[arg(long, required_unless_present = "pyramid", requires = "dataset")]
    server: Option<String>,
    /// Dataset name on the server.
    #[arg(long, required_unless_present = "pyramid", requires = "server")]
    dataset: Option<String>,
    /// Read a pyramid file straight from a static host, CDN or object store with
    /// HTTP Range requests, no Tessera server: http(s)://host/path/file.tess (or
    /// file:///path/file.tess). The host must answer Range requests with 206.
    #[arg(long, value_name = "URL", conflicts_with_all = ["server", "dataset"])]
    pyramid: Option<String>,
}

impl SourceArgs {
    pub(crate) fn source(self) -> anyhow::Result<TileSource> {
        match (self.pyramid, self.server, self.dataset) {
            (Some(url), None, None) => Ok(TileSource::pyramid(url)),
            (None, Some(server), Some(dataset)) => Ok(TileSource::server(server, dataset)),
            _ => anyhow::bail!("give --server URL --dataset NAME, or --pyramid URL"),
        }
    }
}

/// Parses `30s`, `2m`, `1500ms` or plain seconds (clap's value parser).
pub(crate) fn parse_duration(s: &str) -> Result<std::time::Duration, String> {
    crate::loadtest::schedule::parse_duration(s)
        .ok_or_else(|| format!("{s:?} is not a positive duration like 30s, 2m or 1500ms"))
}

pub(crate) fn parse_viewport(v: &str) -> anyhow::Result<(u32, u32)> {
    v.split_once('x')
        .and_then(|(a, b)| Some((a.parse::<u32>().ok()?, b.parse::<u32>().ok()?)))
        .filter(|(w, h)| *w > 0 && *h > 0)
        .with_context(|| format!("viewport {v:?} is not WIDTHxHEIGHT"))
}
