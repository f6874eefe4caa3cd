//! `serve` settings: command-line flags, then environment variables, then a TOML
//! file (`--config`), then defaults — the first that says something wins.

use super::compute::ComputeLimits;
use super::viewer::ViewerConfig;
use super::web_cache::{EmptyTiles, WebConfig};
use crate::http::conventions::CorsOrigins;
use crate::http::tls::TlsFiles;
use crate::serve::routes::elevation::ElevationLimits;
use crate::web::render::ramp::{self, RampSpec};
use anyhow::Context;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

/// `tessera-server serve` flags (each also readable from a `TESSERA_*` variable).
#[derive(Debug, Clone, clap::Args)]
#[allow(clippy::struct_excessive_bools)] // a command line's switches are bools
pub struct ServeArgs {
    /// Pyramid files (.tess), directories holding them, or object URLs
    /// (s3://BUCKET/KEY.tess, gs://, az://, file://, or http(s):// to any server that
    /// answers Range; credentials and endpoint from the AWS_*, GOOGLE_* or AZURE_*
    /// environment variables, e.g. AWS_ENDPOINT_URL and AWS_ALLOW_HTTP=true); datasets
    /// are named by file stem.
    pub paths: Vec<PathBuf>,
    /// Address to listen on [default: 127.0.0.1:8080].
    #[arg(long, env = "TESSERA_LISTEN")]
    pub listen: Option<SocketAddr>,
    /// TOML file with any of these settings (keys as the flags, with underscores).
    #[arg(long, env = "TESSERA_CONFIG")]
    pub config: Option<PathBuf>,
    /// Most Morton ranges in one request [default: 256].
    #[arg(long, env = "TESSERA_MAX_RANGES")]
    pub max_ranges: Option<usize>,
    /// Most tiles (Morton codes) in one request [default: 4096].
    #[arg(long, env = "TESSERA_MAX_TILES")]
    pub max_tiles: Option<u64>,
    /// Longest query string accepted, in bytes [default: 8192].
    #[arg(long, env = "TESSERA_MAX_QUERY_BYTES")]
    pub max_query_bytes: Option<usize>,
    /// Seconds before an unfinished request is answered 408 [default: 30].
    #[arg(long, env = "TESSERA_TIMEOUT_SECS")]
    pub timeout_secs: Option<u64>,
    /// Requests handled at once, counted apart for the cheap routes (stored tiles,
    /// ranges, metadata, health) and the computed ones (Cesium terrain, grid and PNG
    /// tiles, bootstrap), so that neither starves the other; more wait their turn
    /// [default: 1024].
    #[arg(long, env = "TESSERA_CONCURRENCY")]
    pub concurrency: Option<usize>,
    /// Computed responses (Cesium meshes, grid and PNG tiles, bootstrap bodies) made
    /// at once; identical requests share one computation [default: the number of CPUs,
    /// at least 2].
    #[arg(long, env = "TESSERA_MAX_COMPUTE", value_name = "N")]
    pub max_compute: Option<usize>,
    /// MiB of working memory for computed responses, and for computed bodies clients
    /// have not yet read [default: a sixteenth of the machine's (or cgroup's) memory,
    /// 256-1024].
    #[arg(long, env = "TESSERA_MAX_COMPUTE_MIB", value_name = "MIB")]
    pub max_compute_mib: Option<u64>,
    /// Computations that may wait for a slot or memory; beyond them, and after
    /// --compute-queue-secs, requests get 503 with Retry-After [default: 256 per slot,
    /// at least 512].
    #[arg(long, env = "TESSERA_COMPUTE_QUEUE", value_name = "N")]
    pub compute_queue: Option<usize>,
    /// Seconds a computation may wait for a slot or memory before a 503 [default: 10].
    #[arg(long, env = "TESSERA_COMPUTE_QUEUE_SECS", value_name = "SECS")]
    pub compute_queue_secs: Option<u64>,
    /// Cache-Control max-age for responses whose URL does not pin the content [default: 3600].
    #[arg(long, env = "TESSERA_CACHE_MAX_AGE")]
    pub cache_max_age: Option<u64>,
    /// Seconds a connection may take to send a complete request head, counted from
    /// when it opens or its previous response ends; then it is closed [default: 10].
    #[arg(long, env = "TESSERA_HEADER_TIMEOUT_SECS")]
    pub header_timeout_secs: Option<u64>,
    /// Seconds a connection may go without a byte moving either way while no request
    /// is being handled (e.g. a client that stops reading its response); then it is
    /// closed [default: 60].
    #[arg(long, env = "TESSERA_IDLE_TIMEOUT_SECS")]
    pub idle_timeout_secs: Option<u64>,
    /// Most connections open at once; at the cap the least recently active idle one is
    /// closed for a newcomer, or the newcomer gets 503. Never more than the open-file
    /// limit allows [default: the open-file limit less a reserve].
    #[arg(long, env = "TESSERA_MAX_CONNECTIONS")]
    pub max_connections: Option<usize>,
    /// Scheme and authority for absolute URLs in TileJSON and WMTS, e.g.
    /// https://tiles.example.org; documents built with it are shareable by caches
    /// [default: none: the request's Host, and those documents are private].
    #[arg(long, env = "TESSERA_PUBLIC_URL")]
    // These doc comments are the `--help` text, where a URL is plain text.
    #[allow(rustdoc::bare_urls)]
    pub public_url: Option<String>,
    /// Build absolute URLs from X-Forwarded-Host and X-Forwarded-Proto (only behind a
    /// proxy that sets them) when --public-url is not given.
    #[arg(long, env = "TESSERA_TRUST_FORWARDED")]
    pub trust_forwarded: bool,
    /// Origins allowed to read responses from browsers (CORS): `*` for any, `none` to
    /// send no CORS headers, or origins like https://map.example.org (repeat the flag or
    /// separate with commas) [default: *].
    #[arg(
        long,
        env = "TESSERA_CORS_ORIGIN",
        value_name = "ORIGIN",
        value_delimiter = ','
    )]
    #[allow(rustdoc::bare_urls)] // the --help text, where a URL is plain text
    pub cors_origin: Vec<String>,
    /// PEM file of the TLS certificate chain: serve HTTPS (HTTP/2 and HTTP/1.1 by ALPN);
    /// needs --tls-key.
    #[arg(long, env = "TESSERA_TLS_CERT", value_name = "PEM")]
    pub tls_cert: Option<PathBuf>,
    /// PEM file of the TLS private key (PKCS#8, PKCS#1 or SEC1); needs --tls-cert.
    #[arg(long, env = "TESSERA_TLS_KEY", value_name = "PEM")]
    pub tls_key: Option<PathBuf>,
    /// What standard-grid tiles without data get: 404 with a JSON reason, or 204 No
    /// Content [default: 404].
    #[arg(long, env = "TESSERA_EMPTY_TILES", value_name = "STATUS")]
    pub empty_tiles: Option<EmptyTiles>,
    /// Attribution shown by maps (TileJSON `attribution`), e.g. "© swisstopo"
    /// [default: none].
    #[arg(long, env = "TESSERA_ATTRIBUTION", value_name = "TEXT")]
    pub attribution: Option<String>,
    /// A colour ramp in gdaldem's color-relief format, named for `ramp=NAME` on the
    /// color-relief and slope layers (repeatable; API.md "Rendered terrain tiles").
    /// Built in: hypsometric, relative, grey, slope, slope-percent.
    #[arg(long, value_name = "NAME=FILE")]
    pub ramp: Vec<String>,
    /// Points in one elevation request, a profile's samples included (400 beyond)
    /// [default: 100000].
    #[arg(long, env = "TESSERA_MAX_POINTS", value_name = "N")]
    pub max_points: Option<usize>,
    /// MiB of an elevation POST's body (413 beyond) [default: 16].
    #[arg(long, env = "TESSERA_MAX_BODY_MIB", value_name = "MIB")]
    pub max_body_mib: Option<u64>,
    /// MiB of decoded pyramid tiles kept for standard-grid tiles [default: 256].
    #[arg(long, env = "TESSERA_SOURCE_CACHE_MIB", value_name = "MIB")]
    pub source_cache_mib: Option<u64>,
    /// MiB of made standard-grid tiles kept [default: 64].
    #[arg(long, env = "TESSERA_TILE_CACHE_MIB", value_name = "MIB")]
    pub tile_cache_mib: Option<u64>,
    /// MiB of object-store blocks kept in memory, shared by every dataset served from
    /// s3://, gs://, az:// or http(s):// (hits and misses in /metrics) [default: 256].
    #[arg(long, env = "TESSERA_BLOCK_CACHE_MIB", value_name = "MIB")]
    pub block_cache_mib: Option<u64>,
    /// The EGM96 geoid grid (GTX) that puts EGM96 heights on the ellipsoid for Cesium
    /// terrain [default: TESSERA_GEOID, then /usr/share/proj/egm96_15.gtx from
    /// Debian's proj-data; without one, such heights are served as-is with a warning].
    #[arg(long, value_name = "GTX")]
    pub geoid: Option<PathBuf>,
    /// Cesium terrain's water mask: water where this raster (a GeoTIFF in EPSG:4326,
    /// nonzero = water) says so [default: none].
    #[arg(long, env = "TESSERA_WATER", value_name = "FILE")]
    pub water: Option<PathBuf>,
    /// Cesium terrain's water mask: water where heights are at or below METRES (the
    /// dataset's own heights) and connected to the tile's edge or to no-data
    /// [default: none].
    #[arg(
        long,
        env = "TESSERA_SEA_LEVEL",
        value_name = "METRES",
        allow_negative_numbers = true
    )]
    pub sea_level: Option<f64>,
    /// Cesium terrain's water mask: water where the dataset has no data (no-data
    /// samples, beyond its edge), for a DEM whose sea is no-data.
    #[arg(long, env = "TESSERA_NO_DATA_WATER")]
    pub no_data_water: bool,
    /// Turn the built-in viewer off: `/` and `/viewer/...` then answer 404 like any
    /// unknown path (the API is unchanged).
    #[arg(long, env = "TESSERA_NO_VIEWER")]
    pub no_viewer: bool,
    /// Directory holding the viewer's MapLibre GL JS and CesiumJS files, as
    /// server/viewer-assets.sh prepares it [default: beside the executable,
    /// ../viewer-assets, then ../share/tessera/viewer-assets].
    #[arg(long, env = "TESSERA_VIEWER_ASSETS", value_name = "DIR")]
    pub viewer_assets: Option<PathBuf>,
    /// Log only errors (no request lines or warnings); RUST_LOG still overrides.
    #[arg(short, long)]
    pub quiet: bool,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileConfig {
    listen: Option<SocketAddr>,
    datasets: Option<Vec<PathBuf>>,
    max_ranges: Option<usize>,
    max_tiles: Option<u64>,
    max_query_bytes: Option<usize>,
    timeout_secs: Option<u64>,
    concurrency: Option<usize>,
    max_compute: Option<usize>,
    max_compute_mib: Option<u64>,
    compute_queue: Option<usize>,
    compute_queue_secs: Option<u64>,
    cache_max_age: Option<u64>,
    header_timeout_secs: Option<u64>,
    idle_timeout_secs: Option<u64>,
    max_connections: Option<usize>,
    public_url: Option<String>,
    trust_forwarded: Option<bool>,
    cors_origin: Option<OneOrMany>,
    tls_cert: Option<PathBuf>,
    tls_key: Option<PathBuf>,
    empty_tiles: Option<EmptyTiles>,
    attribution: Option<String>,
    /// `[ramps]` NAME = "FILE".
    ramps: Option<BTreeMap<String, PathBuf>>,
    max_points: Option<usize>,
    max_body_mib: Option<u64>,
    source_cache_mib: Option<u64>,
    tile_cache_mib: Option<u64>,
    block_cache_mib: Option<u64>,
    geoid: Option<PathBuf>,
    water: Option<PathBuf>,
    sea_level: Option<f64>,
    no_data_water: Option<bool>,
    no_viewer: Option<bool>,
    viewer_assets: Option<PathBuf>,
}

