//! Building a pyramid from a DEM, out of core
//! (docs/ARCHITECTURE.md#building-out-of-core).
//!
//! 1. File inputs are spooled row by row into a temporary raw file ([`spool`]);
//!    the synthetic terrain is generated on demand instead.
//! 2. Finest tiles are cut in Morton order, in parallel batches; each one measures
//!    its mesh errors for every spacing ([`mesh_error`]) and is encoded.
//! 3. A post-order walk of the Morton quadtree assembles each coarse tile as soon
//!    as its four children exist: heights by decimation (sample `(i, j)` of level
//!    `L` is sample `(2i, 2j)` of level `L+1`), errors by pooling the children's
//!    exact block maxima.
//! 4. [`writer`] lays the records out level by level in Morton order, verifies
//!    the file and renames it into place.
//!
//! Memory stays bounded by the batch of finest tiles in flight and one pending
//! quadruple of tiles per level, whatever the DEM's size.
//!
//! [`build_inputs`] ties the steps together: the input opened, sized and read
//! (`prepare`), the quadtree tiled (`tiling`: each tile a `node`, its records handed
//! to a `sink`), the pyramid written and verified.

mod coarse;
mod datum;
mod finest;
pub mod interrupt;
pub mod memory;
pub mod mesh_error;
mod node;
pub mod parts;
pub mod plausible;
mod prepare;
pub mod provenance;
pub mod share;
mod sink;
pub mod spool;
pub mod support;
mod tiling;
pub mod update;
pub mod writer;

use crate::ingest;
use crate::ingest::raster;
use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use prepare::{Loaded, prepare};
use std::path::Path;
use std::time::Instant;
use tessera_shared::{Level, LevelCounts, Metadata, TileGeometry, VerticalDatum};
use tiling::Tiling;

/// What `tessera-server build` was asked to do.
#[derive(Clone, Debug)]
pub struct BuildOptions {
    /// Tile size in cells (a power of two, 64..=4096).
    pub tile_size: u32,
    /// `metres = offset + scale · raw` for the input's samples.
    pub scale: f64,
    pub offset: f64,
    /// Bound on the memory the build uses, in bytes.
    pub memory_budget: u64,
    /// Most samples (width × height) an input may declare ([`plausible`]).
    pub max_samples: u64,
    /// Overrides the input's own no-data value (each input's, in a mosaic).
    pub nodata: Option<f64>,
    /// `--height-range`: the heights' range in metres that floating-point samples are
    /// quantized over, checked against every sample; `None`: the input's own range
    /// (known only once all of it is read).
    pub height_range: Option<[f64; 2]>,
    /// `--state`: also write `OUT.tess.state`, what `build --update` needs to update
    /// the pyramid later ([`update`]).
    pub state: bool,
    /// Which input wins where a mosaic's inputs overlap and disagree; `None`: an
    /// error on one grid, the finest input on different grids.
    pub overlap: Option<ingest::Overlap>,
    /// How samples are resampled (`--to`, and inputs on different grids).
    pub resampling: ingest::reproject::Resampling,
    /// The target spacing for inputs on different grids (`--spacing`; with `--to`,
    /// its `spacing` too).
    pub spacing: Option<[f64; 2]>,
    /// What the heights are measured from; `None`: what the input says, else unknown.
    pub vertical_datum: Option<VerticalDatum>,
    /// What the heights of inputs whose file name matches a pattern are measured
    /// from (before `vertical_datum`).
    pub vertical_per_input: Vec<(glob::Pattern, VerticalDatum)>,
    /// Convert every input's heights to this datum (`--to-vertical`).
    pub to_vertical: Option<VerticalDatum>,
    /// Blend seams between inputs over this many metres (`--feather`).
    pub feather: Option<f64>,
    /// Store every level everywhere, even where only coarser data lies
    /// (`--full-pyramid`; [`support`]).
    pub full_pyramid: bool,
    /// Assign this horizontal CRS (`--crs`: `EPSG:CODE` or a PROJ string) to the
    /// input, replacing its own: coordinates are relabelled, not transformed
    /// ([`ingest::assign`]). With a mosaic, to the mosaic (all its inputs).
    pub crs: Option<String>,
    /// Assign these outer pixel edges (`--bounds`, in the CRS's units) to the input,
    /// replacing its own geotransform. One input only (a file or a VRT).
    pub bounds: Option<ingest::assign::Bounds>,
    /// Resample to another CRS first (`--to`), from the one `crs` assigns if given.
    pub reproject: Option<ingest::reproject::ReprojectOptions>,
    /// Show progress bars (on a terminal).
    pub progress: bool,
    /// Set by SIGINT/SIGTERM (when installed): the build stops and cleans up.
    pub interrupt: interrupt::Interrupt,
}

