//! Building a pyramid from a DEM, out of core (DESIGN §3).
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

mod coarse;
mod datum;
mod finest;
pub mod interrupt;
pub mod memory;
pub mod mesh_error;
pub mod parts;
pub mod plausible;
pub mod spool;
pub mod writer;

use crate::ingest::raster::{self, Raster};
use crate::ingest::{self, Input};
use anyhow::Context;
use coarse::Aggregator;
use finest::finest_node;
use indicatif::{ProgressBar, ProgressStyle};
use mesh_error::BlockErrors;
use rayon::prelude::*;
use std::path::Path;
use std::time::Instant;
use tessera_shared::error_table::round_up_f32;
use tessera_shared::format::{FLAG_PARTIAL, IndexEntry};
use tessera_shared::tile::BLOCKS;
use tessera_shared::{
    CellMask, ErrorTable, Level, LevelCounts, Metadata, Morton, Quantization, TileGeometry, TileId,
    VerticalDatum, codec,
};

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
    /// Which input wins where a mosaic's inputs overlap and disagree.
    pub overlap: ingest::Overlap,
    /// What the heights are measured from; `None`: what the input says, else unknown.
    pub vertical_datum: Option<VerticalDatum>,
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
            overlap: ingest::Overlap::Error,
            vertical_datum: None,
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
    /// vertical datum is unknown ([`datum`]).
    pub warnings: Vec<String>,
}

/// A tile with what its parent needs: heights, exact block errors for every spacing,
/// and block min/max (empty blocks are `min = u16::MAX, max = 0`).
struct Node {
    heights: Vec<u16>,
    errors: BlockErrors,
    min: [u16; 64],
    max: [u16; 64],
    /// Which cells are terrain (FORMAT.md "Validity mask").
    mask: CellMask,
}

/// An encoded record and its index summary; `None` record for a tile inside the DEM
/// that holds no terrain cell (it is absent from the file, but its node still feeds
/// its parent's heights).
struct Encoded {
    record: Option<Vec<u8>>,
    summary: IndexEntry,
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
    let dir = output_dir(output);
    let folders = plausible::Folders {
        spool: dir.to_path_buf(),
        output: dir.to_path_buf(),
    };
    let prepared = prepare(inputs, &folders, 1, opts)?;
    let warnings = prepared.warnings.clone();
    let writer = create_output(output, prepared.geometry, meta_reserve(&prepared.meta))
        .with_context(|| prepared.label.clone())?;
    let loaded = prepared.load(dir, opts, started, None)?;
    let report = build_tiles(&loaded, writer, opts, started)?;
    Ok(BuildReport { warnings, ..report })
}

