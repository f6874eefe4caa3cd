//! `tessera bench-select`: the selection alone, timed over a local pyramid.

use super::args::parse_viewport;
use crate::app::bench_select::{BenchSelect, bench_select};
use std::path::PathBuf;

/// `tessera bench-select`'s arguments (its help text is on the `Command` it is a variant of).
#[derive(Debug, clap::Args)]
pub struct BenchSelectArgs {
    /// A `.tess` pyramid file.
    file: PathBuf,
    /// canyon (low and fast), pass (high, across the whole dataset), orbit, or
    /// a path JSON file.
    #[arg(long, default_value = "pass")]
    path: String,
    /// Frames per second along the path (how far the camera moves per frame).
    #[arg(long, default_value_t = 60.0)]
    fps: f64,
    /// Screen-space error threshold in pixels.
    #[arg(long, default_value_t = 1.0)]
    tau: f64,
    /// Frames to time (the path is run forward and back as often as needed).
    #[arg(long, default_value_t = 2000)]
    frames: u32,
    /// Viewport, e.g. 1920x1080.
    #[arg(long, default_value = "1920x1080")]
    viewport: String,
    /// Metres between neighbouring samples, both axes (default: the dataset's ground
    /// spacing, measured by the server for each axis; else 100).
    #[arg(long)]
    spacing: Option<f64>,
    /// Print one JSON object: file, tiles, width, height, tau, path, fps,
    /// frames, median_us, mean_us, p90_us, max_us, median_triangles,
    /// worst_deficit.
    #[arg(long)]
    json: bool,
}

/// Runs the command.
pub fn run(args: BenchSelectArgs) -> anyhow::Result<()> {
    let BenchSelectArgs {
        file,
        path,
        fps,
        tau,
        frames,
        viewport,
        spacing,
        json,
    } = args;
    let (width, height) = parse_viewport(&viewport)?;
    let r = bench_select(&BenchSelect {
        file: &file,
        path: &path,
        fps,
        tau,
        frames,
        width,
        height,
        spacing,
    })?;
    if json {
        println!("{}", serde_json::to_string(&r)?);
    } else {
        println!("{r}");
    }
    Ok(())
}
