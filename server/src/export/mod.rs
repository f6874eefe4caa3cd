//! `tessera-server export`: a dataset's standard-grid tiles — heights (Terrarium,
//! Terrain-RGB), a rendered layer (hillshade, colour relief, slope) or contour lines
//! (vector tiles) — written into one PMTiles v3 archive for serverless web maps
//! (DECISIONS.md "PMTiles export").
//!
//! Each tile is made by the very code that serves it (`routes::web_grid::make`,
//! `routes::rendered::make`, `routes::contours::make`), so an archive's tile is byte
//! for byte the server's tile of the same z/x/y (or, with `--precision auto`, its
//! heights rounded: [`precision`]; vector tiles are stored gzipped).
//! Tiles are made in parallel under the server's compute admission (slots and a
//! memory budget), read through a bounded cache of decoded pyramid tiles, and written
//! in PMTiles tile-id order (a clustered archive) as they come, with identical tiles
//! stored once (the `pmtiles` crate's content-hash deduplication): memory stays
//! bounded by the cache, the budget and the archive's directory (~24 bytes a tile).
//! The archive is written beside its destination and renamed into place when whole,
//! or, for an object URL, uploaded with a multipart upload completed only then.

pub mod precision;

use crate::serve::compute::{Compute, ComputeLimits, Kind as ComputeKind};
use crate::serve::registry::Registry;
use crate::serve::routes::contours;
use crate::serve::routes::elevation::CachedTiles;
use crate::serve::routes::rendered::{self, Style};
use crate::serve::routes::web_grid;
use crate::serve::routes::wmts::tile_limits;
use crate::serve::web_cache::{Look, MadeKey, WebConfig, WebTiles, dataset_key};
use crate::storage::upload;
use crate::web::contour::vector_tile::Levels;
use crate::web::encoding::{Encoding, ImageFormat, NoData, TileFormat};
use crate::web::footprint::Footprint;
use crate::web::render::{Kind, Layer};
use crate::web::tile_matrix::{TileMatrixSet, WebTile};
use anyhow::{Context, anyhow, bail};
use futures_util::StreamExt;
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// The tiles' image format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    Png,
    /// Lossless WebP.
    Webp,
}

/// How exactly heights are kept.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Precision {
    /// As the server's tiles.
    Exact,
    /// Rounded to a step that grows with each zoom's pixel size (at most 1/64 of a
    /// pixel at the equator), for smaller archives.
    Auto,
}

/// `tessera-server export`'s arguments.
#[derive(Debug, clap::Args)]
pub struct ExportArgs {
    /// The pyramid: a .tess file, or an object URL (s3://BUCKET/KEY.tess, …, as `serve` takes).
    pub file: PathBuf,
    /// The PMTiles v3 archive to write: a file, or an object URL (s3://BUCKET/KEY.pmtiles: a multipart upload completed only when the archive is whole). Nothing is left behind on failure.
    #[arg(long, value_name = "OUT.pmtiles")]
    pub pmtiles: PathBuf,
    /// The tile grid. PMTiles v3 archives hold Web Mercator (XYZ) tiles only.
    #[arg(long, default_value = "webmercator", value_name = "GRID")]
    pub grid: String,
    /// Height tiles in this encoding: terrarium, or mapbox (Terrain-RGB) [default: terrarium].
    #[arg(long, conflicts_with = "layer", value_name = "ENCODING")]
    pub encoding: Option<String>,
    /// A rendered layer instead of heights: hillshade, color-relief or slope; or contours (vector tiles of contour lines, 512 px, whatever --format and --size say).
    #[arg(long, value_name = "LAYER")]
    pub layer: Option<String>,
    /// A layer option as the tile URLs take it (azimuth=200, method=multidirectional, ramp=relative, unit=percent, interval=20, index=5, …); repeatable.
    #[arg(long = "option", value_name = "KEY=VALUE", requires = "layer")]
    pub options: Vec<String>,
    /// A colour ramp in gdaldem's color-relief format, for `--option ramp=NAME` (repeatable), as `serve --ramp`.
    #[arg(long, value_name = "NAME=FILE")]
    pub ramp: Vec<String>,
    /// The tiles' image format.
    #[arg(long, value_enum, default_value = "png")]
    pub format: Format,
    /// Tile size in pixels: 256 or 512.
    #[arg(long, default_value_t = 256, value_name = "PX")]
    pub size: u32,
    /// The first zoom written.
    #[arg(long, default_value_t = 0, value_name = "Z")]
    pub minzoom: u8,
    /// The last zoom written [default: the dataset's TileJSON maxzoom at this size; deeper zooms only magnify, and maps over-zoom by themselves].
    #[arg(long, value_name = "Z")]
    pub maxzoom: Option<u8>,
    /// Heights exactly as the server's tiles, or rounded per zoom (auto: to the largest power-of-two multiple of the encoding's step within 1/32 of the zoom's equatorial pixel, so within 1/64 of a pixel).
    #[arg(long, value_enum, default_value = "exact")]
    pub precision: Precision,
    /// Tiles made at once [default: the cores].
    #[arg(long, value_name = "N")]
    pub jobs: Option<usize>,
    /// No progress bar.
    #[arg(long, short)]
    pub quiet: bool,
}

