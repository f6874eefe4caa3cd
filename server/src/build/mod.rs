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
mod finest;
pub mod interrupt;
pub mod memory;
pub mod mesh_error;
pub mod raster;
pub mod spool;
pub mod writer;

use crate::ingest::{self, Input};
use anyhow::Context;
use coarse::Aggregator;
use finest::finest_node;
use indicatif::{ProgressBar, ProgressStyle};
use mesh_error::BlockErrors;
use raster::Raster;
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
    let dir = output
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
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
    let geometry =
        TileGeometry::new(width, height, opts.tile_size).with_context(|| input.to_string())?;
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
    let vertical_datum = opts.vertical_datum.unwrap_or_else(|| match &source {
        Input::Rows(r) => r.vertical_datum().unwrap_or_default(),
        Input::Synthetic(_) => VerticalDatum::Unknown,
    });
    let mut meta = Metadata {
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
        vertical_datum,
        level_counts: Vec::new(),
        georef,
        source: format!("{description} ({source_name})"),
        generator: format!("tessera-server {}", env!("CARGO_PKG_VERSION")),
        content_hash: String::new(),
    };
    let writer = writer::PyramidWriter::create(output, geometry, meta_reserve(&meta))
        .with_context(|| output.display().to_string())?;
    match source {
        Input::Rows(mut rows) => {
            let spool_bar = bar(opts.progress, u64::from(height), "reading");
            let spooled = spool::SpooledRaster::spool(
                rows.as_mut(),
                dir,
                spool_nodata,
                plan.band_bytes,
                |r| {
                    spool_bar.set_position(u64::from(r));
                    opts.interrupt.check()
                },
            )
            .with_context(|| input.to_string())?;
            spool_bar.finish_and_clear();
            tracing::debug!(seconds = started.elapsed().as_secs_f64(), "input spooled");
            meta.quantization = spooled.quantizer.to_metres(
                opts.scale,
                opts.offset,
                spooled.sample_type.is_integer(),
            );
            meta.nodata_count = spooled.nodata_count;
            build_tiles(&spooled, geometry, &mut meta, writer, opts, &plan, started)
        }
        Input::Synthetic(synth) => {
            meta.quantization = Quantization {
                offset: ingest::synthetic::OFFSET,
                scale: ingest::synthetic::SCALE,
                max_error: 0.0,
            };
            meta.nodata_fill = "none (synthetic)".into();
            build_tiles(&synth, geometry, &mut meta, writer, opts, &plan, started)
        }
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

fn build_tiles(
    raster: &dyn Raster,
    geometry: TileGeometry,
    meta: &mut Metadata,
    mut writer: writer::PyramidWriter,
    opts: &BuildOptions,
    plan: &memory::Plan,
    started: Instant,
) -> anyhow::Result<BuildReport> {
    let finest = geometry.finest();
    let t = geometry.tile_log2();
    // Spacings 0 ..= t + L_max: from the data itself to the root's single cell.
    let spacings = t + u32::from(finest.get()) + 1;
    let total_tiles: u64 = geometry
        .levels()
        .map(|l| geometry.present_tiles(l).count() as u64)
        .sum();
    let tiles_bar = bar(opts.progress, total_tiles, "tiling");
    let batch = plan.batch;
    let slots = finest.tile_slots();
    let quant = meta.quantization;
    let mut agg = Aggregator {
        geometry,
        quant,
        spacings,
        pending: (0..=finest.get())
            .map(|_| [None, None, None, None])
            .collect(),
        min_q: u16::MAX,
        max_q: 0,
        bar: &tiles_bar,
    };
    std::thread::scope(|scope| -> anyhow::Result<()> {
        let (tx, rx) =
            std::sync::mpsc::sync_channel::<anyhow::Result<Vec<Option<(Node, Encoded)>>>>(1);
        let producer = scope.spawn(move || {
            let mut start = 0u64;
            while start < slots {
                let end = (start + batch as u64).min(slots);
                let result: anyhow::Result<Vec<_>> = (start..end)
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
                start = end;
            }
        });
        let mut m = 0u64;
        for batch in rx {
            opts.interrupt.check()?;
            for item in batch? {
                agg.push(&mut writer, finest, Morton::from_raw(m), item)?;
                m += 1;
            }
        }
        producer.join().expect("tile producer panicked");
        anyhow::ensure!(m == slots, "tile production stopped early");
        Ok(())
    })?;
    tiles_bar.finish_and_clear();
    tracing::debug!(seconds = started.elapsed().as_secs_f64(), "tiles built");
    meta.min_height = quant.height(agg.min_q);
    meta.max_height = quant.height(agg.max_q);
    meta.level_counts = level_counts(&geometry, &raster.depth_counts());
    let verify_bar = bar(opts.progress, total_tiles, "verifying");
    let target = writer.target().to_path_buf();
    let (metadata, file_bytes) = writer
        .finish(meta.clone(), &opts.interrupt, |n| verify_bar.inc(n))
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
    })
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