/// The folder beside `output` where its temporary files go.
fn output_dir(output: &Path) -> &Path {
    output
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// An input opened and sized, before any sample is read: its geometry, the memory
/// plan and the metadata but for what reading it tells (quantization, counts).
/// What a whole build and a part of a distributed build ([`parts`]) both start from.
struct Prepared {
    source: Input,
    /// The no-data value the spool recognises (none after reprojection, which marks
    /// no-data as NaN itself).
    spool_nodata: Option<f64>,
    label: String,
    geometry: TileGeometry,
    plan: memory::Plan,
    meta: Metadata,
    /// For [`BuildReport::warnings`].
    warnings: Vec<String>,
}

/// The DEM as the tiler reads it.
enum Dem {
    Spooled(Box<spool::SpooledRaster>),
    Synthetic(ingest::synthetic::Synthetic),
}

impl Dem {
    fn raster(&self) -> &dyn Raster {
        match self {
            Dem::Spooled(s) => s.as_ref(),
            Dem::Synthetic(s) => s,
        }
    }
}

/// A [`Prepared`] input after reading: what the tiler reads, and the metadata with
/// its quantization (and, for a whole build, its no-data count) known.
struct Loaded {
    dem: Dem,
    geometry: TileGeometry,
    plan: memory::Plan,
    meta: Metadata,
}

/// Opens the inputs, applies `--crs`/`--bounds`/`--to`, and sizes the pyramid; refuses
/// a raster larger than `--max-samples` or than the free disk space takes
/// ([`plausible`]) before any sample is read. `folders.spool` holds temporary files
/// (reprojection's, then the spool); `folders.output` gets `1/share` of the pyramid.
fn prepare(
    inputs: &ingest::InputSpec,
    folders: &plausible::Folders,
    share: u32,
    opts: &BuildOptions,
) -> anyhow::Result<Prepared> {
    let dir = folders.spool.as_path();
    anyhow::ensure!(
        opts.scale.is_finite() && opts.scale > 0.0 && opts.offset.is_finite(),
        "--scale must be a positive number and --offset a finite number"
    );
    // Flag errors before any input is read.
    let assigned_crs = opts
        .crs
        .as_deref()
        .map(|s| crate::crs::Crs::parse(s).context("--crs"))
        .transpose()?;
    if opts.bounds.is_some()
        && let ingest::inputs::Expanded::Files(files) = ingest::inputs::expand(inputs)?
        && files.len() > 1
    {
        anyhow::bail!(
            "{} and {} more: --bounds places one raster, not a mosaic of {} inputs; give \
             each input its own georeferencing (GeoTIFFs, or a VRT)",
            files[0].display(),
            files.len() - 1,
            files.len()
        );
    }
    let ingest::Opened {
        input: source,
        label,
        source_name,
    } = ingest::open_inputs(inputs, opts.nodata, opts.overlap)?;
    let source = match source {
        Input::Rows(rows) => Input::Rows(
            ingest::assign::assign(rows, assigned_crs.as_ref(), opts.bounds, &label)
                .with_context(|| label.clone())?,
        ),
        Input::Synthetic(_) if assigned_crs.is_some() || opts.bounds.is_some() => {
            anyhow::bail!(
                "{label}: --crs and --bounds need a file input; synthetic terrain has no grid \
                 to georeference"
            )
        }
        source @ Input::Synthetic(_) => source,
    };
    // Decided on the input as read (georeferenced by --crs/--bounds if given), before
    // --to resamples it: reprojection moves the samples, not the heights' reference.
    let datum = datum::decide(opts.vertical_datum, &source, &label);
    // What the inputs declare, checked before a sample is read: the source a `--to`
    // spools whole first, then the raster the pyramid is built from.
    let declared = match &source {
        Input::Rows(r) => Some(plausible::Declared {
            width: r.info().width,
            height: r.info().height,
        }),
        Input::Synthetic(_) => None,
    };
    let reproject_spool = match (declared, &opts.reproject) {
        (Some(size), Some(_)) => {
            plausible::check_samples(&label, "declares", size, opts.max_samples)?;
            let need = plausible::reproject_need(size);
            plausible::check_disk(
                &label,
                &format!("declares {}", size.describe()),
                folders,
                need,
                plausible::DiskNeed::default(),
            )?;
            need
        }
        _ => plausible::DiskNeed::default(),
    };
    // Reprojection reads the source whole first; its output marks no-data as NaN,
    // so the spool below needs no no-data value of its own.
    let (source, spool_nodata) = match (source, &opts.reproject) {
        (Input::Rows(rows), Some(r)) => (
            Input::Rows(Box::new(
                ingest::reproject::Reprojected::new(rows, r, opts.nodata, dir)
                    .with_context(|| label.clone())?,
            )),
            None,
        ),
        (Input::Synthetic(_), Some(_)) => {
            anyhow::bail!("{label}: --to needs a georeferenced input; synthetic terrain has no CRS")
        }
        (source, None) => (source, opts.nodata),
    };
    let input = label.as_str();
    let (width, height) = match &source {
        Input::Rows(r) => (r.info().width, r.info().height),
        Input::Synthetic(s) => (s.width(), s.height()),
    };
    let size = plausible::Declared { width, height };
    let what = if opts.reproject.is_some() {
        "--to makes"
    } else {
        "declares"
    };
    plausible::check_samples(input, what, size, opts.max_samples)?;
    let geometry =
        TileGeometry::new(width, height, opts.tile_size).with_context(|| input.to_string())?;
    let spool = match &source {
        Input::Rows(_) => plausible::spool_need(size),
        Input::Synthetic(_) => plausible::DiskNeed::default(),
    };
    plausible::check_disk(
        input,
        &format!("{what} {}", size.describe()),
        folders,
        reproject_spool + spool,
        plausible::output_need(&geometry, share),
    )?;
    let input_bytes = match &source {
        Input::Rows(r) => r.buffer_bytes(),
        Input::Synthetic(s) => s.memory_bytes(),
    };
    let plan = memory::Plan::new(&geometry, input_bytes, opts.memory_budget)
        .with_context(|| input.to_string())?;
    let (description, mut georef) = match &source {
        Input::Rows(r) => (r.info().description.clone(), r.info().georef.clone()),
        Input::Synthetic(s) => (s.description(), None),
    };
    let ground_spacing = georef
        .as_mut()
        .and_then(|g| ground_geometry(g, width, height, input));
    let meta = Metadata {
        width,
        height,
        tile_size: opts.tile_size,
        levels: geometry.level_count(),
        quantization: Quantization {
            offset: 0.0,
            scale: 1.0,
            max_error: 0.0,
        },
        min_height: 0.0,
        max_height: 0.0,
        nodata_count: 0,
        nodata_fill: "nearest valid sample".into(),
        ground_spacing,
        vertical_datum: datum.datum,
        level_counts: Vec::new(),
        georef,
        source: format!("{description} ({source_name})"),
        generator: format!("tessera-server {}", env!("CARGO_PKG_VERSION")),
        content_hash: String::new(),
    };
    Ok(Prepared {
        source,
        spool_nodata,
        label,
        geometry,
        plan,
        meta,
        warnings: datum.warning.into_iter().collect(),
    })
}

impl Prepared {
    /// Reads the input: a file is spooled into `dir` (its quantization and no-data
    /// count then known), synthetic terrain needs nothing. With `digest`, every raw
    /// sample read is hashed into it too (a part's fingerprint of its input).
    fn load(
        self,
        dir: &Path,
        opts: &BuildOptions,
        started: Instant,
        digest: Option<&mut xxhash_rust::xxh3::Xxh3>,
    ) -> anyhow::Result<Loaded> {
        let Prepared {
            source,
            spool_nodata,
            label,
            geometry,
            plan,
            mut meta,
            warnings: _,
        } = self;
        let dem = match source {
            Input::Rows(mut rows) => {
                let spool_bar = bar(opts.progress, u64::from(geometry.height()), "reading");
                let mut digesting;
                let rows: &mut dyn ingest::RowSource = match digest {
                    Some(hash) => {
                        digesting = parts::part::Digesting::new(rows.as_mut(), hash);
                        &mut digesting
                    }
                    None => rows.as_mut(),
                };
                let spooled =
                    spool::SpooledRaster::spool(rows, dir, spool_nodata, plan.band_bytes, |r| {
                        spool_bar.set_position(u64::from(r));
                        opts.interrupt.check()
                    })
                    .with_context(|| label.clone())?;
                spool_bar.finish_and_clear();
                tracing::debug!(seconds = started.elapsed().as_secs_f64(), "input spooled");
                meta.quantization = spooled.quantizer.to_metres(
                    opts.scale,
                    opts.offset,
                    spooled.sample_type.is_integer(),
                );
                meta.nodata_count = spooled.nodata_count;
                Dem::Spooled(Box::new(spooled))
            }
            Input::Synthetic(synth) => {
                meta.quantization = Quantization {
                    offset: ingest::synthetic::OFFSET,
                    scale: ingest::synthetic::SCALE,
                    max_error: 0.0,
                };
                meta.nodata_fill = "none (synthetic)".into();
                Dem::Synthetic(synth)
            }
        };
        Ok(Loaded {
            dem,
            geometry,
            plan,
            meta,
        })
    }
}

/// The CRS's PROJ string and WKT, and the ground spacing at the DEM's centre
/// (DESIGN §9), from the projection library. A CRS it does not know leaves both
/// out, with a warning: the pyramid is still right, clients fall back to a spacing.
fn ground_geometry(
    georef: &mut tessera_shared::GeoRef,
    width: u32,
    height: u32,
    input: &str,
) -> Option<tessera_shared::GroundSpacing> {
    let Some(crs) = crate::crs::Crs::of(georef) else {
        tracing::warn!(
            input,
            crs = georef.crs_name.as_deref().unwrap_or("unnamed"),
            "the CRS has no EPSG code the projection library knows: no ground spacing recorded"
        );
        return None;
    };
    crs.describe(georef);
    match crate::crs::ground_spacing(georef, width, height) {
        Ok(s) => Some(s),
        Err(e) => {
            tracing::warn!(input, "no ground spacing: {e:#}");
            None
        }
    }
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

/// Where the tiler's output goes: a pyramid file ([`writer::PyramidWriter`]) or a
/// part of a distributed build ([`parts`]).
trait Sink {
    /// A tile's record and its index summary; each level's arrive in Morton order.
    fn record(
        &mut self,
        level: Level,
        m: Morton,
        record: &[u8],
        summary: IndexEntry,
    ) -> anyhow::Result<()>;

    /// A tile of the top level the tiler assembles (`None`: absent), in Morton order.
    fn top(&mut self, m: Morton, node: Option<Node>) -> anyhow::Result<()>;
}

impl Sink for writer::PyramidWriter {
    fn record(
        &mut self,
        level: Level,
        m: Morton,
        record: &[u8],
        summary: IndexEntry,
    ) -> anyhow::Result<()> {
        self.push(level, m, record, summary)
    }

    /// A pyramid's top is its root: nothing waits for it.
    fn top(&mut self, _m: Morton, _node: Option<Node>) -> anyhow::Result<()> {
        Ok(())
    }
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
    })
}

