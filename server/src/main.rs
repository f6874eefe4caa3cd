//! `tessera-server`: build, verify and describe Tessera tile pyramids.

use anyhow::Context;
use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use tessera_server::builder::interrupt::{Interrupt, Interrupted};
use tessera_server::builder::parts::{PartRead, PartSpec, assemble as assemble_parts, build_part};
use tessera_server::builder::update::UpdateReport;
use tessera_server::builder::{BuildOptions, build_inputs};
use tessera_server::ingest::assign::Bounds;
use tessera_server::ingest::reproject::{ReprojectOptions, Resampling, parse_spacing};
use tessera_server::ingest::vertical_shift::parse_vertical_arg;
use tessera_server::ingest::{InputSpec, Overlap};
use tessera_server::{info, preview, verify};

#[derive(Debug, Parser)]
#[command(
    name = "tessera-server",
    version,
    about = "Build, check and serve Tessera tile pyramids of large elevation models",
    long_about = "Build, check and serve Tessera tile pyramids of large elevation models.\n\n\
        A pyramid is one .tess file: every level of detail of a DEM, cut into tiles stored in \
        Z-order (Morton order) with per-tile error tables, so a client can fetch exactly the \
        detail its view needs with a few byte-range requests."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

// Parsed once per process: the size of the largest variant (serve's flags) costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Subcommand)]
enum Command {
    /// Build a pyramid from a DEM or a mosaic of DEMs (out of core: memory stays under --memory).
    ///
    /// INPUT is a GeoTIFF (int16/uint16/float32; striped or tiled; none/deflate/LZW/PackBits),
    /// a 16-bit grayscale PNG, an SRTM .hgt file, a GDAL .vrt (the sources gdalbuildvrt
    /// writes, copied 1:1), or synthetic:SIZE[:SEED] for a deterministic fractal terrain of
    /// SIZE×SIZE samples.
    ///
    /// Several inputs make one mosaic: `build A.tif B.tif`, `build DIR/` (its .tif, .tiff,
    /// .hgt and .png files, sorted), `build 'tiles/*.hgt'` (a quoted glob, sorted), `build
    /// --inputs LIST.txt`, or a VRT. Inputs on one grid (one CRS, spacing and lattice)
    /// are copied as they are. Inputs on different grids (other CRSs, spacings or
    /// lattices) are resampled onto one: the CRS, spacing and lattice of the finest input
    /// (or --to, --spacing), with --resampling; where they overlap the finest wins
    /// (--overlap). Samples no input covers are no-data, and so is each input's own
    /// no-data value. Inputs are opened only while the rows being read cross them.
    ///
    /// Inputs may be in object storage or on a web server: `s3://BUCKET/KEY.tif`,
    /// `https://HOST/x.tif`, `s3://BUCKET/PREFIX/` (its DEM files), `'s3://BUCKET/dir/*.tif'`,
    /// and such URLs in --inputs lists and VRTs (GDAL's /vsis3/ and /vsicurl/ names
    /// too). Credentials and endpoints come from AWS_*, GOOGLE_* or AZURE_* variables.
    /// Tiled GeoTIFFs (COGs) are read in place, only the tiles needed and no overview;
    /// other inputs are fetched whole into TMPDIR first.
    ///
    /// Distributed build (e.g. a Kubernetes Indexed Job): `build INPUT --part K/N -o PARTS/`
    /// in N processes, one per K, then `build --assemble PARTS/ -o OUT.tess` once. The
    /// assembled file is byte for byte the one a single `build INPUT -o OUT.tess` with the
    /// same options writes. Each part reads only its share of the input (from a COG or a
    /// mosaic, the tiles and files under its subtrees), unless its share holds no-data
    /// or the samples are floating-point without --height-range: it then reads the
    /// whole input, and says why.
    Build {
        /// The DEMs to read (files, directories, quoted glob patterns, .vrt files, or the
        /// same as s3://, gs://, az://, http(s):// URLs), or synthetic:SIZE[:SEED].
        #[arg(
            value_name = "INPUT",
            required_unless_present_any = ["inputs_list", "assemble"]
        )]
        input: Vec<String>,
        /// A text file naming inputs, one per line (files, directories or patterns,
        /// relative to the list's folder, or URLs; blank lines and lines starting with #
        /// are skipped).
        #[arg(long = "inputs", value_name = "LIST")]
        inputs_list: Option<PathBuf>,
        /// Where overlapping inputs disagree (two valid samples differ): the input given
        /// first wins, the last wins, the one with the finest ground spacing wins (ties by
        /// order), or the build stops naming the sample and both files. Default: error for
        /// inputs on one grid, finest for inputs on different grids.
        #[arg(long, value_enum)]
        overlap: Option<Overlap>,
        /// Blend the seams between inputs over this many metres instead of a hard
        /// edge: within that distance of a higher-priority input's edge its heights
        /// fade linearly into those below it (needs --overlap finest or first).
        #[arg(long, value_name = "METRES")]
        feather: Option<f64>,
        /// Store every level over the whole collection. By default, with inputs of
        /// different resolutions, a place covered only by coarser data is stored down
        /// to the level that data supports and no deeper (readers refine only where
        /// finer tiles exist; the server's web and Cesium tiles upsample the stored
        /// ancestor), so storage follows each resolution's area.
        #[arg(long)]
        full_pyramid: bool,
        /// The pyramid file to write (e.g. dem.tess). Written to a temporary file beside
        /// it and renamed into place only when complete and verified. Or an object URL
        /// (s3://BUCKET/KEY.tess, gs://, az://; credentials from the AWS_*, GOOGLE_* or
        /// AZURE_* variables): built under TMPDIR, then sent with a multipart upload that
        /// is completed only when the pyramid is whole and verified. With --part: the
        /// folder the part file goes into (created if missing).
        #[arg(short, long)]
        output: PathBuf,
        /// Build only part K of N of the pyramid (K from 0): the subtrees of the Kth slice
        /// of the top-level Morton ranges, written to OUTPUT/part-KKKK-of-NNNN.tesspart
        /// (renamed into place when complete, so a part that died is simply rerun). `/N`
        /// takes K from JOB_COMPLETION_INDEX, which a Kubernetes Indexed Job sets. Every
        /// part must be built with the same input and options.
        #[arg(long, value_name = "K/N", conflicts_with = "assemble")]
        part: Option<String>,
        /// Assemble the parts in this folder (every part-*-of-N.tesspart of one build)
        /// into the pyramid OUTPUT: the top levels from the parts' roots, then the file,
        /// verified and renamed into place. A missing, duplicate, damaged or mismatched
        /// part is an error naming it. Takes no INPUT and no options that shape the
        /// pyramid: those come from the parts.
        #[arg(
            long,
            value_name = "PARTS",
            conflicts_with_all = [
                "input", "inputs_list", "overlap", "feather", "full_pyramid", "tile_size", "scale", "offset", "nodata",
                "vertical_datum", "to_vertical", "crs", "bounds", "to", "resampling",
                "spacing"
            ]
        )]
        assemble: Option<PathBuf>,
        /// Tile size in cells: a power of two from 64 to 4096 (tiles have one more sample).
        #[arg(long, default_value_t = 512)]
        tile_size: u32,
        /// Multiply input samples by this to get metres (e.g. 0.1 for decimetres).
        #[arg(long, default_value_t = 1.0)]
        scale: f64,
        /// Add this after scaling to get metres (e.g. -10000 for the moon mosaics).
        #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
        offset: f64,
        /// Input value that means "no data", overriding each file's own (e.g. GDAL_NODATA).
        #[arg(long, allow_negative_numbers = true)]
        nodata: Option<f64>,
        /// The heights' range in metres, for inputs of floating-point samples: they are
        /// stored in 65 536 steps between its ends (half a step of error), checked
        /// against every sample. Default: the input's own range, which takes reading
        /// all of it first, so each part of a distributed build (--part) then reads the
        /// whole input. Given, a part reads only its share. Integer inputs are stored
        /// exactly whatever the range.
        #[arg(long, value_name = "MIN,MAX", value_parser = parse_height_range, allow_hyphen_values = true)]
        height_range: Option<[f64; 2]>,
        /// Also write OUT.tess.state (about 1-2 % of the pyramid at --tile-size 512):
        /// the errors a record does not keep and the inputs read, which `--update` needs
        /// to update this pyramid later. Not with --part or a multi-resolution pyramid.
        #[arg(long, conflicts_with_all = ["part", "assemble"])]
        state: bool,
        /// Update OLD.tess (built with --state) to the pyramid of the inputs given now:
        /// reads only the inputs added, removed or changed since (by size and ETag or
        /// modification time), re-encodes only the tiles they touch and copies every
        /// other record byte for byte; the result is byte for byte what a whole build
        /// of the inputs with the same options writes, and gets its own .state. Other
        /// options than OLD's (--tile-size, --to, --scale, ...) are an error; when the
        /// data prevent an exact update (no-data, inputs reaching further, reordered
        /// inputs, ...), it builds the whole pyramid and says why.
        #[arg(long, value_name = "OLD.tess", conflicts_with_all = ["part", "assemble"])]
        update: Option<PathBuf>,
        /// What the heights are measured from, recorded so outputs that need another
        /// reference (Cesium: the ellipsoid) can convert: egm96, egm2008, ellipsoid or
        /// unknown, for every input, or 'PATTERN=DATUM' for the inputs whose file name
        /// matches PATTERN (repeatable; e.g. --vertical-datum 'swissalti*=ellipsoid').
        /// Default: what the input says (SRTM .hgt: egm96; a GeoTIFF's vertical GeoKeys,
        /// its DTED metadata, or the file name of a product such as USGS SRTM or
        /// Copernicus DEM), else unknown, with a warning giving the error Cesium terrain
        /// would show. Inputs in different datums are an error without --to-vertical.
        #[arg(long, value_name = "[PATTERN=]DATUM", value_parser = parse_vertical_arg)]
        vertical_datum: Vec<(Option<glob::Pattern>, tessera_shared::VerticalDatum)>,
        /// Convert every input's heights to this vertical datum as they are read, through
        /// PROJ and its geoid grids (proj-data ships EGM96's; EGM2008's must be
        /// downloaded from cdn.proj.org): the pyramid records it.
        #[arg(long, value_enum, value_name = "DATUM")]
        to_vertical: Option<ToVertical>,
        /// The input's horizontal CRS: EPSG:CODE or a PROJ string (e.g. '+proj=longlat
        /// +R=1737400 +no_defs' for the Moon). Assigned, not reprojected: it replaces the
        /// input's own CRS (with a warning naming both), and --to reprojects from it. The
        /// input needs a geotransform: its own or --bounds. A mosaic on one grid takes it
        /// as a whole (every input); inputs on different grids need their own (in the
        /// file, a .prj beside it, or a VRT's <SRS>).
        #[arg(long, value_name = "CRS")]
        crs: Option<String>,
        /// The outer edges of the raster's pixels in the CRS's units (pixel-is-area, as
        /// GDAL's -a_ullr but in W,S,E,N order), for inputs without a geotransform such as
        /// a PNG: e.g. --bounds 51,8.9921875,67,24.9921875. Replaces the input's own
        /// geotransform (with a warning). Needs a CRS: the input's or --crs. One input
        /// only (a file or a VRT), not a mosaic of several.
        #[arg(
            long,
            value_name = "W,S,E,N",
            value_parser = parse_bounds,
            allow_hyphen_values = true
        )]
        bounds: Option<Bounds>,
        /// Reproject to this CRS first (EPSG:CODE, e.g. EPSG:4326, EPSG:3857, EPSG:32632,
        /// or a PROJ string), resampling onto a north-up grid that covers the input.
        #[arg(long, value_name = "CRS")]
        to: Option<String>,
        /// How --to, and inputs on different grids, compute output samples (GDAL's
        /// bilinear, cubic and nearest).
        #[arg(long, value_enum, default_value_t = Resampling::Bilinear)]
        resampling: Resampling,
        /// Output spacing in the target CRS's units, X or X,Y, for --to (default: the
        /// input's resolution at its centre) and for inputs on different grids
        /// (default: the finest input's).
        #[arg(long, value_name = "X[,Y]", value_parser = parse_spacing)]
        spacing: Option<[f64; 2]>,
        /// Memory budget, e.g. 512MiB, 2GiB, 300MB.
        #[arg(long, default_value = "512MiB", value_parser = parse_memory)]
        memory: u64,
        /// Most samples (width × height) an input may declare: a larger one is refused
        /// before anything is read, as is one whose spool (4 bytes a sample) does not fit
        /// in the free disk space. The default, 2^40, passes a planet at 1″.
        #[arg(long, value_name = "N", default_value_t = tessera_server::builder::plausible::DEFAULT_MAX_SAMPLES)]
        max_samples: u64,
        /// Also build the imagery pyramid of this image (GeoTIFF, or PNG/JPEG with a world
        /// file and .prj; any CRS, reprojected onto the DEM's grid) as OUTPUT with the
        /// extension .tessimg: the DEM's tiles, levels and Morton layout, a JPEG per tile.
        /// The DEM needs a CRS the projection library knows (its own or --crs). If the
        /// imagery fails, neither file is left.
        #[arg(long, value_name = "IMAGE", conflicts_with_all = ["part", "assemble"])]
        imagery: Option<PathBuf>,
        /// The bands of --imagery (1-based) that become red, green and blue, e.g. 3,2,1
        /// for Landsat true colour; one band for grey. Default: 1,2,3 (or 1 of a
        /// one-band image). Bands wider than 8 bits are stretched from their 2nd to 98th
        /// percentile.
        #[arg(long, value_name = "R,G,B", requires = "imagery")]
        bands: Option<String>,
        /// No progress bars, and only errors in the log.
        #[arg(short, long)]
        quiet: bool,
    },
    /// Serve pyramids over HTTP (API.md): Morton-range tile streams, single tiles, the raw
    /// file with HTTP Range, PNG height tiles, TileJSON, /healthz and /metrics.
    ///
    /// Settings come from flags, then TESSERA_* environment variables, then --config FILE
    /// (TOML), then defaults. Stops on SIGINT/SIGTERM after in-flight requests finish;
    /// SIGHUP reopens every dataset (deploy by renaming a new file over the old one).
    /// HTTP/1.1 and HTTP/2 (h2c) on one port, or HTTPS with --tls-cert and --tls-key;
    /// CORS, gzip/br for JSON and text, ETag and Last-Modified on every endpoint.
    Serve(tessera_server::serve::config::ServeArgs),
    /// Check a pyramid's structure and every tile's checksum; exit 1 naming each bad tile.
    Verify {
        /// The .tess file to check.
        file: PathBuf,
    },
    /// Draw one level of a pyramid as a shaded-relief PNG (hypsometric tint × hillshade).
    Preview {
        /// The .tess file to draw.
        file: PathBuf,
        /// The PNG to write.
        #[arg(short, long)]
        output: PathBuf,
        /// Level to draw (default: the finest that fits in --max-size pixels).
        #[arg(long)]
        level: Option<u8>,
        /// Largest image side when choosing the level automatically.
        #[arg(long, default_value_t = 2048)]
        max_size: u32,
    },
    /// Heights of points or a profile, each with its level and error bound: the
    /// elevation API (API.md "Elevation queries") on the command line.
    ///
    /// Points come from --at LAT,LON (repeatable) and --points FILE (CSV with lat and
    /// lon columns, or GeoJSON); with --samples or --spacing they are a path, sampled
    /// along its geodesics. Writes CSV (default), GeoJSON or the API's JSON to stdout
    /// or --output (written whole or not at all). Example:
    ///
    ///   tessera-server query alps.tess --at 46.5,8.1 --at 46.6,8.2 --accuracy 5
    Query(tessera_server::query::QueryArgs),
    /// Write a dataset's Web Mercator tiles into one PMTiles v3 archive, for web maps
    /// without a server (API.md "PMTiles export").
    ///
    /// Height tiles (--encoding terrarium|mapbox) or a rendered layer (--layer
    /// hillshade|color-relief|slope, with --option KEY=VALUE as the tile URLs take
    /// them), PNG or lossless WebP, from --minzoom to --maxzoom; each tile is the
    /// server's tile of the same z/x/y, byte for byte (with --precision auto, heights
    /// rounded per zoom for smaller archives). Identical tiles are stored once; the
    /// archive is clustered. Written whole or not at all, to a file or an object URL
    /// (s3://…, a multipart upload). Example:
    ///
    ///   tessera-server export alps.tess --pmtiles alps.pmtiles --format webp --size 512
    Export(tessera_server::export::ExportArgs),
    /// Print a pyramid's metadata and per-level statistics.
    Info {
        /// The .tess file to describe.
        file: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
}