/// What an export wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct Exported {
    /// Tiles addressed by the archive.
    pub tiles: u64,
    /// Distinct tile contents stored.
    pub unique: u64,
    /// The tiles' bytes before deduplication (and, for vector tiles, before gzip).
    pub tile_bytes: u64,
    /// The archive's size.
    pub archive_bytes: u64,
    pub seconds: f64,
}

/// How one tile is made.
enum Maker {
    /// Heights, rounded to a step (`--precision auto`).
    Heights(Option<f64>),
    Rendered(Layer),
    /// Contours at the tile's zoom's levels (known valid before any tile is made).
    Contours(crate::http::error::ApiResult<Levels>),
}

/// What each tile shows.
#[derive(Debug)]
enum Shows {
    Heights(Encoding),
    Rendered(Style),
    Contours(contours::Style),
}

/// Runs `export`; a one-line summary on stderr.
pub fn run(args: &ExportArgs) -> anyhow::Result<Exported> {
    let tms = TileMatrixSet::parse(&args.grid)
        .ok_or_else(|| anyhow!("--grid {}: the grids are webmercator and crs84", args.grid))?;
    if tms != TileMatrixSet::WebMercatorQuad {
        bail!(
            "--grid {}: PMTiles v3 archives hold Web Mercator (XYZ) tiles only; export --grid webmercator",
            args.grid
        );
    }
    if !web_grid::SIZES.contains(&args.size) {
        bail!("--size {}: sizes are 256 and 512", args.size);
    }
    let ds = Registry::open_one(&args.file)?;
    let fp = Arc::new(
        Footprint::new(ds.pyramid.metadata())
            .map_err(|e| anyhow!("{}: no place on a map: {e}", args.file.display()))?,
    );
    let contour_lines = args.layer.as_deref() == Some("contours");
    let px = if contour_lines {
        contours::GRID
    } else {
        args.size
    };
    let deepest = fp.max_zoom(tms, px);
    let maxzoom = args.maxzoom.unwrap_or(deepest);
    if maxzoom > deepest {
        bail!(
            "--maxzoom {maxzoom}: beyond the data: {}'s finest zoom at {px} px is {deepest} (deeper zooms only magnify; maps over-zoom by themselves)",
            ds.name,
        );
    }
    if args.minzoom > maxzoom {
        bail!("--minzoom {} is beyond --maxzoom {maxzoom}", args.minzoom);
    }
    let shows = match &args.layer {
        None => {
            let e = Encoding::from_query(args.encoding.as_deref())
                .map_err(|e| anyhow!("--{}", e.to_string().trim_start_matches("unknown ")))?;
            Shows::Heights(e)
        }
        Some(layer) => {
            if args.precision == Precision::Auto {
                bail!(
                    "--precision auto rounds heights: it is for height tiles, not --layer {layer}"
                );
            }
            let mut query = HashMap::new();
            for o in &args.options {
                let (k, v) = o
                    .split_once('=')
                    .ok_or_else(|| anyhow!("--option {o}: give KEY=VALUE, e.g. azimuth=200"))?;
                query.insert(k.to_string(), v.to_string());
            }
            if contour_lines {
                let style =
                    contours::style(&query).map_err(|e| anyhow!("--option: {}", e.message))?;
                // Every zoom's interval is known before a tile is made.
                for z in args.minzoom..=maxzoom {
                    style.levels(&fp, tms, z).map_err(|e| {
                        anyhow!("--option {}; raise --minzoom or the interval", e.message)
                    })?;
                }
                Shows::Contours(style)
            } else {
                const LAYERS: &str = "hillshade, color-relief, slope and contours";
                let kind = Kind::parse(layer)
                    .ok_or_else(|| anyhow!("--layer {layer}: the layers are {LAYERS}"))?;
                let ramps =
                    crate::serve::config::ramps(&args.ramp, std::collections::BTreeMap::default())?;
                let style = rendered::style(&ramps, &ds, kind, &query, &[])
                    .map_err(|e| anyhow!("--option: {}", e.message))?;
                Shows::Rendered(style)
            }
        }
    };
    let format = match (&shows, args.format) {
        (Shows::Contours(_), _) => TileFormat::Mvt,
        (_, Format::Png) => TileFormat::Image(ImageFormat::Png),
        (_, Format::Webp) => TileFormat::Image(ImageFormat::Webp),
    };
    // Every tile of each zoom within the dataset's bounds (what its TileJSON states),
    // in PMTiles tile-id order: the archive is clustered.
    let mut tiles: Vec<(u64, WebTile)> = Vec::new();
    for z in args.minzoom..=maxzoom {
        let l = tile_limits(tms, fp.grid_bounds(tms), z);
        let start = tiles.len();
        for y in l.min_row..=l.max_row {
            for x in l.min_col..=l.max_col {
                let t = WebTile::new(tms, z, x, y).expect("within the matrix");
                if fp.meets(t) {
                    let coord =
                        pmtiles::TileCoord::new(z, x, y).context("a tile beyond PMTiles' zooms")?;
                    tiles.push((pmtiles::TileId::from(coord).value(), t));
                }
            }
        }
        tiles[start..].sort_unstable_by_key(|(id, _)| *id);
    }
    let jobs = args
        .jobs
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(2, std::num::NonZero::get))
        .max(1);
    let started = Instant::now();
    let out = &args.pmtiles;
    let exported = upload::with_output_of_kind(out, "pmtiles", !args.quiet, |local| {
        let made = write(local, &ds, &fp, &shows, &tiles, format, args, maxzoom, jobs)?;
        Ok(made)
    })?;
    let exported = Exported {
        seconds: started.elapsed().as_secs_f64(),
        ..exported
    };
    let mb = exported.archive_bytes as f64 / 1e6;
    eprintln!(
        "exported {} tiles ({} distinct) of {} at zooms {}-{maxzoom} to {}: {mb:.1} MB (tiles {:.1} MB before deduplication{}) in {:.1} s, {:.0} tiles/s, {:.1} MB/s",
        exported.tiles,
        exported.unique,
        ds.name,
        args.minzoom,
        out.display(),
        exported.tile_bytes as f64 / 1e6,
        if matches!(format, TileFormat::Mvt) {
            " and gzip"
        } else {
            ""
        },
        exported.seconds,
        exported.tiles as f64 / exported.seconds,
        mb / exported.seconds
    );
    Ok(exported)
}