/// Tiles the geometry places inside the DEM at these levels.
fn count_tiles(geometry: &TileGeometry, levels: impl Iterator<Item = Level>) -> u64 {
    levels
        .map(|l| geometry.present_tiles(l).count() as u64)
        .sum()
}

/// A whole build: the root's subtree, then the metadata's numbers, then the file.
fn build_tiles(
    loaded: &Loaded,
    writer: writer::PyramidWriter,
    opts: &BuildOptions,
    started: Instant,
) -> anyhow::Result<BuildReport> {
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
    };
    let (min_q, max_q) = tiling.subtrees(&mut writer, Level::ROOT, 0..1)?;
    tiles_bar.finish_and_clear();
    tracing::debug!(seconds = started.elapsed().as_secs_f64(), "tiles built");
    meta.min_height = quant.height(min_q);
    meta.max_height = quant.height(max_q);
    meta.level_counts = level_counts(&geometry, &raster.depth_counts());
    finish_output(writer, meta, &geometry, opts, started)
}

/// What the tiler reads and how: shared by a whole build and a part.
struct Tiling<'a> {
    raster: &'a dyn Raster,
    geometry: TileGeometry,
    quant: Quantization,
    plan: memory::Plan,
    opts: &'a BuildOptions,
    bar: &'a ProgressBar,
}