/// `cors_origin = "*"` or `cors_origin = ["https://a.example", "https://b.example"]`.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum OneOrMany {
    One(String),
    Many(Vec<String>),
}

/// Resolved settings.
#[derive(Debug, Clone)]
pub struct Settings {
    pub listen: SocketAddr,
    pub datasets: Vec<PathBuf>,
    pub max_ranges: usize,
    pub max_tiles: u64,
    pub max_query_bytes: usize,
    pub timeout: Duration,
    pub concurrency: usize,
    /// Bounds on computed responses (serve/compute/).
    pub compute: ComputeLimits,
    pub cache_max_age: u64,
    pub header_timeout: Duration,
    pub idle_timeout: Duration,
    /// `None`: derive from the open-file limit.
    pub max_connections: Option<usize>,
    /// Scheme and authority without a trailing `/`.
    pub public_url: Option<String>,
    pub trust_forwarded: bool,
    pub cors: CorsOrigins,
    /// `None`: plain HTTP (HTTP/1.1 and h2c).
    pub tls: Option<TlsFiles>,
    /// Standard-grid tiles: empty-tile status, attribution, cache sizes.
    pub web: WebConfig,
    /// Capacity of the object-store block cache, in bytes (0: no cache).
    pub block_cache_bytes: u64,
    /// The built-in viewer (`/`, `/viewer/…`): on or off, and where its assets are.
    pub viewer: ViewerConfig,
    /// Elevation requests: points and body size.
    pub elevation: ElevationLimits,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            listen: SocketAddr::from(([127, 0, 0, 1], 8080)),
            datasets: Vec::new(),
            max_ranges: 256,
            max_tiles: 4096,
            max_query_bytes: 8192,
            timeout: Duration::from_secs(30),
            concurrency: 1024,
            compute: ComputeLimits::for_this_machine(),
            cache_max_age: 3600,
            header_timeout: Duration::from_secs(10),
            idle_timeout: Duration::from_secs(60),
            max_connections: None,
            public_url: None,
            trust_forwarded: false,
            cors: CorsOrigins::Any,
            tls: None,
            web: WebConfig::default(),
            block_cache_bytes: 256 << 20,
            viewer: ViewerConfig::default(),
            elevation: ElevationLimits::default(),
        }
    }
}

