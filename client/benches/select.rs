//! Selection time per frame (BENCHMARKS.md "Selection time",
//! docs/ARCHITECTURE.md#measuring): `Selector::select` at 1920×1080, τ = 1 px, with every
//! tile resident, one selection per frame along a built-in path at 60 fps (`pass`, the
//! high fast traverse; and `canyon`, low and fast, the harder case), the selector's state
//! (quadtrees, refinements) carried from frame to frame as in a real flight.
//!
//! ```sh
//! cargo bench -p tessera-client --bench select
//! ```
//!
//! Each divan sample is one frame. The cameras are those of
//! `tessera_client::paths::path_cameras` (placed as `tessera fly` places them); the
//! camera runs the path forward and back (0, 1, …, N−1, N−2, …, 1, 0, 1, …) so that
//! consecutive frames are always neighbours on the path; the first frame, which
//! builds every quadtree from scratch, is selected once before timing starts. After
//! each run a line on stderr gives the selector's own clock (`FrameStats::select_us`,
//! what `tessera bench-select --path pass|canyon` reports for the same frames), the
//! median triangle count and the worst deficit.
//!
//! Pyramids: `$TESSERA_BENCH_MOON` and `$TESSERA_BENCH_SYNTH` name existing `.tess`
//! files; otherwise `cargo bench` builds them once into `target/bench-data/` with
//! `cargo run -p tessera-server --release -- build …` (the moon 8192² mosaic from
//! `../shared/data/dem` or `$TESSERA_DEM_DIR`, a few seconds; `synthetic:65537`,
//! about 95 s). A dataset whose input is missing is skipped with a message. In test
//! mode (`cargo test --benches`, `-- --test`) nothing is built: a dataset whose
//! pyramid is absent is skipped.

use anyhow::Context;
use divan::Bencher;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;
use tessera_client::paths::path_cameras;
use tessera_client::select::{SelectParams, Selector, World};
use tessera_shared::{ErrorTable, FileSource, Pyramid, TileId};

const FPS: f64 = 60.0;
const WIDTH: u32 = 1920;
const HEIGHT: u32 = 1080;
const TAU: f64 = 1.0;
/// Frames timed per dataset and path: `pass` (979 frames on any square DEM: the
/// path and its speed both scale with the extent) forward and back, or most of
/// `canyon` (2581 frames).
const FRAMES: u32 = 2000;

fn main() {
    divan::main();
}

static MOON_TERRAIN: OnceLock<Option<Terrain>> = OnceLock::new();
static SYNTH_TERRAIN: OnceLock<Option<Terrain>> = OnceLock::new();

/// The moon 8192² mosaic (LOLA/Kaguya GLD100, 118.45 m per sample).
#[divan::bench(args = ["pass", "canyon"], sample_count = FRAMES, sample_size = 1)]
fn moon_8192(bencher: Bencher, path: &str) {
    run(bencher, &MOON, &MOON_TERRAIN, path);
}

/// The synthetic 65537² terrain at 30 m per sample.
#[divan::bench(args = ["pass", "canyon"], sample_count = FRAMES, sample_size = 1)]
fn synthetic_65537(bencher: Bencher, path: &str) {
    run(bencher, &SYNTH, &SYNTH_TERRAIN, path);
}

/// A benchmark dataset: where its pyramid comes from.
struct Dataset {
    label: &'static str,
    /// Environment variable naming an existing pyramid.
    env: &'static str,
    /// File name under `target/bench-data/`.
    file: &'static str,
    /// `tessera-server build` input: a DEM file name in the DEM folder, or `synthetic:…`.
    input: &'static str,
    flags: &'static [&'static str],
    /// Metres between samples on both axes (as in BENCHMARKS.md's `bench-select`
    /// runs, which pass `--spacing`).
    spacing: f64,
}

const MOON: Dataset = Dataset {
    label: "moon 8192²",
    env: "TESSERA_BENCH_MOON",
    file: "moon8k.tess",
    input: "moon_crisium_gld100_8192.png",
    flags: &["--offset", "-10000"],
    spacing: 118.45,
};

const SYNTH: Dataset = Dataset {
    label: "synthetic:65537",
    env: "TESSERA_BENCH_SYNTH",
    file: "synthetic65537.tess",
    input: "synthetic:65537",
    flags: &[],
    spacing: 30.0,
};

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the client crate lives in the workspace")
        .to_path_buf()
}

fn bench_data_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map_or_else(|| workspace().join("target"), PathBuf::from)
        .join("bench-data")
}

/// Whether divan is benchmarking (`cargo bench`), as opposed to testing or listing.
fn benchmarking() -> bool {
    let args: Vec<String> = std::env::args().collect();
    args.iter().any(|a| a == "--bench") && !args.iter().any(|a| a == "--test" || a == "--list")
}

