//! `tessera-server query`: the elevation API on the command line, through the same
//! engine, storage and tile cache as the server (a local `.tess` or an object URL),
//! reading points from flags, a CSV or a GeoJSON file and writing CSV, GeoJSON or
//! the API's JSON. The output file is written whole or not at all.

use crate::elevation::locations::{self, LatLon};
use crate::elevation::profile::Body;
use crate::elevation::request::{Datum, Raw};
use crate::elevation::{self, kernel::Interpolation, output};
use crate::serve::registry::Registry;
use crate::serve::routes::elevation::CachedTiles;
use crate::serve::web_cache::{WebConfig, WebTiles};
use crate::web::footprint::Footprint;
use anyhow::{Context, anyhow, bail};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// What `query` writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// `lat,lon,elevation,level,error_bound,resolution,datum,reason`, with a header.
    Csv,
    /// A FeatureCollection of points with the answers as properties.
    Geojson,
    /// The HTTP API's JSON (Google's and opentopodata's shape).
    Json,
}

/// `tessera-server query`'s arguments.
#[derive(Debug, clap::Args)]
pub struct QueryArgs {
    /// The pyramid: a .tess file, or an object URL (s3://BUCKET/KEY.tess, …, as `serve` takes).
    pub file: PathBuf,
    /// A point as LAT,LON in degrees (WGS 84); repeat for more. Also "LAT,LON|LAT,LON" or an encoded polyline.
    #[arg(long = "at", value_name = "LAT,LON")]
    pub at: Vec<String>,
    /// Points from a file: CSV with lat and lon columns (or latitude, lng, longitude), or GeoJSON (Point, MultiPoint and LineString geometries, [lon, lat]).
    #[arg(long, value_name = "FILE")]
    pub points: Option<PathBuf>,
    /// Treat the points as a path and sample N points evenly along its geodesics (both ends included).
    #[arg(long, value_name = "N", conflicts_with = "spacing")]
    pub samples: Option<usize>,
    /// Treat the points as a path and sample one point every METRES along its geodesics, then its end.
    #[arg(long, value_name = "METRES")]
    pub spacing: Option<f64>,
    /// How heights are interpolated between samples: nearest, bilinear (as GDAL's -r bilinear) or cubic (GDAL's -r cubic).
    #[arg(long, default_value = "bilinear", value_parser = parse_interpolation)]
    pub interpolation: Interpolation,
    /// Answer each point from the coarsest level whose error bound there is within METRES (default: the finest data).
    #[arg(long, value_name = "METRES")]
    pub accuracy: Option<f64>,
    /// The vertical datum of the answers: native (the dataset's), egm96 or ellipsoid.
    #[arg(long, default_value = "native", value_parser = parse_datum)]
    pub datum: Datum,
    /// The EGM96 geoid grid (GTX) for --datum conversions; default: $TESSERA_GEOID, then /usr/share/proj/egm96_15.gtx.
    #[arg(long, value_name = "GTX")]
    pub geoid: Option<PathBuf>,
    /// What to write (default: from --output's extension, else csv).
    #[arg(long, value_enum)]
    pub format: Option<Format>,
    /// The file to write (default: standard output).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// The most points one query may ask for (a profile's samples included).
    #[arg(long, default_value_t = 10_000_000)]
    pub max_points: usize,
}

fn parse_interpolation(s: &str) -> Result<Interpolation, String> {
    Interpolation::parse(s)
        .ok_or_else(|| format!("{s:?}: the methods are {}", elevation::methods()))
}

fn parse_datum(s: &str) -> Result<Datum, String> {
    Datum::parse(s).ok_or_else(|| format!("{s:?}: the datums are native, egm96 and ellipsoid"))
}

/// Points from a CSV file with a header naming its latitude and longitude columns.
fn csv_points(path: &Path, max: usize) -> anyhow::Result<Vec<LatLon>> {
    let mut r = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_path(path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    let headers = r
        .headers()
        .with_context(|| format!("{}: no header row", path.display()))?
        .clone();
    let find = |names: &[&str]| {
        headers
            .iter()
            .position(|h| names.iter().any(|n| h.eq_ignore_ascii_case(n)))
    };
    let (Some(lat), Some(lon)) = (
        find(&["lat", "latitude"]),
        find(&["lon", "lng", "longitude"]),
    ) else {
        bail!(
            "{}: the header ({}) has no lat and lon columns (lat or latitude; lon, lng or longitude)",
            path.display(),
            headers.iter().collect::<Vec<_>>().join(",")
        );
    };
    let mut out = Vec::new();
    for (i, row) in r.records().enumerate() {
        let line = i + 2;
        let row = row.with_context(|| format!("{}: line {line}", path.display()))?;
        let num = |c: usize, what: &str| -> anyhow::Result<f64> {
            let v = row.get(c).unwrap_or("");
            v.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    anyhow!(
                        "{}: line {line}: {what} {v:?} is not a number",
                        path.display()
                    )
                })
        };
        let p = LatLon::new(num(lat, "latitude")?, num(lon, "longitude")?)
            .map_err(|e| anyhow!("{}: line {line}: {e}", path.display()))?;
        if out.len() == max {
            bail!(
                "{}: more than the {max} points allowed (--max-points)",
                path.display()
            );
        }
        out.push(p);
    }
    Ok(out)
}

