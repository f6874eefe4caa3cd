//! `tessera`: the Tessera client. Selection, streaming and rendering arrive in later
//! issues; for now it can describe a local pyramid, which proves the client reads the
//! same contract (`tessera-shared`) the server writes.

use anyhow::Context;
use clap::{Parser, Subcommand};
use std::path::PathBuf;
use tessera_shared::Pyramid;

#[derive(Debug, Parser)]
#[command(
    name = "tessera",
    version,
    about = "Tessera client: fly through DEM pyramids streamed from a Tessera server"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Print the size, levels and height range of a local pyramid file.
    Inspect {
        /// A `.tess` pyramid file.
        file: PathBuf,
    },
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Inspect { file } => {
            let p = Pyramid::open_file(&file).with_context(|| file.display().to_string())?;
            let m = p.metadata();
            println!(
                "{}: {}×{} samples, {} levels of {}-cell tiles, heights {:.2}..{:.2} m",
                file.display(),
                m.width,
                m.height,
                m.levels,
                m.tile_size,
                m.min_height,
                m.max_height
            );
            Ok(())
        }
    }
}