/// `--bounds W,S,E,N` ([`Bounds`]'s parser, its error as clap shows it).
fn parse_bounds(s: &str) -> Result<Bounds, String> {
    s.parse().map_err(|e: anyhow::Error| format!("{e:#}"))
}

/// `--height-range MIN,MAX`: two finite heights in metres, MIN below MAX.
fn parse_height_range(s: &str) -> Result<[f64; 2], String> {
    let bad = || format!("{s:?} is not a range of heights like -500,9000 (MIN,MAX in metres)");
    let (a, b) = s.split_once(',').ok_or_else(bad)?;
    let (lo, hi): (f64, f64) = (
        a.trim().parse().map_err(|_| bad())?,
        b.trim().parse().map_err(|_| bad())?,
    );
    if !(lo.is_finite() && hi.is_finite()) {
        return Err(bad());
    }
    if lo >= hi {
        return Err(format!("{s:?}: MIN ({lo}) must be below MAX ({hi})"));
    }
    Ok([lo, hi])
}

/// Why a `--memory` value is refused ([`parse_memory`]).
#[derive(Debug, thiserror::Error)]
enum MemoryError {
    #[error("{0:?} is not a size like 512MiB (units B, KiB, MiB, GiB, KB, MB, GB, …)")]
    NotASize(String),
    #[error("{0} is below the 64 MiB minimum memory budget")]
    BelowMinimum(String),
}

