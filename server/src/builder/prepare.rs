//! An input opened, checked and sized before any sample is read (`--crs`, `--bounds`,
//! `--to`, the memory plan, the plausibility checks), then read: spooled, or
//! generated on demand for synthetic terrain.

use super::{BuildOptions, bar, datum, memory, plausible, share, spool};
use crate::ingest::raster::Raster;
use crate::ingest::{self, Input};
use anyhow::Context;
use std::path::Path;
use std::time::Instant;
use tessera_shared::{Metadata, Quantization, TileGeometry};

/// An input opened and sized, before any sample is read: its geometry, the memory
/// plan and the metadata but for what reading it tells (quantization, counts).
/// What a whole build and a part of a distributed build ([`parts`]) both start from.
pub(super) struct Prepared {
    source: Input,
    /// The no-data value the spool recognises (none after reprojection, which marks
    /// no-data as NaN itself).
    spool_nodata: Option<f64>,
    pub(super) label: String,
    pub(super) geometry: TileGeometry,
    plan: memory::Plan,
    pub(super) meta: Metadata,
    /// For [`BuildReport::warnings`].
    pub(super) warnings: Vec<String>,
    /// Which tiles a multi-resolution pyramid stores; `None`: all.
    pub(super) support: Option<super::support::Support>,
    /// Each input file and its window on the grid (`build --state`).
    pub(super) input_windows: Vec<(std::path::PathBuf, [u32; 4])>,
    /// Whether samples were resampled onto the grid (`--to`, or inputs on different
    /// grids): a changed input then reaches a little past its window.
    pub(super) resampled: bool,
}

/// The DEM as the tiler reads it.
pub(super) enum Dem {
    Spooled(Box<spool::SpooledRaster>),
    Synthetic(ingest::synthetic::Synthetic),
}

impl Dem {
    pub(super) fn raster(&self) -> &dyn Raster {
        match self {
            Dem::Spooled(s) => s.as_ref(),
            Dem::Synthetic(s) => s,
        }
    }
}

/// A [`Prepared`] input after reading: what the tiler reads, and the metadata with
/// its quantization (and, for a whole build, its no-data count) known.
pub(super) struct Loaded {
    pub(super) dem: Dem,
    pub(super) geometry: TileGeometry,
    pub(super) plan: memory::Plan,
    pub(super) meta: Metadata,
    pub(super) support: Option<super::support::Support>,
}