impl Default for BuildOptions {
    fn default() -> Self {
        Self {
            tile_size: 512,
            scale: 1.0,
            offset: 0.0,
            memory_budget: 512 << 20,
            max_samples: plausible::DEFAULT_MAX_SAMPLES,
            nodata: None,
            height_range: None,
            state: false,
            overlap: None,
            resampling: ingest::reproject::Resampling::Bilinear,
            spacing: None,
            vertical_datum: None,
            vertical_per_input: Vec::new(),
            to_vertical: None,
            feather: None,
            full_pyramid: false,
            crs: None,
            bounds: None,
            reproject: None,
            progress: false,
            interrupt: interrupt::Interrupt::default(),
        }
    }
}

/// What a build produced.
#[derive(Clone, Debug)]
pub struct BuildReport {
    pub metadata: Metadata,
    pub samples: u64,
    pub tiles: u64,
    pub file_bytes: u64,
    pub seconds: f64,
    /// What the command prints after its summary, also under `--quiet`: the heights'
    /// vertical datum is unknown (`datum`).
    pub warnings: Vec<String>,
    /// Bytes fetched from object storage or HTTP for the inputs (`ingest::remote`).
    pub fetched: ingest::remote::Fetched,
}

fn bar(enabled: bool, len: u64, what: &str) -> ProgressBar {
    if !enabled {
        return ProgressBar::hidden();
    }
    let b = ProgressBar::new(len);
    b.set_style(
        ProgressStyle::with_template("{msg:>10} [{bar:40}] {pos}/{len} {per_sec} eta {eta}")
            .expect("static template")
            .progress_chars("=> "),
    );
    b.set_message(what.to_string());
    b
}

/// Builds `output` from `input` (a file path, a VRT or `synthetic:SIZE[:SEED]`).
pub fn build(input: &str, output: &Path, opts: &BuildOptions) -> anyhow::Result<BuildReport> {
    build_inputs(&ingest::InputSpec::one(input), output, opts)
}

/// Builds `output` from one input or a mosaic of many ([`ingest::open_inputs`]).
pub fn build_inputs(
    inputs: &ingest::InputSpec,
    output: &Path,
    opts: &BuildOptions,
) -> anyhow::Result<BuildReport> {
    let started = Instant::now();
    let _spools = ingest::remote::SpoolScope::new();
    let fetched_before = ingest::remote::fetched();
    let dir = output_dir(output);
    let folders = plausible::Folders {
        spool: dir.to_path_buf(),
        output: dir.to_path_buf(),
    };
    let prepared = prepare(inputs, &folders, 1, opts)?;
    let warnings = prepared.warnings.clone();
    let state = if opts.state {
        anyhow::ensure!(
            !output.to_string_lossy().contains("://"),
            "{}: --state writes a file beside the pyramid: give a local -o",
            output.display()
        );
        anyhow::ensure!(
            prepared.support.is_none(),
            "{}: --state is for pyramids stored whole; this collection builds a \
             multi-resolution one (add --full-pyramid)",
            prepared.label
        );
        let records = update::input_records(&prepared.input_windows)?;
        let writer =
            update::state::StateWriter::create(&update::state::path_of(output), prepared.geometry)?;
        Some((writer, records))
    } else {
        None
    };
    let writer = create_output(output, prepared.geometry, meta_reserve(&prepared.meta))
        .with_context(|| prepared.label.clone())?;
    let loaded = prepared.load(dir, opts, started)?;
    let (report, state) = build_tiles(&loaded, writer, state, opts, started)?;
    if let Some((writer, records)) = state {
        writer.finish(&report.metadata.content_hash, records)?;
    }
    let after = ingest::remote::fetched();
    Ok(BuildReport {
        warnings,
        fetched: after.since(fetched_before),
        ..report
    })
}