/// `--memory`: sizes like `512MiB`, `2GiB`, `300MB`, `1.5GiB`, `1000` (bytes), units
/// in any case, as the `bytesize` crate reads them; at least 64 MiB.
fn parse_memory(s: &str) -> Result<u64, MemoryError> {
    let size: bytesize::ByteSize = s
        .trim()
        .parse()
        .map_err(|_| MemoryError::NotASize(s.into()))?;
    if size.as_u64() < 64 << 20 {
        return Err(MemoryError::BelowMinimum(s.into()));
    }
    Ok(size.as_u64())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let quiet = match &cli.command {
        Command::Build { quiet, .. } => *quiet,
        Command::Serve(args) => args.quiet,
        _ => false,
    };
    // `-q` keeps only errors; an explicit RUST_LOG still wins. Colour codes only on a
    // terminal: in a file or a pipe they are noise.
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| {
                tracing_subscriber::EnvFilter::new(if quiet { "error" } else { "info" })
            }),
        )
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_writer(std::io::stderr)
        .init();
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// `--to-vertical` values (shared/ does not link clap).
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum ToVertical {
    /// Heights above the EGM96 geoid (SRTM).
    Egm96,
    /// Heights above the EGM2008 geoid (Copernicus DEM).
    Egm2008,
    /// Heights above the WGS 84 ellipsoid.
    Ellipsoid,
}

