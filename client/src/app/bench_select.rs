//! `tessera bench-select`: view-dependent selection alone, timed on a local
//! pyramid with every error table resident, along a path flown forward and back.

use crate::paths;
use crate::select::{self, SelectParams, Selector, World};
use anyhow::Context;
use std::path::Path;
use tessera_shared::Pyramid;

/// What `tessera bench-select` times.
#[derive(Debug)]
pub struct BenchSelect<'a> {
    /// A `.tess` pyramid file.
    pub file: &'a Path,
    /// `canyon`, `pass`, `orbit` or a path JSON file.
    pub path: &'a str,
    pub fps: f64,
    pub tau: f64,
    /// Frames timed.
    pub frames: u32,
    pub width: u32,
    pub height: u32,
    /// Metres between samples on both axes (`--spacing`); default the pyramid's
    /// `ground_spacing` (east–west and north–south), else 100.
    pub spacing: Option<f64>,
}

/// What `tessera bench-select` reports (`--json`): the selector's own clock
/// (`FrameStats::select_us`) over the timed frames.
#[derive(Debug, serde::Serialize)]
pub struct BenchSelectReport {
    pub file: String,
    /// Error tables resident (every present tile).
    pub tiles: usize,
    pub width: u32,
    pub height: u32,
    pub tau: f64,
    pub path: String,
    pub fps: f64,
    /// Frames timed.
    pub frames: u32,
    pub median_us: f64,
    pub mean_us: f64,
    pub p90_us: f64,
    pub max_us: f64,
    pub median_triangles: u64,
    pub worst_deficit: f64,
}

/// The one-line summary `tessera bench-select` prints without `--json`.
impl std::fmt::Display for BenchSelectReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {} tiles resident, path `{}` at {} fps (forward and back), {}×{}, τ = {} px, {} frames: selection median {:.0} µs, mean {:.0} µs, p90 {:.0} µs, max {:.0} µs; median {} triangles, worst deficit {:.2}",
            self.file,
            self.tiles,
            self.path,
            self.fps,
            self.width,
            self.height,
            self.tau,
            self.frames,
            self.median_us,
            self.mean_us,
            self.p90_us,
            self.max_us,
            self.median_triangles,
            self.worst_deficit
        )
    }
}

/// Opens the pyramid, places the path's cameras and times one selection per frame;
/// the first frame, which builds every quadtree from nothing, is not timed.
pub fn bench_select(b: &BenchSelect) -> anyhow::Result<BenchSelectReport> {
    anyhow::ensure!(b.frames > 0, "--frames must be at least 1");
    anyhow::ensure!(
        b.fps.is_finite() && b.fps > 0.0 && b.tau > 0.0,
        "--fps and --tau must be positive"
    );
    let p = Pyramid::open_file(b.file).with_context(|| b.file.display().to_string())?;
    let meta = p.metadata().clone();
    let tables = select::all_tables(&p)?;
    let world = World {
        geometry: *p.geometry(),
        quant: meta.quantization,
        spacing: World::spacing_from(b.spacing, meta.ground_spacing),
        globe: None,
    };
    let cameras = paths::path_cameras(&p, &world, b.path, b.fps, b.width, b.height)?;
    // Forward and back, so consecutive frames are always neighbours on the path:
    // frame k is camera `order[k % order.len()]`.
    let n = cameras.len();
    let order: Vec<usize> = (0..n).chain((1..n.saturating_sub(1)).rev()).collect();
    let mut sel = Selector::new(
        world,
        SelectParams {
            tau: b.tau,
            ..SelectParams::default()
        },
    );
    // The first frame builds every quadtree from nothing: not a steady-state frame.
    sel.select(&cameras[order[0]], &tables);
    let mut times = Vec::with_capacity(b.frames as usize);
    let mut tris = Vec::with_capacity(b.frames as usize);
    let mut worst_deficit = 0f64;
    for k in 1..=b.frames as usize {
        let s = sel.select(&cameras[order[k % order.len()]], &tables);
        times.push(s.stats.select_us);
        tris.push(s.stats.triangles);
        // Everything is resident: an unbounded deficit would be a selection bug.
        let deficit = s.stats.deficit.with_context(|| {
            format!("frame {k}: the deficit is missing with every tile resident")
        })?;
        worst_deficit = worst_deficit.max(deficit);
    }
    times.sort_by(f64::total_cmp);
    tris.sort_unstable();
    // Microseconds to the nanosecond: the clock's own resolution, without float noise.
    let ns = |us: f64| (us * 1e3).round() / 1e3;
    let pct = |q: f64| ns(times[((times.len() - 1) as f64 * q).round() as usize]);
    Ok(BenchSelectReport {
        file: b.file.display().to_string(),
        tiles: tables.len(),
        width: b.width,
        height: b.height,
        tau: b.tau,
        path: b.path.to_string(),
        fps: b.fps,
        frames: b.frames,
        median_us: pct(0.5),
        mean_us: ns(times.iter().sum::<f64>() / times.len() as f64),
        p90_us: pct(0.9),
        max_us: pct(1.0),
        median_triangles: tris[tris.len() / 2],
        worst_deficit,
    })
}