/// The folder beside `output` where its temporary files go.
fn output_dir(output: &Path) -> &Path {
    output
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// Room for the metadata once its numbers are final (they are all fixed-size or small).
fn meta_reserve(meta: &Metadata) -> u64 {
    let mut m = meta.clone();
    m.nodata_count = u64::MAX;
    m.content_hash = "0".repeat(16);
    m.level_counts = vec![
        LevelCounts {
            valid: u64::MAX,
            filled: u64::MAX,
        };
        usize::from(m.levels)
    ];
    tessera_shared::format::encode_metadata(&m).len() as u64 + 64
}

/// Creates the writer of a finished pyramid at `output`; with [`finish_output`], the
/// one way a pyramid reaches its output, for a whole build and an assembled one alike.
fn create_output(
    output: &Path,
    geometry: TileGeometry,
    meta_reserve: u64,
) -> anyhow::Result<writer::PyramidWriter> {
    writer::PyramidWriter::create(output, geometry, meta_reserve)
        .with_context(|| output.display().to_string())
}

/// Writes the pyramid's index, header and metadata, verifies the file and moves it
/// into place ([`writer::PyramidWriter::finish`]).
fn finish_output(
    writer: writer::PyramidWriter,
    meta: Metadata,
    geometry: &TileGeometry,
    opts: &BuildOptions,
    started: Instant,
) -> anyhow::Result<BuildReport> {
    let total_tiles = count_tiles(geometry, geometry.levels());
    let verify_bar = bar(opts.progress, total_tiles, "verifying");
    let target = writer.target().to_path_buf();
    let (metadata, file_bytes) = writer
        .finish(meta, &opts.interrupt, |n| verify_bar.inc(n))
        .with_context(|| format!("cannot finish {}", target.display()))?;
    verify_bar.finish_and_clear();
    tracing::debug!(
        seconds = started.elapsed().as_secs_f64(),
        "written and verified"
    );
    Ok(BuildReport {
        metadata,
        samples: u64::from(geometry.width()) * u64::from(geometry.height()),
        tiles: total_tiles,
        file_bytes,
        seconds: started.elapsed().as_secs_f64(),
        warnings: Vec::new(),
        fetched: ingest::remote::Fetched::default(),
    })
}

/// Tiles the geometry places inside the DEM at these levels.
fn count_tiles(geometry: &TileGeometry, levels: impl Iterator<Item = Level>) -> u64 {
    levels
        .map(|l| geometry.present_tiles(l).count() as u64)
        .sum()
}

/// A whole build: the root's subtree, then the metadata's numbers, then the file.
fn build_tiles<S>(
    loaded: &Loaded,
    writer: writer::PyramidWriter,
    mut state: Option<(update::state::StateWriter, S)>,
    opts: &BuildOptions,
    started: Instant,
) -> anyhow::Result<(BuildReport, Option<(update::state::StateWriter, S)>)> {
    let geometry = loaded.geometry;
    let raster = loaded.dem.raster();
    let mut writer = writer;
    let mut meta = loaded.meta.clone();
    let quant = meta.quantization;
    let tiles_bar = bar(
        opts.progress,
        count_tiles(&geometry, geometry.levels()),
        "tiling",
    );
    let tiling = Tiling {
        raster,
        geometry,
        quant,
        plan: loaded.plan,
        opts,
        bar: &tiles_bar,
        support: loaded.support.as_ref(),
    };
    let (min_q, max_q) = match state.as_mut() {
        Some((state, _)) => tiling.subtrees(
            &mut update::StateSink {
                pyramid: &mut writer,
                state,
                old: None,
            },
            Level::ROOT,
            0..1,
        )?,
        None => tiling.subtrees(&mut writer, Level::ROOT, 0..1)?,
    };
    tiles_bar.finish_and_clear();
    tracing::debug!(seconds = started.elapsed().as_secs_f64(), "tiles built");
    meta.min_height = quant.height(min_q);
    meta.max_height = quant.height(max_q);
    meta.level_counts = level_counts(&geometry, &raster.depth_counts());
    Ok((
        finish_output(writer, meta, &geometry, opts, started)?,
        state,
    ))
}
/// Valid and filled sample counts of each level (level 0 first) from the raster's
/// depth counts: level `L` samples every `2^(L_max − L)`-th column and row.
pub fn level_counts(geometry: &TileGeometry, depths: &raster::DepthCounts) -> Vec<LevelCounts> {
    let finest = usize::from(geometry.finest().get());
    (0..=finest)
        .map(|level| {
            let below = finest - level;
            depths[below..]
                .iter()
                .fold(LevelCounts::default(), |acc, [v, f]| LevelCounts {
                    valid: acc.valid + v,
                    filled: acc.filled + f,
                })
        })
        .collect()
}
