//! `tessera`: the Tessera client. Selection, streaming and rendering arrive in later
//! issues; for now it can describe a local pyramid, which proves the client reads the
//! same contract (`tessera-shared`) the server writes.

use anyhow::Context;
use clap::{Parser, Subcommand};
use glam::DVec3;
use std::collections::HashMap;
use std::path::PathBuf;
use tessera_client::camera::Camera;
use tessera_client::select::{SelectParams, Selector, World};
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
    /// Time view-dependent selection on a local pyramid: every error table resident,
    /// a camera flying low across the terrain, median and worst time per frame.
    BenchSelect {
        /// A `.tess` pyramid file.
        file: PathBuf,
        /// Screen-space error threshold in pixels.
        #[arg(long, default_value_t = 1.0)]
        tau: f64,
        /// Frames to time.
        #[arg(long, default_value_t = 300)]
        frames: u32,
        /// Viewport, e.g. 1920x1080.
        #[arg(long, default_value = "1920x1080")]
        viewport: String,
        /// Metres between neighbouring samples (default: from the georeferencing, else 100).
        #[arg(long)]
        spacing: Option<f64>,
    },
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

/// Metres between samples: from a projected CRS's pixel size, from degrees for a
/// geographic one, else `fallback`.
fn spacing(meta: &tessera_shared::Metadata, fallback: f64) -> f64 {
    match &meta.georef {
        Some(g) if g.epsg == Some(4326) => {
            let lat =
                (g.geotransform[3] + g.geotransform[5] * f64::from(meta.height) / 2.0).to_radians();
            g.geotransform[1].abs() * 111_320.0 * lat.cos()
        }
        Some(g) if g.epsg.is_some() => g.geotransform[1].abs(),
        _ => fallback,
    }
}

fn bench_select(
    file: &std::path::Path,
    tau: f64,
    frames: u32,
    viewport: &str,
    spacing_m: Option<f64>,
) -> anyhow::Result<()> {
    let (w, h) = viewport
        .split_once('x')
        .and_then(|(a, b)| Some((a.parse::<u32>().ok()?, b.parse::<u32>().ok()?)))
        .with_context(|| format!("viewport {viewport:?} is not WIDTHxHEIGHT"))?;
    let p = Pyramid::open_file(file).with_context(|| file.display().to_string())?;
    let g = *p.geometry();
    let meta = p.metadata().clone();
    let mut tables = HashMap::new();
    for level in g.levels() {
        for tile in g.present_tiles(level) {
            let t = p
                .read_error_table(tile)?
                .context("present tile without a record")?;
            tables.insert(tile, t);
        }
    }
    let world = World {
        geometry: g,
        quant: meta.quantization,
        spacing: spacing_m.unwrap_or_else(|| spacing(&meta, 100.0)),
    };
    let extent = f64::from(g.width().max(g.height())) * world.spacing;
    let mut sel = Selector::new(
        world,
        SelectParams {
            tau,
            ..SelectParams::default()
        },
    );
    let mut times = Vec::new();
    let mut tris = Vec::new();
    for f in 0..frames {
        // A straight low pass along the diagonal, looking ahead and down.
        let a = 0.1 + 0.8 * f64::from(f) / f64::from(frames.max(1));
        let camera = Camera {
            position: DVec3::new(a * extent, meta.max_height + 300.0, a * extent),
            yaw: 135f64.to_radians(),
            pitch: -0.25,
            fovy: 60f64.to_radians(),
            width: w,
            height: h,
            near: 1.0,
            far: 4.0 * extent,
        };
        let s = sel.select(&camera, &tables);
        times.push(s.stats.select_us);
        tris.push(s.stats.triangles);
    }
    times.sort_by(f64::total_cmp);
    let pct = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize];
    println!(
        "{}: {} tiles resident, {w}×{h}, τ = {tau} px, {frames} frames: selection median {:.0} µs, p90 {:.0} µs, max {:.0} µs; median {} triangles",
        file.display(),
        tables.len(),
        pct(0.5),
        pct(0.9),
        pct(1.0),
        {
            let mut t = tris.clone();
            t.sort_unstable();
            t[t.len() / 2]
        }
    );
    Ok(())
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::BenchSelect {
            file,
            tau,
            frames,
            viewport,
            spacing,
        } => bench_select(&file, tau, frames, &viewport, spacing),
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