/// `value` unless it is zero, which no limit or timeout may be: the error names the
/// flag, its variable and its TOML key, since any of them may have set it.
fn positive<T: PartialEq + Default>(value: T, flag: &str) -> anyhow::Result<T> {
    if value == T::default() {
        let key = flag.replace('-', "_");
        let env = format!("TESSERA_{}", key.to_ascii_uppercase());
        anyhow::bail!("--{flag} ({env}, `{key}` in --config) must be at least 1, not 0");
    }
    Ok(value)
}

/// A `--public-url`: `http://` or `https://`, a valid host, no path beyond `/`, no
/// query or fragment (the API's paths are appended to it).
fn public_url(raw: &str) -> anyhow::Result<String> {
    let bad = |why: &str| anyhow::anyhow!("--public-url {raw:?}: {why}");
    let uri: axum::http::Uri = raw
        .parse()
        .map_err(|_| bad("not a URL like https://tiles.example.org"))?;
    match uri.scheme_str() {
        Some("http" | "https") => {}
        _ => return Err(bad("the scheme must be http or https")),
    }
    let authority = uri.authority().ok_or_else(|| bad("no host"))?;
    if authority.as_str().contains('@') {
        return Err(bad("user information is not allowed"));
    }
    if uri.query().is_some() || raw.contains('#') {
        return Err(bad("a query or fragment is not allowed"));
    }
    let path = uri.path().trim_end_matches('/');
    Ok(format!(
        "{}://{}{path}",
        uri.scheme_str().unwrap_or("http"),
        authority
    ))
}

