//! `tessera-load`: the load tester alone, `tessera load` without the renderer
//! ([`tessera_client::cli::load`]). Built with `--no-default-features` it links no
//! wgpu, winit or naga: a load-test image or a CI job that only replays traces
//! needs none of them.

use clap::Parser;
use tessera_client::cli::{self, load::LoadCli};

fn main() -> std::process::ExitCode {
    cli::exit_code(cli::load::run(LoadCli::parse().load))
}