impl ToVertical {
    const fn datum(self) -> tessera_shared::VerticalDatum {
        use tessera_shared::VerticalDatum as V;
        match self {
            Self::Egm96 => V::Egm96,
            Self::Egm2008 => V::Egm2008,
            Self::Ellipsoid => V::Ellipsoid,
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Build {
            input,
            inputs_list,
            overlap,
            feather,
            full_pyramid,
            output,
            tile_size,
            scale,
            offset,
            nodata,
            height_range,
            state,
            update,
            vertical_datum,
            to_vertical,
            crs,
            bounds,
            to,
            resampling,
            spacing,
            memory,
            max_samples,
            quiet,
            part,
            assemble,
            imagery,
            bands,
        } => {
            // Flag errors before anything is read.
            let part = part
                .map(|p| PartSpec::parse(&p, std::env::var("JOB_COMPLETION_INDEX").ok().as_deref()))
                .transpose()?;
            // The image is read and checked before anything is written.
            let imagery = imagery
                .map(|p| {
                    if output.to_string_lossy().contains("://") {
                        anyhow::bail!("--imagery: the output must be a local file");
                    }
                    tessera_server::imagery::Prepared::open(&p, bands.as_deref())
                })
                .transpose()?;
            let opts = BuildOptions {
                tile_size,
                scale,
                offset,
                memory_budget: memory,
                max_samples,
                nodata,
                height_range,
                state: state || update.is_some(),
                vertical_datum: {
                    let all: Vec<_> = vertical_datum.iter().filter(|(p, _)| p.is_none()).collect();
                    if all.len() > 1 {
                        anyhow::bail!(
                            "--vertical-datum is given {} times for every input; give it once, \
                             or as 'PATTERN=DATUM' for some inputs",
                            all.len()
                        );
                    }
                    all.first().map(|(_, d)| *d)
                },
                vertical_per_input: vertical_datum
                    .iter()
                    .filter_map(|(p, d)| Some((p.clone()?, *d)))
                    .collect(),
                to_vertical: to_vertical.map(ToVertical::datum),
                feather,
                full_pyramid,
                crs,
                bounds,
                reproject: to.map(|to| ReprojectOptions {
                    to,
                    resampling,
                    spacing,
                }),
                overlap,
                resampling,
                spacing,
                progress: !quiet,
                interrupt: Interrupt::install().context("cannot watch SIGINT/SIGTERM")?,
            };
            let inputs = InputSpec {
                args: input,
                list: inputs_list,
            };
            // Death by signal N exits 128 + N, the shell's convention.
            let interrupted = |e: &anyhow::Error| {
                e.downcast_ref::<Interrupted>().map(|Interrupted(sig)| {
                    eprintln!("error: {e:#}");
                    ExitCode::from(128 + *sig as u8)
                })
            };
            if let Some(spec) = part {
                let r = match build_part(&inputs, &output, spec, &opts) {
                    Ok(r) => r,
                    Err(e) => return interrupted(&e).ok_or(e),
                };
                println!(
                    "built part {}/{} {}: level {} codes {}..{}, {} records, {:.1} MB in {:.2} s",
                    r.spec.k,
                    r.spec.n,
                    r.path.display(),
                    r.split,
                    r.tops.start,
                    r.tops.end,
                    r.records,
                    r.file_bytes as f64 / 1e6,
                    r.seconds
                );
                match &r.read {
                    PartRead::Share { samples, of } => println!(
                        "read its share of the input: {samples} of {of} samples ({:.1} %)",
                        100.0 * *samples as f64 / *of as f64
                    ),
                    PartRead::Whole(why) => println!("read the whole input: {why}"),
                    PartRead::Generated => {}
                }
                if r.fetched.total() > 0 {
                    println!(
                        "read {} bytes of inputs from object storage ({} by range, {} whole into spools)",
                        r.fetched.total(),
                        r.fetched.ranged,
                        r.fetched.spooled
                    );
                }
                for w in &r.warnings {
                    eprintln!("warning: {w}");
                }
                return Ok(ExitCode::SUCCESS);
            }
            // An object URL (s3://…) is built locally first, then uploaded whole.
            if opts.state && output.to_string_lossy().contains("://") {
                anyhow::bail!(
                    "{}: --state and --update write the pyramid's .state beside it: give a \
                     local -o (and upload both)",
                    output.display()
                );
            }
            let r = tessera_server::storage::upload::with_output(&output, !quiet, |out| {
                match (&assemble, &update) {
                    (Some(dir), _) => assemble_parts(dir, out, &opts).map(|r| (r, None)),
                    (None, Some(old)) => {
                        tessera_server::builder::update::update(&inputs, old, out, &opts)
                            .map(|(r, u)| (r, Some(u)))
                    }
                    (None, None) => build_inputs(&inputs, out, &opts).map(|r| (r, None)),
                }
            });
            let (r, updated) = match r {
                Ok(r) => r,
                Err(e) => return interrupted(&e).ok_or(e),
            };
            let m = &r.metadata;
            println!(
                "{} {}: {}×{} samples, {} levels, {} tiles, {:.1} MB ({:.3} bytes/sample) in {:.2} s ({:.1} M samples/s)",
                if assemble.is_some() {
                    "assembled"
                } else {
                    "built"
                },
                output.display(),
                m.width,
                m.height,
                m.levels,
                r.tiles,
                r.file_bytes as f64 / 1e6,
                r.file_bytes as f64 / r.samples as f64,
                r.seconds,
                r.samples as f64 / r.seconds / 1e6
            );
            if r.fetched.total() > 0 {
                println!(
                    "read {} bytes of inputs from object storage ({} by range, {} whole into spools)",
                    r.fetched.total(),
                    r.fetched.ranged,
                    r.fetched.spooled
                );
            }
            match (&updated, &update) {
                (
                    Some(UpdateReport::Updated {
                        measured,
                        rewritten,
                        copied,
                        samples,
                    }),
                    Some(old),
                ) => println!(
                    "updated {} from {}: {rewritten} tiles with new bytes, {copied} copied byte \
                     for byte ({measured} finest tiles measured again); read {samples} of {} \
                     input samples ({:.1} %)",
                    output.display(),
                    old.display(),
                    r.samples,
                    100.0 * *samples as f64 / r.samples as f64
                ),
                (Some(UpdateReport::Whole(why)), _) => {
                    println!("built the whole pyramid, not an update: {why}");
                }
                _ => {}
            }
            // After the summary, whatever --quiet says: a build that succeeded but whose
            // heights Cesium terrain will misplace.
            for w in &r.warnings {
                eprintln!("warning: {w}");
            }
            if let Some(prepared) = &imagery {
                let i = tessera_server::imagery::build_beside(prepared, &output, &opts.interrupt)?;
                println!(
                    "built {}: {} imagery tiles of {}² texels, {:.1} MB",
                    i.path.display(),
                    i.records,
                    i.metadata.texels,
                    i.file_bytes as f64 / 1e6
                );
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Serve(args) => {
            let settings = tessera_server::serve::config::Settings::resolve(&args)?;
            let rt = tokio::runtime::Builder::new_multi_thread()
                .enable_all()
                .build()
                .context("cannot start the async runtime")?;
            rt.block_on(tessera_server::serve::run(settings))?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Verify { file } => {
            let r = verify::verify(&file).with_context(|| file.display().to_string())?;
            for problem in &r.problems {
                println!("bad file: {problem}");
            }
            for (tile, problem) in &r.bad {
                println!("bad {tile}: {problem}");
            }
            if r.is_ok() {
                println!(
                    "ok {}: {} tiles, {} record bytes, every checksum matches",
                    file.display(),
                    r.tiles,
                    r.bytes
                );
                Ok(ExitCode::SUCCESS)
            } else {
                let bad_tiles = r
                    .bad
                    .iter()
                    .map(|(t, _)| *t)
                    .collect::<std::collections::BTreeSet<_>>()
                    .len();
                eprintln!(
                    "error: {}: {} of {} tiles are bad, {} problems with the file as a whole",
                    file.display(),
                    bad_tiles,
                    r.tiles,
                    r.problems.len()
                );
                Ok(ExitCode::FAILURE)
            }
        }
        Command::Preview {
            file,
            output,
            level,
            max_size,
        } => {
            let (level, w, h) = preview::preview(&file, &output, level, max_size)
                .with_context(|| file.display().to_string())?;
            println!("wrote {}: level {level}, {w}×{h} pixels", output.display());
            Ok(ExitCode::SUCCESS)
        }
        Command::Query(args) => {
            tessera_server::query::run(&args)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Export(args) => {
            tessera_server::export::run(&args)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Info { file, json } => {
            let i = info::info(&file).with_context(|| file.display().to_string())?;
            if json {
                println!("{}", serde_json::to_string_pretty(&i)?);
            } else {
                print!("{}", info::render(&i));
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::parse_memory;

    #[test]
    fn memory_takes_the_sizes_it_always_took() {
        for (s, want) in [
            ("512MiB", 512u64 << 20),
            ("2GiB", 2 << 30),
            ("300MB", 300_000_000),
            (" 1.5 gib ", 3 << 29),
            ("100000000", 100_000_000),
            ("70000kb", 70_000_000),
            ("65536KiB", 64 << 20),
        ] {
            assert_eq!(parse_memory(s).unwrap(), want, "{s}");
        }
        for bad in ["", "MiB", "-1GiB", "12 parsecs", "1e9"] {
            assert!(
                parse_memory(bad)
                    .unwrap_err()
                    .to_string()
                    .contains("is not a size like 512MiB"),
                "{bad}"
            );
        }
        assert!(
            parse_memory("63MiB")
                .unwrap_err()
                .to_string()
                .contains("below the 64 MiB minimum")
        );
    }
}
