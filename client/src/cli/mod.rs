//! The command line: `tessera`'s clap definitions and each command's runner, one
//! module per command. `tessera-load` is the `load` command alone ([`load::LoadCli`]),
//! which needs no renderer. The binaries (`main.rs`, `bin/tessera-load.rs`) parse
//! and call [`run`] or [`load::run`], and turn the result into an exit status
//! ([`exit_code`]).

mod args;
pub mod bench_select;
pub mod flight_report;
#[cfg(feature = "render")]
pub mod fly;
pub mod inspect;
pub mod load;

use crate::output;
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
    Report(flight_report::ReportArgs),
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
        Command::Report(args) => flight_report::run(args),
        Command::Inspect(args) => inspect::run(args),
    }
}

/// The exit status of a command that ended with `result`, its error printed.
pub fn exit_code(result: anyhow::Result<()>) -> std::process::ExitCode {
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        // The reader of our output went away (`| head -1`): not an error to report.
        Err(e) if output::is_stdout_closed(e.as_ref()) => {
            std::process::ExitCode::from(output::STDOUT_CLOSED_EXIT)
        }
        Err(e) => {
            output::progress(format_args!("error: {e:#}\n"));
            std::process::ExitCode::FAILURE
        }
    }
}