impl Dataset {
    /// The pyramid file, building it first when needed and allowed; `None` (after
    /// saying why) when the dataset must be skipped.
    fn pyramid(&self) -> Option<PathBuf> {
        if let Some(p) = std::env::var_os(self.env) {
            let p = PathBuf::from(p);
            if p.is_file() {
                return Some(p);
            }
            eprintln!(
                "\nSKIPPED {}: ${} = {} is not a file",
                self.label,
                self.env,
                p.display()
            );
            return None;
        }
        let out = bench_data_dir().join(self.file);
        if out.is_file() {
            return Some(out);
        }
        if !benchmarking() {
            eprintln!(
                "\nSKIPPED {}: {} is not built (`cargo bench` builds it; test mode never does)",
                self.label,
                out.display()
            );
            return None;
        }
        let input = if self.input.starts_with("synthetic:") {
            self.input.to_string()
        } else {
            let p = tessera_shared::testdata::dem_dir().join(self.input);
            if !p.is_file() {
                eprintln!(
                    "\nSKIPPED {}: its input {} is absent (set TESSERA_DEM_DIR, or {} to a built pyramid)",
                    self.label,
                    p.display(),
                    self.env
                );
                return None;
            }
            p.to_string_lossy().into_owned()
        };
        std::fs::create_dir_all(bench_data_dir()).expect("cannot create target/bench-data");
        eprintln!(
            "\nbuilding {} from {input} (once; synthetic:65537 takes about 95 s in release)",
            out.display()
        );
        let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
        let status = Command::new(cargo)
            .current_dir(workspace())
            .args(["run", "-q", "--release", "-p", "tessera-server", "--"])
            .args(["build", &input, "-o"])
            .arg(&out)
            .arg("--quiet")
            .args(self.flags)
            .status()
            .expect("cannot run cargo");
        assert!(
            status.success() && out.is_file(),
            "building {} failed ({status})",
            out.display()
        );
        Some(out)
    }
}

/// A pyramid with every error table resident.
struct Terrain {
    file: PathBuf,
    pyramid: Pyramid<FileSource>,
    world: World,
    tables: HashMap<TileId, ErrorTable>,
}

impl Terrain {
    fn load(file: &Path, spacing: f64) -> anyhow::Result<Self> {
        let p = Pyramid::open_file(file).with_context(|| file.display().to_string())?;
        let g = *p.geometry();
        let tables = tessera_client::select::all_tables(&p)?;
        Ok(Self {
            file: file.to_path_buf(),
            world: World {
                geometry: g,
                quant: p.metadata().quantization,
                spacing: glam::DVec2::splat(spacing),
                globe: None,
            },
            pyramid: p,
            tables,
        })
    }
}

fn run(bencher: Bencher, dataset: &Dataset, cell: &OnceLock<Option<Terrain>>, path: &str) {
    let terrain = cell.get_or_init(|| {
        let file = dataset.pyramid()?;
        Some(
            Terrain::load(&file, dataset.spacing)
                .unwrap_or_else(|e| panic!("{}: {e:#}", file.display())),
        )
    });
    let Some(terrain) = terrain else {
        return;
    };
    let cameras = path_cameras(&terrain.pyramid, &terrain.world, path, FPS, WIDTH, HEIGHT)
        .unwrap_or_else(|e| panic!("{}: {e:#}", terrain.file.display()));
    let n = cameras.len();
    // Forward and back: frame k of the sequence is camera `order[k % len]`.
    let order: Vec<usize> = (0..n).chain((1..n.saturating_sub(1)).rev()).collect();
    let mut selector = Selector::new(
        terrain.world,
        SelectParams {
            tau: TAU,
            ..SelectParams::default()
        },
    );
    // The first frame builds every quadtree from nothing: not a steady-state frame.
    selector.select(&cameras[0], &terrain.tables);
    let mut k = 1;
    let mut own_us = Vec::with_capacity(FRAMES as usize + 1);
    let mut triangles = Vec::with_capacity(FRAMES as usize + 1);
    let mut worst_deficit = 0f64;
    bencher.bench_local(|| {
        let camera = &cameras[order[k % order.len()]];
        k += 1;
        let s = selector.select(camera, &terrain.tables);
        own_us.push(s.stats.select_us);
        triangles.push(s.stats.triangles);
        // Everything is resident: the deficit is always bounded (∞ would say a bug).
        worst_deficit = worst_deficit.max(s.stats.deficit.unwrap_or(f64::INFINITY));
        s
    });
    own_us.sort_by(f64::total_cmp);
    triangles.sort_unstable();
    if let (Some(us), Some(tris)) = (
        own_us.get(own_us.len() / 2),
        triangles.get(triangles.len() / 2),
    ) {
        eprintln!(
            "\n{} `{path}`: {} tiles resident, {n} frames at {FPS} fps (run forward and back), {WIDTH}×{HEIGHT}, τ = {TAU} px, {} frames timed: selector's own clock median {us:.0} µs, median {tris} triangles, worst deficit {worst_deficit:.2}",
            dataset.label,
            terrain.tables.len(),
            own_us.len(),
        );
    }
}