/// Points from a GeoJSON file: every Point, MultiPoint and LineString position.
fn geojson_points(path: &Path, max: usize) -> anyhow::Result<Vec<LatLon>> {
    let text = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let doc: serde_json::Value =
        serde_json::from_slice(&text).with_context(|| format!("{}: not JSON", path.display()))?;
    let mut out = Vec::new();
    collect(&doc, &mut out, max).map_err(|e| anyhow!("{}: {e}", path.display()))?;
    if out.is_empty() {
        bail!(
            "{}: no Point, MultiPoint or LineString in it",
            path.display()
        );
    }
    Ok(out)
}

fn collect(v: &serde_json::Value, out: &mut Vec<LatLon>, max: usize) -> Result<(), String> {
    let position = |p: &serde_json::Value| -> Result<LatLon, String> {
        let c = p
            .as_array()
            .filter(|c| c.len() >= 2)
            .ok_or_else(|| format!("position {p} is not [lon, lat]"))?;
        let (Some(lon), Some(lat)) = (c[0].as_f64(), c[1].as_f64()) else {
            return Err(format!("position {p} is not [lon, lat]"));
        };
        LatLon::new(lat, lon)
    };
    match v.get("type").and_then(|t| t.as_str()) {
        Some("FeatureCollection") => {
            for f in v
                .get("features")
                .and_then(|f| f.as_array())
                .into_iter()
                .flatten()
            {
                collect(f, out, max)?;
            }
        }
        Some("Feature") => {
            if let Some(g) = v.get("geometry") {
                collect(g, out, max)?;
            }
        }
        Some("GeometryCollection") => {
            for g in v
                .get("geometries")
                .and_then(|g| g.as_array())
                .into_iter()
                .flatten()
            {
                collect(g, out, max)?;
            }
        }
        Some("Point") => out.push(position(&v["coordinates"])?),
        Some("MultiPoint" | "LineString") => {
            for p in v["coordinates"].as_array().into_iter().flatten() {
                out.push(position(p)?);
            }
        }
        _ => {}
    }
    if out.len() > max {
        return Err(format!("more than the {max} points allowed (--max-points)"));
    }
    Ok(())
}

/// Runs `query`.
pub fn run(args: &QueryArgs) -> anyhow::Result<()> {
    let max = args.max_points;
    let mut points = Vec::new();
    for a in &args.at {
        points.extend(locations::parse(a, max).map_err(|e| anyhow!("--at {a:?}: {e}"))?);
    }
    if let Some(file) = &args.points {
        let is_json = file
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("geojson") || e.eq_ignore_ascii_case("json"));
        points.extend(if is_json {
            geojson_points(file, max)?
        } else {
            csv_points(file, max)?
        });
    }
    if points.is_empty() {
        bail!("no points: give --at LAT,LON or --points FILE");
    }
    if points.len() > max {
        bail!(
            "{} points, more than the {max} allowed (--max-points)",
            points.len()
        );
    }
    let format = args.format.unwrap_or_else(|| {
        match args
            .output
            .as_deref()
            .and_then(Path::extension)
            .and_then(|e| e.to_str())
        {
            Some("geojson") => Format::Geojson,
            Some("json") => Format::Json,
            _ => Format::Csv,
        }
    });
    let ds = &Registry::open_one(&args.file)?;
    let metadata = ds.pyramid.metadata();
    let footprint = Footprint::new(metadata)
        .map_err(|e| anyhow!("{}: no elevations: {e}", args.file.display()))?;
    let body = Body::of(&footprint);
    let raw = Raw {
        locations: Some(points),
        samples: args.samples,
        spacing: args.spacing,
        interpolation: Some(args.interpolation),
        accuracy: args.accuracy,
        datum: Some(args.datum),
        ..Raw::default()
    };
    if let Some(a) = args.accuracy
        && !(a.is_finite() && a > 0.0)
    {
        bail!("--accuracy {a}: expected a positive number of metres");
    }
    let request = raw.resolve(body, max).map_err(|e| anyhow!("{e}"))?;
    let geoid = if args.datum == Datum::Native {
        None
    } else {
        crate::geoid::find(args.geoid.as_deref())
            .map(|p| crate::geoid::Geoid::open(&p).map(Arc::new))
            .transpose()?
    };
    let (shift, datum) = elevation::shift(
        metadata.vertical_datum,
        args.datum,
        geoid.as_ref(),
        footprint.crs().is_earth(),
    )
    .map_err(|e| anyhow!("--{e}"))?;
    let web = WebTiles::new(WebConfig::default(), &prometheus::Registry::new());
    let answers =
        crate::serve::routes::elevation::answers(&web, ds, &footprint, &request, &shift, None)
            .map_err(|f| anyhow!("{}: {}", args.file.display(), CachedTiles::describe(&f)))?;
    let cx = output::Context {
        dataset: &ds.name,
        datum,
        interpolation: request.options.interpolation.name(),
        nodata_value: None,
    };
    let text = match format {
        Format::Csv => output::csv(&answers, &cx),
        Format::Geojson => output::geojson(&answers, &cx),
        Format::Json => {
            let mut s = output::json(&answers, &cx);
            s.push('\n');
            s
        }
    };
    match &args.output {
        None => {
            use std::io::Write;
            std::io::stdout().lock().write_all(text.as_bytes())?;
        }
        Some(path) => write_whole(path, text.as_bytes())?,
    }
    Ok(())
}

/// Writes `bytes` to a temporary file beside `path`, then renames it into place.
fn write_whole(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    use std::io::Write;
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let mut tmp = tempfile::NamedTempFile::new_in(dir)
        .with_context(|| format!("{}: cannot write", path.display()))?;
    tmp.write_all(bytes)
        .with_context(|| format!("{}: cannot write", path.display()))?;
    tmp.persist(path)
        .map_err(|e| anyhow!("{}: cannot write: {}", path.display(), e.error))?;
    Ok(())
}