impl Tiling<'_> {
    /// Builds the subtrees of the level-`top` tiles with Morton codes `tops`: cuts,
    /// measures and encodes their finest tiles in parallel batches, in Morton order,
    /// and assembles every tile up to level `top` as soon as its four children exist.
    /// Records go to `sink` (each level in Morton order), level-`top` nodes to
    /// [`Sink::top`]. A whole build is the root's subtree (`top` 0, `tops` 0..1).
    /// Returns the range of the finest records' quantized heights (`u16::MAX, 0`
    /// when there is none).
    fn subtrees(
        &self,
        sink: &mut dyn Sink,
        top: Level,
        tops: std::ops::Range<u64>,
    ) -> anyhow::Result<(u16, u16)> {
        let Tiling {
            raster,
            geometry,
            quant,
            plan,
            opts,
            bar,
        } = *self;
        let finest = geometry.finest();
        let t = geometry.tile_log2();
        // Spacings 0 ..= t + L_max: from the data itself to the root's single cell.
        let spacings = t + u32::from(finest.get()) + 1;
        let batch = plan.batch;
        let depth = 2 * u32::from(finest.get() - top.get());
        let (first, end) = (tops.start << depth, tops.end << depth);
        let mut agg = Aggregator {
            geometry,
            quant,
            spacings,
            top,
            pending: (0..=finest.get())
                .map(|_| [None, None, None, None])
                .collect(),
            min_q: u16::MAX,
            max_q: 0,
            bar,
        };
        std::thread::scope(|scope| -> anyhow::Result<()> {
            let (tx, rx) =
                std::sync::mpsc::sync_channel::<anyhow::Result<Vec<Option<(Node, Encoded)>>>>(1);
            let producer = scope.spawn(move || {
                let mut start = first;
                while start < end {
                    let stop = (start + batch as u64).min(end);
                    let result: anyhow::Result<Vec<_>> = (start..stop)
                        .into_par_iter()
                        .map(|m| {
                            let tile =
                                TileId::from_morton(finest, Morton::from_raw(m)).expect("m < 4^L");
                            if !geometry.is_present(tile) {
                                return Ok(None);
                            }
                            let node = finest_node(raster, &geometry, tile, spacings)?;
                            let enc = encode(&node, &geometry, finest, &quant);
                            Ok(Some((node, enc)))
                        })
                        .collect();
                    let failed = result.is_err();
                    if tx.send(result).is_err() || failed {
                        return;
                    }
                    start = stop;
                }
            });
            let mut m = first;
            for batch in rx {
                opts.interrupt.check()?;
                for item in batch? {
                    agg.push(sink, finest, Morton::from_raw(m), item)?;
                    m += 1;
                }
            }
            producer.join().expect("tile producer panicked");
            anyhow::ensure!(m == end, "tile production stopped early");
            Ok(())
        })?;
        Ok((agg.min_q, agg.max_q))
    }
}