/// `--cors-origin` values: `*`, `none`, or origins `scheme://host[:port]`.
fn cors_origins(raw: &[String]) -> anyhow::Result<CorsOrigins> {
    let values: Vec<&str> = raw
        .iter()
        .map(|v| v.trim())
        .filter(|v| !v.is_empty())
        .collect();
    match values.as_slice() {
        [] | ["*"] => return Ok(CorsOrigins::Any),
        [v] if v.eq_ignore_ascii_case("none") => return Ok(CorsOrigins::Disabled),
        _ => {}
    }
    let mut list = Vec::with_capacity(values.len());
    for v in values {
        let bad = |why: &str| anyhow::anyhow!("--cors-origin {v:?}: {why}");
        if v == "*" || v.eq_ignore_ascii_case("none") {
            return Err(bad("`*` and `none` must be given alone"));
        }
        let uri: axum::http::Uri = v
            .parse()
            .map_err(|_| bad("not an origin like https://map.example.org"))?;
        let (Some(scheme), Some(authority)) = (uri.scheme_str(), uri.authority()) else {
            return Err(bad("not an origin like https://map.example.org"));
        };
        if authority.as_str().contains('@')
            || uri.query().is_some()
            || !matches!(uri.path(), "" | "/")
            || v.ends_with('/')
        {
            return Err(bad(
                "an origin is scheme://host[:port] only, with no path, query or trailing /",
            ));
        }
        let origin = format!("{scheme}://{authority}").to_ascii_lowercase();
        axum::http::HeaderValue::from_str(&origin).map_err(|_| bad("not a valid header value"))?;
        if !list.contains(&origin) {
            list.push(origin);
        }
    }
    Ok(CorsOrigins::List(list))
}