/// Makes every tile and writes the archive at `local`, renamed into place from a
/// temporary file beside it once finalized.
#[allow(clippy::too_many_arguments)]
fn write(
    local: &Path,
    ds: &Arc<crate::serve::dataset::Dataset>,
    fp: &Arc<Footprint>,
    shows: &Shows,
    tiles: &[(u64, WebTile)],
    format: TileFormat,
    args: &ExportArgs,
    maxzoom: u8,
    jobs: usize,
) -> anyhow::Result<Exported> {
    let dir = local
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let tmp = tempfile::Builder::new()
        .prefix(".tessera-export-")
        .tempfile_in(dir)
        .with_context(|| format!("cannot write beside {}", local.display()))?;
    let file = std::io::BufWriter::with_capacity(1 << 20, tmp.as_file().try_clone()?);
    let (tile_type, format_name) = match format {
        TileFormat::Image(ImageFormat::Png) => (pmtiles::TileType::Png, "png"),
        TileFormat::Image(ImageFormat::Webp) => (pmtiles::TileType::Webp, "webp"),
        TileFormat::Mvt => (pmtiles::TileType::Mvt, "pbf"),
    };
    let px = match shows {
        Shows::Contours(_) => contours::GRID,
        _ => args.size,
    };
    let [w, s, e, n] = fp.lon_lat;
    let [lon, lat] = fp.centre();
    let m = ds.pyramid.metadata();
    let (what, encoding_field) = match shows {
        Shows::Heights(enc) => (
            format!("heights, {} encoding", enc.name()),
            Some(enc.name()),
        ),
        Shows::Rendered(style) => (style.canonical.clone(), None),
        Shows::Contours(style) => (style.canonical.clone(), None),
    };
    let mut meta = serde_json::json!({
        "name": ds.name,
        "description": format!("{} of {}, exported by tessera-server from pyramid {}", what, ds.name, m.content_hash),
        "type": if matches!(shows, Shows::Contours(_)) { "overlay" } else { "baselayer" },
        "format": format_name,
        "tileSize": px,
        "tessera": {
            "dataset": ds.name,
            "content_hash": m.content_hash,
            "precision": match args.precision { Precision::Exact => "exact", Precision::Auto => "auto" },
        },
    });
    if let Shows::Contours(style) = shows {
        // What a vector archive's readers look for: its layers and their fields.
        let doc = contours::tilejson_doc(ds, fp, TileMatrixSet::WebMercatorQuad, "", style, None);
        meta["vector_layers"] = doc["vector_layers"].clone();
        meta["tessera"]["contour_intervals"] = doc["contour_intervals"].clone();
    }
    if let Some(enc) = encoding_field {
        meta["encoding"] = enc.into();
        if args.precision == Precision::Auto
            && let Shows::Heights(e) = shows
        {
            let steps: serde_json::Map<String, serde_json::Value> = (args.minzoom..=maxzoom)
                .map(|z| (z.to_string(), precision::step(z, args.size, *e).into()))
                .collect();
            meta["tessera"]["rounding_step_m"] = steps.into();
        }
    }
    let mut writer = pmtiles::PmTilesWriter::new(tile_type)
        .min_zoom(args.minzoom)
        .max_zoom(maxzoom)
        .bounds(
            w.max(-180.0),
            s.max(-85.051_13),
            e.min(180.0),
            n.min(85.051_13),
        )
        .center(lon, lat)
        .center_zoom(
            fp.overview_zoom(TileMatrixSet::WebMercatorQuad)
                .min(maxzoom),
        )
        .metadata(meta.to_string())
        .create(file)
        .map_err(|e| anyhow!("{}: {e}", local.display()))?;

    let web = Arc::new(WebTiles::new(
        WebConfig {
            // Made tiles go straight into the archive: no made-tile cache.
            tile_cache_bytes: 1 << 20,
            ..WebConfig::default()
        },
        &prometheus::Registry::new(),
    ));
    let compute = Arc::new(Compute::new(
        ComputeLimits {
            max_compute: jobs,
            queue: tiles.len().max(1),
            queue_wait: std::time::Duration::from_secs(3600),
            ..ComputeLimits::for_this_machine()
        },
        &prometheus::Registry::new(),
    ));
    let bar = if args.quiet {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(tiles.len() as u64).with_style(
            indicatif::ProgressStyle::with_template(
                "{msg:>10} [{bar:40}] {pos}/{len} tiles {per_sec} eta {eta}",
            )
            .expect("static template")
            .progress_chars("=> "),
        )
    };
    bar.set_message("export");
    let dataset = dataset_key(ds.content_hash());
    let rounding = |z: u8| match (shows, args.precision) {
        (Shows::Heights(e), Precision::Auto) => Some(precision::step(z, args.size, *e)),
        _ => None,
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()?;
    let (mut count, mut bytes) = (0u64, 0u64);
    let mut seen = HashSet::new();
    rt.block_on(async {
        let mut made = futures_util::stream::iter(tiles.iter().copied())
            .map(|(_, tile)| {
                let (web, ds, fp, compute) = (web.clone(), ds.clone(), fp.clone(), compute.clone());
                let hash = |c: &str| xxhash_rust::xxh3::xxh3_128(c.as_bytes());
                let (look, maker, kind) = match shows {
                    Shows::Heights(e) => (
                        Look::Heights(*e, NoData::Opaque),
                        Maker::Heights(rounding(tile.z)),
                        ComputeKind::GridTile,
                    ),
                    Shows::Rendered(s) => (
                        Look::Rendered(hash(&s.canonical)),
                        Maker::Rendered(s.layer.clone()),
                        ComputeKind::Rendered,
                    ),
                    Shows::Contours(s) => (
                        Look::Contours(hash(&s.canonical)),
                        Maker::Contours(s.levels(&fp, tile.tms, tile.z)),
                        ComputeKind::Contours,
                    ),
                };
                let key = MadeKey {
                    dataset,
                    tile,
                    px,
                    look,
                    format,
                };
                async move {
                    let made = compute
                        .run_blocking(kind, tile.to_string(), move |ticket| {
                            let b = match maker {
                                Maker::Heights(round) => {
                                    web_grid::make(&web, &ds, &fp, key, round, ticket)
                                }
                                Maker::Rendered(l) => {
                                    rendered::make(&web, &ds, &fp, key, &l, ticket)
                                }
                                Maker::Contours(levels) => {
                                    contours::make(&web, &ds, &fp, key, levels?, ticket)
                                }
                            }
                            .map_err(|f| {
                                crate::http::error::ApiError::internal(format!(
                                    "{tile}: {}",
                                    CachedTiles::describe(&f)
                                ))
                            })?;
                            Ok(ticket.made(b, 1))
                        })
                        .await;
                    (tile, made)
                }
            })
            .buffered(jobs * 2);
        while let Some((tile, made)) = made.next().await {
            let made = made.map_err(|e| anyhow!("{}: {}", tile, e.message))?;
            let b = made.bytes.clone();
            drop(made);
            bar.inc(1);
            if b.is_empty() {
                continue;
            }
            let coord = pmtiles::TileCoord::new(tile.z, tile.x, tile.y)?;
            writer
                .add_tile(coord, &b)
                .map_err(|e| anyhow!("{}: {e}", local.display()))?;
            count += 1;
            bytes += b.len() as u64;
            seen.insert(xxhash_rust::xxh3::xxh3_128(&b));
        }
        anyhow::Ok(())
    })?;
    bar.finish_and_clear();
    writer
        .finalize()
        .map_err(|e| anyhow!("{}: {e}", local.display()))?;
    tmp.as_file().sync_all()?;
    let archive_bytes = tmp.as_file().metadata()?.len();
    // tempfile makes its files private; an archive is for publishing.
    std::fs::set_permissions(
        tmp.path(),
        std::os::unix::fs::PermissionsExt::from_mode(0o644),
    )?;
    tmp.persist(local)
        .map_err(|e| anyhow!("{}: {}", local.display(), e.error))?;
    Ok(Exported {
        tiles: count,
        unique: seen.len() as u64,
        tile_bytes: bytes,
        archive_bytes,
        seconds: 0.0,
    })
}