/// Errors in quantization steps → metres, rounded up so the bound stays conservative.
fn to_metres(steps: f64, q: &Quantization) -> f32 {
    if steps == 0.0 {
        0.0
    } else {
        round_up_f32((steps * q.scale).next_up())
    }
}

fn encode(node: &Node, g: &TileGeometry, level: Level, q: &Quantization) -> Encoded {
    let t = g.tile_log2();
    let mut table = ErrorTable::empty(t);
    let below = u32::from(g.finest().get() - level.get());
    for n in 0..=t {
        let k = t - n + below;
        for by in 0..BLOCKS {
            for bx in 0..BLOCKS {
                table.set_error(n, bx, by, to_metres(node.errors.get(k, bx, by), q));
            }
        }
    }
    for by in 0..BLOCKS {
        for bx in 0..BLOCKS {
            let i = (by * BLOCKS + bx) as usize;
            table.set_block_range(bx, by, node.min[i], node.max[i]);
        }
    }
    let (min, max) = table.tile_range();
    let partial = !node.mask.is_all_valid();
    Encoded {
        record: (!node.mask.is_none_valid())
            .then(|| codec::encode_record(&table, &node.mask, &node.heights)),
        summary: IndexEntry {
            min,
            max,
            full_res_error: table.full_resolution_error(),
            flags: if partial { FLAG_PARTIAL } else { 0 },
            ..IndexEntry::default()
        },
    }
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