impl Settings {
    pub fn resolve(args: &ServeArgs) -> anyhow::Result<Self> {
        let file: FileConfig = match &args.config {
            Some(p) => {
                let text = std::fs::read_to_string(p)
                    .with_context(|| format!("{}: cannot read config", p.display()))?;
                toml::from_str(&text).with_context(|| format!("{}: bad config", p.display()))?
            }
            None => FileConfig::default(),
        };
        let d = Self::default();
        let datasets = if args.paths.is_empty() {
            file.datasets.unwrap_or_default()
        } else {
            args.paths.clone()
        };
        anyhow::ensure!(
            !datasets.is_empty(),
            "no datasets: name .tess files or directories (or `datasets = [...]` in --config)"
        );
        let secs = |v: Option<u64>, flag: &str, default: Duration| {
            v.map_or(Ok(default), |n| positive(n, flag).map(Duration::from_secs))
        };
        let s = Self {
            listen: args.listen.or(file.listen).unwrap_or(d.listen),
            datasets,
            max_ranges: positive(
                args.max_ranges.or(file.max_ranges).unwrap_or(d.max_ranges),
                "max-ranges",
            )?,
            max_tiles: positive(
                args.max_tiles.or(file.max_tiles).unwrap_or(d.max_tiles),
                "max-tiles",
            )?,
            max_query_bytes: positive(
                args.max_query_bytes
                    .or(file.max_query_bytes)
                    .unwrap_or(d.max_query_bytes),
                "max-query-bytes",
            )?,
            timeout: secs(
                args.timeout_secs.or(file.timeout_secs),
                "timeout-secs",
                d.timeout,
            )?,
            concurrency: positive(
                args.concurrency
                    .or(file.concurrency)
                    .unwrap_or(d.concurrency),
                "concurrency",
            )?,
            compute: {
                let dc = d.compute.clone();
                let max_compute = positive(
                    args.max_compute
                        .or(file.max_compute)
                        .unwrap_or(dc.max_compute),
                    "max-compute",
                )?;
                ComputeLimits {
                    max_compute,
                    memory_bytes: args
                        .max_compute_mib
                        .or(file.max_compute_mib)
                        .map_or(Ok(dc.memory_bytes), |n| {
                            positive(n, "max-compute-mib").map(|n| n.saturating_mul(1 << 20))
                        })?,
                    // A queue of 0 is allowed: busy means 503 at once.
                    queue: args
                        .compute_queue
                        .or(file.compute_queue)
                        .unwrap_or(dc.queue),
                    queue_wait: secs(
                        args.compute_queue_secs.or(file.compute_queue_secs),
                        "compute-queue-secs",
                        dc.queue_wait,
                    )?,
                }
            },
            cache_max_age: args
                .cache_max_age
                .or(file.cache_max_age)
                .unwrap_or(d.cache_max_age),
            header_timeout: secs(
                args.header_timeout_secs.or(file.header_timeout_secs),
                "header-timeout-secs",
                d.header_timeout,
            )?,
            idle_timeout: secs(
                args.idle_timeout_secs.or(file.idle_timeout_secs),
                "idle-timeout-secs",
                d.idle_timeout,
            )?,
            max_connections: args
                .max_connections
                .or(file.max_connections)
                .map(|n| positive(n, "max-connections"))
                .transpose()?,
            public_url: args
                .public_url
                .as_deref()
                .or(file.public_url.as_deref())
                .map(public_url)
                .transpose()?,
            trust_forwarded: args.trust_forwarded || file.trust_forwarded.unwrap_or(false),
            cors: if args.cors_origin.is_empty() {
                match file.cors_origin {
                    None => d.cors,
                    Some(OneOrMany::One(v)) => cors_origins(&[v])?,
                    Some(OneOrMany::Many(v)) => cors_origins(&v)?,
                }
            } else {
                cors_origins(&args.cors_origin)?
            },
            tls: match (
                args.tls_cert.clone().or(file.tls_cert),
                args.tls_key.clone().or(file.tls_key),
            ) {
                (Some(cert), Some(key)) => Some(TlsFiles { cert, key }),
                (None, None) => None,
                (Some(_), None) => anyhow::bail!(
                    "--tls-cert needs --tls-key (TESSERA_TLS_KEY, `tls_key` in --config): the certificate's private key"
                ),
                (None, Some(_)) => anyhow::bail!(
                    "--tls-key needs --tls-cert (TESSERA_TLS_CERT, `tls_cert` in --config): the certificate chain"
                ),
            },
            web: {
                let dw = WebConfig::default();
                let mib = |v: Option<u64>, flag: &str, default: u64| {
                    v.map_or(Ok(default), |n| {
                        positive(n, flag).map(|n| n.saturating_mul(1 << 20))
                    })
                };
                WebConfig {
                    empty_tiles: args
                        .empty_tiles
                        .or(file.empty_tiles)
                        .unwrap_or(dw.empty_tiles),
                    attribution: args.attribution.clone().or(file.attribution),
                    source_cache_bytes: mib(
                        args.source_cache_mib.or(file.source_cache_mib),
                        "source-cache-mib",
                        dw.source_cache_bytes,
                    )?,
                    tile_cache_bytes: mib(
                        args.tile_cache_mib.or(file.tile_cache_mib),
                        "tile-cache-mib",
                        dw.tile_cache_bytes,
                    )?,
                    geoid: geoid(args.geoid.clone().or(file.geoid).as_deref())?,
                    water: water_rule(
                        args.water.clone().or(file.water).as_deref(),
                        args.sea_level.or(file.sea_level),
                        args.no_data_water || file.no_data_water.unwrap_or(false),
                    )?,
                    ramps: Arc::new(ramps(&args.ramp, file.ramps.unwrap_or_default())?),
                }
            },
            // 0 is allowed here: it turns the cache off (every read goes to the store).
            block_cache_bytes: args
                .block_cache_mib
                .or(file.block_cache_mib)
                .map_or(d.block_cache_bytes, |m| m.saturating_mul(1 << 20)),
            viewer: ViewerConfig {
                enabled: !(args.no_viewer || file.no_viewer.unwrap_or(false)),
                assets: args.viewer_assets.clone().or(file.viewer_assets),
            },
            elevation: ElevationLimits {
                max_points: args
                    .max_points
                    .or(file.max_points)
                    .map_or(Ok(d.elevation.max_points), |n| positive(n, "max-points"))?,
                max_body_bytes: args
                    .max_body_mib
                    .or(file.max_body_mib)
                    .map_or(Ok(d.elevation.max_body_bytes), |n| {
                        positive(n, "max-body-mib").map(|n| n.saturating_mul(1 << 20))
                    })?,
            },
        };
        Ok(s)
    }
}