/// Opens the inputs, applies `--crs`/`--bounds`/`--to`, and sizes the pyramid; refuses
/// a raster larger than `--max-samples` or than the free disk space takes
/// ([`plausible`]) before any sample is read. `folders.spool` holds temporary files
/// (reprojection's, then the spool); `folders.output` gets `1/share` of the pyramid.
pub(super) fn prepare(
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
    let vertical = ingest::vertical_shift::VerticalOptions {
        all: opts.vertical_datum,
        per_input: opts.vertical_per_input.clone(),
        to: opts.to_vertical,
        scale: opts.scale,
    };
    let mosaic_opts = ingest::MosaicOptions {
        feather: opts.feather,
        vertical: vertical.clone(),
        nodata: opts.nodata,
        overlap: opts.overlap,
        grid: Some(ingest::GridOptions {
            to: opts.reproject.as_ref().map(|r| r.to.clone()),
            spacing: opts.spacing,
            resampling: opts.resampling,
            spool_dir: dir.to_path_buf(),
            max_samples: opts.max_samples,
        }),
    };
    let ingest::Opened {
        input: source,
        label,
        source_name,
        resampled,
        mosaic,
        inputs: mut input_summaries,
        coverage,
    } = ingest::open_inputs(inputs, &mosaic_opts)?;
    if opts.feather.is_some() && !mosaic {
        anyhow::bail!("{label}: --feather blends the seams between several inputs; this is one");
    }
    // Inputs on different grids were resampled onto one, --to and --spacing with them.
    let reproject = if resampled {
        None
    } else {
        opts.reproject.clone()
    };
    if reproject.is_none() && !resampled && opts.spacing.is_some() {
        anyhow::bail!(
            "{label}: --spacing needs --to, or inputs on different grids to resample onto one"
        );
    }
    if resampled && opts.crs.is_some() {
        anyhow::bail!(
            "{label}: --crs relabels one grid; these inputs are on different grids, so give \
             each its own CRS (its file's, a .prj beside it, or a VRT's <SRS>)"
        );
    }
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
    // One input's heights in the datum the user names for it (or it states),
    // converted to --to-vertical's once it is georeferenced (a mosaic converts each
    // of its inputs itself).
    let (source, flag) = match source {
        Input::Rows(rows) if !mosaic => {
            let path = Path::new(&label);
            let clue = vertical.datum_for(path, rows.datum_clue());
            let user = vertical.datum_for(path, None).and_then(|c| c.datum);
            input_summaries.push(ingest::InputSummary {
                name: source_name.clone(),
                georef: rows.info().georef.clone(),
                width: rows.info().width,
                height: rows.info().height,
                datum: clue.as_ref().and_then(|c| c.datum),
            });
            let nodata: Vec<f32> = opts.nodata.map(|v| v as f32).into_iter().collect();
            (
                Input::Rows(vertical.convert(rows, &label, clue.as_ref(), &nodata)?),
                opts.to_vertical.or(user),
            )
        }
        source => (source, opts.to_vertical),
    };
    // Decided on the input as read (georeferenced by --crs/--bounds if given), before
    // --to resamples it: reprojection moves the samples, not the heights' reference.
    let datum = datum::decide(flag, &source, &label);
    // What the inputs declare, checked before a sample is read: the source a `--to`
    // spools whole first, then the raster the pyramid is built from.
    let declared = match &source {
        Input::Rows(r) => Some(plausible::Declared {
            width: r.info().width,
            height: r.info().height,
        }),
        Input::Synthetic(_) => None,
    };
    let reproject_spool = match (declared, &reproject) {
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
    let (source, spool_nodata) = match (source, &reproject) {
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
    let what = if reproject.is_some() {
        "--to makes"
    } else if resampled {
        "the inputs' common grid makes"
    } else {
        "declares"
    };
    plausible::check_samples(input, what, size, opts.max_samples)?;
    let geometry =
        TileGeometry::new(width, height, opts.tile_size).with_context(|| input.to_string())?;
    let spool = match &source {
        // A part spools its share at least, and the whole input when its share
        // cannot stand alone (`share::read`): a warning if that cannot fit.
        Input::Rows(_) if share > 1 => {
            let whole = plausible::spool_need(size);
            plausible::DiskNeed {
                least: whole.least / u64::from(share),
                most: whole.most,
            }
        }
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
    let support = ground_spacing
        .filter(|_| !opts.full_pyramid)
        .and_then(|g| super::support::Support::new(&geometry, &coverage, (g.x * g.y).sqrt()));
    let sources =
        super::provenance::records(&input_summaries, ground_spacing, geometry.level_count() - 1);
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
        sources,
    };
    let input_windows = match &source {
        Input::Rows(r) => {
            let w = r.input_windows();
            if w.is_empty()
                && let ingest::inputs::Expanded::Files(files) = ingest::inputs::expand(inputs)?
            {
                files
                    .into_iter()
                    .map(|f| (f, [0, 0, width, height]))
                    .collect()
            } else {
                w
            }
        }
        Input::Synthetic(_) => Vec::new(),
    };
    Ok(Prepared {
        source,
        spool_nodata,
        label,
        geometry,
        plan,
        meta,
        warnings: datum.warning.into_iter().collect(),
        support,
        input_windows,
        resampled: resampled || reproject.is_some(),
    })
}

impl Prepared {
    /// Reads the input: a file is spooled into `dir` (its quantization and no-data
    /// count then known), synthetic terrain needs nothing.
    pub(super) fn load(
        self,
        dir: &Path,
        opts: &BuildOptions,
        started: Instant,
    ) -> anyhow::Result<Loaded> {
        let Prepared {
            source,
            spool_nodata,
            label,
            geometry,
            plan,
            mut meta,
            warnings: _,
            support,
            input_windows: _,
            resampled: _,
        } = self;
        let stated = stated_range(opts);
        let dem = match source {
            Input::Rows(mut rows) => {
                let spool_bar = bar(opts.progress, u64::from(geometry.height()), "reading");
                let spooled = spool::SpooledRaster::spool(
                    rows.as_mut(),
                    dir,
                    spool_nodata,
                    plan.band_bytes,
                    stated.as_ref(),
                    |r| {
                        spool_bar.set_position(u64::from(r));
                        opts.interrupt.check()
                    },
                )
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
            support,
        })
    }

    /// Reads only `footprint` of the input, for a part of a distributed build
    /// ([`share::read`]): the whole build's samples and quantization there, or
    /// why the share cannot stand alone (the caller then prepares and reads the whole
    /// input); with the samples read, `None` for synthetic terrain, generated where
    /// it is read.
    pub(super) fn load_share(
        self,
        dir: &Path,
        footprint: &share::footprint::Footprint,
        opts: &BuildOptions,
        started: Instant,
    ) -> anyhow::Result<Result<(Loaded, Option<u64>), String>> {
        let stated = stated_range(opts);
        let rows = match &self.source {
            Input::Synthetic(_) => return self.load(dir, opts, started).map(|l| Ok((l, None))),
            Input::Rows(rows) => rows,
        };
        if let Some(why) = share::read::needs_whole(rows.as_ref(), stated.as_ref()) {
            return Ok(Err(why));
        }
        let Prepared {
            source,
            spool_nodata,
            label,
            geometry,
            plan,
            mut meta,
            warnings: _,
            support,
            input_windows: _,
            resampled: _,
        } = self;
        let Input::Rows(mut rows) = source else {
            unreachable!("synthetic terrain returned above")
        };
        let quantizer = share::read::quantizer(rows.as_ref(), stated.as_ref());
        let info = rows.info().clone();
        let share = share::read::read(
            rows.as_mut(),
            footprint,
            dir,
            spool_nodata,
            stated.as_ref(),
            plan.band_bytes,
            || opts.interrupt.check(),
        )
        .with_context(|| label.clone())?;
        let (file, samples) = match share {
            share::read::Share::Read { file, samples } => (file, samples),
            share::read::Share::Whole(why) => return Ok(Err(why)),
        };
        tracing::debug!(
            seconds = started.elapsed().as_secs_f64(),
            samples,
            "share spooled"
        );
        meta.quantization =
            quantizer.to_metres(opts.scale, opts.offset, info.sample_type.is_integer());
        let spooled = spool::SpooledRaster::from_share(
            file,
            info.width,
            info.height,
            quantizer,
            info.sample_type,
        );
        Ok(Ok((
            Loaded {
                dem: Dem::Spooled(Box::new(spooled)),
                geometry,
                plan,
                meta,
                support,
            },
            Some(samples),
        )))
    }
}

/// `--height-range` in the input's raw values.
fn stated_range(opts: &BuildOptions) -> Option<spool::StatedRange> {
    opts.height_range
        .map(|m| spool::StatedRange::new(m, opts.scale, opts.offset))
}

/// The CRS's PROJ string and WKT, and the ground spacing at the DEM's centre
/// (docs/ARCHITECTURE.md#coordinate-systems), from the projection library. A CRS it does
/// not know leaves both out, with a warning: the pyramid is still right, clients fall
/// back to a spacing.
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