/// The ramps of `--ramp NAME=FILE` (over the config file's `[ramps]`), each read and
/// checked now: a bad file stops the server before it listens, naming the file and
/// the line.
pub fn ramps(
    args: &[String],
    mut file: BTreeMap<String, PathBuf>,
) -> anyhow::Result<BTreeMap<String, RampSpec>> {
    for a in args {
        let Some((name, path)) = a.split_once('=') else {
            anyhow::bail!("--ramp {a:?}: give NAME=FILE, e.g. --ramp alpine=alpine.txt");
        };
        file.insert(name.to_string(), PathBuf::from(path));
    }
    file.into_iter()
        .map(|(name, path)| {
            let ok = !name.is_empty()
                && name.len() <= 64
                && name
                    .bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_');
            if !ok {
                anyhow::bail!(
                    "--ramp {name:?}: a ramp's name is 1-64 letters, digits, '-' or '_' (it goes in URLs)"
                );
            }
            if ramp::built_in(&name).is_some() {
                anyhow::bail!("--ramp {name}: {name} is a built-in ramp; give yours another name");
            }
            let text = std::fs::read_to_string(&path)
                .map_err(|e| anyhow::anyhow!("--ramp {name}: cannot read {}: {e}", path.display()))?;
            let spec = RampSpec::parse(&text)
                .map_err(|e| anyhow::anyhow!("--ramp {name}: {}: {e}", path.display()))?;
            Ok((name, spec))
        })
        .collect()
}

/// What Cesium terrain's water masks mark as water: the `--water` raster is read
/// here, so a bad one stops the server with one line naming it.
fn water_rule(
    raster: Option<&std::path::Path>,
    sea_level: Option<f64>,
    no_data: bool,
) -> anyhow::Result<crate::cesium::terrain::water::WaterRule> {
    use crate::cesium::terrain::water::{WaterRaster, WaterRule};
    if let Some(s) = sea_level
        && !s.is_finite()
    {
        anyhow::bail!("--sea-level {s}: want a finite number of metres");
    }
    Ok(WaterRule {
        raster: raster.map(WaterRaster::open).transpose()?.map(Arc::new),
        no_data,
        sea_level,
    })
}

/// The geoid grid: the one named (which must open), else the first default found
/// (which may be missing: Cesium terrain then says so in `layer.json`).
fn geoid(explicit: Option<&std::path::Path>) -> anyhow::Result<Option<Arc<crate::geoid::Geoid>>> {
    let named = explicit.is_some() || std::env::var_os("TESSERA_GEOID").is_some();
    match crate::geoid::find(explicit) {
        Some(path) => match crate::geoid::Geoid::open(&path) {
            Ok(g) => Ok(Some(Arc::new(g))),
            Err(e) if named => Err(e.context("--geoid")),
            Err(e) => {
                tracing::warn!(path = %path.display(), error = %format!("{e:#}"), "cannot read the geoid grid; EGM96 heights go to Cesium as-is");
                Ok(None)
            }
        },
        None if named => anyhow::bail!(
            "--geoid: {} does not exist",
            explicit.map_or_else(
                || std::env::var("TESSERA_GEOID").unwrap_or_default(),
                |p| p.display().to_string()
            )
        ),
        None => Ok(None),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(extra: &[&str]) -> anyhow::Result<Settings> {
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            serve: ServeArgs,
        }
        let mut argv = vec!["serve", "x.tess"];
        argv.extend_from_slice(extra);
        let cli = <Cli as clap::Parser>::try_parse_from(argv)?;
        Settings::resolve(&cli.serve)
    }

    #[test]
    fn zero_limits_name_their_flag() {
        for flag in [
            "max-ranges",
            "max-tiles",
            "max-query-bytes",
            "timeout-secs",
            "concurrency",
            "header-timeout-secs",
            "idle-timeout-secs",
            "max-connections",
            "max-compute",
            "max-compute-mib",
            "compute-queue-secs",
        ] {
            let e = args(&[&format!("--{flag}"), "0"]).unwrap_err().to_string();
            assert!(e.contains(&format!("--{flag}")), "{flag}: {e}");
            assert!(e.contains("at least 1"), "{flag}: {e}");
        }
        assert!(args(&["--timeout-secs", "1"]).is_ok());
    }

    #[test]
    fn compute_limits_come_from_the_flags_or_the_machine() {
        let d = args(&[]).unwrap().compute;
        assert_eq!(d, ComputeLimits::for_this_machine());
        assert!(d.max_compute >= 2 && d.queue >= 512);
        assert!((256 << 20..=1 << 30).contains(&d.memory_bytes), "{d:?}");
        let s = args(&[
            "--max-compute",
            "3",
            "--max-compute-mib",
            "100",
            "--compute-queue",
            "0",
            "--compute-queue-secs",
            "2",
        ])
        .unwrap()
        .compute;
        assert_eq!(
            s,
            ComputeLimits {
                max_compute: 3,
                memory_bytes: 100 << 20,
                queue: 0,
                queue_wait: Duration::from_secs(2),
            }
        );
    }

    #[test]
    fn public_url_is_checked_and_normalised() {
        let s = args(&["--public-url", "https://tiles.example.org/"]).unwrap();
        assert_eq!(s.public_url.as_deref(), Some("https://tiles.example.org"));
        let s = args(&["--public-url", "http://cdn.example:8080/dem"]).unwrap();
        assert_eq!(s.public_url.as_deref(), Some("http://cdn.example:8080/dem"));
        for bad in [
            "tiles.example.org",
            "ftp://tiles.example.org",
            "https://u@tiles.example.org",
            "https://tiles.example.org/?a=b",
            "https://tiles.example.org/#x",
        ] {
            let e = args(&["--public-url", bad]).unwrap_err().to_string();
            assert!(e.contains("--public-url"), "{bad}: {e}");
        }
    }

    #[test]
    fn cors_origins_parse() {
        assert_eq!(args(&[]).unwrap().cors, CorsOrigins::Any);
        assert_eq!(
            args(&["--cors-origin", "*"]).unwrap().cors,
            CorsOrigins::Any
        );
        assert_eq!(
            args(&["--cors-origin", "none"]).unwrap().cors,
            CorsOrigins::Disabled
        );
        let want = CorsOrigins::List(vec![
            "https://a.example".to_string(),
            "http://b.example:8080".to_string(),
        ]);
        assert_eq!(
            args(&["--cors-origin", "https://A.example,http://b.example:8080"])
                .unwrap()
                .cors,
            want
        );
        assert_eq!(
            args(&[
                "--cors-origin",
                "https://a.example",
                "--cors-origin",
                "http://b.example:8080"
            ])
            .unwrap()
            .cors,
            want
        );
        for bad in [
            "a.example",
            "https://a.example/",
            "https://a.example/path",
            "*,https://a.example",
            "none,https://a.example",
        ] {
            let e = args(&["--cors-origin", bad]).unwrap_err().to_string();
            assert!(e.contains("--cors-origin"), "{bad}: {e}");
        }
    }

    #[test]
    fn tls_needs_both_files() {
        let e = args(&["--tls-cert", "c.pem"]).unwrap_err().to_string();
        assert!(e.contains("--tls-key"), "{e}");
        let e = args(&["--tls-key", "k.pem"]).unwrap_err().to_string();
        assert!(e.contains("--tls-cert"), "{e}");
        let s = args(&["--tls-cert", "c.pem", "--tls-key", "k.pem"]).unwrap();
        assert_eq!(
            s.tls,
            Some(TlsFiles {
                cert: "c.pem".into(),
                key: "k.pem".into()
            })
        );
    }

    #[test]
    fn the_viewer_is_on_unless_turned_off() {
        let s = args(&[]).unwrap();
        assert!(s.viewer.enabled);
        assert_eq!(s.viewer.assets, None);
        let s = args(&["--no-viewer", "--viewer-assets", "/opt/va"]).unwrap();
        assert!(!s.viewer.enabled);
        assert_eq!(s.viewer.assets, Some(PathBuf::from("/opt/va")));
        let dir = tempfile::tempdir().unwrap();
        let cfg = dir.path().join("t.toml");
        std::fs::write(&cfg, "no_viewer = true\nviewer_assets = \"/srv/va\"\n").unwrap();
        let s = args(&["--config", cfg.to_str().unwrap()]).unwrap();
        assert!(!s.viewer.enabled);
        assert_eq!(s.viewer.assets, Some(PathBuf::from("/srv/va")));
        // The flag beats the file.
        let s = args(&["--config", cfg.to_str().unwrap(), "--viewer-assets", "x"]).unwrap();
        assert_eq!(s.viewer.assets, Some(PathBuf::from("x")));
    }

    #[test]
    fn config_file_takes_cors_and_tls() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = dir.path().join("t.toml");
        std::fs::write(
            &cfg,
            "cors_origin = [\"https://a.example\"]\ntls_cert = \"c.pem\"\ntls_key = \"k.pem\"\n",
        )
        .unwrap();
        let s = args(&["--config", cfg.to_str().unwrap()]).unwrap();
        assert_eq!(
            s.cors,
            CorsOrigins::List(vec!["https://a.example".to_string()])
        );
        assert!(s.tls.is_some());
        std::fs::write(&cfg, "cors_origin = \"none\"\n").unwrap();
        let s = args(&["--config", cfg.to_str().unwrap()]).unwrap();
        assert_eq!(s.cors, CorsOrigins::Disabled);
        // The flag beats the file.
        let s = args(&["--config", cfg.to_str().unwrap(), "--cors-origin", "*"]).unwrap();
        assert_eq!(s.cors, CorsOrigins::Any);
    }
}
