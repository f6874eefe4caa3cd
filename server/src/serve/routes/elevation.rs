//! `GET` and `POST /v1/datasets/{name}/elevation` (API.md "Elevation queries"):
//! heights of points and profiles, each with its level and error bound, computed by
//! the elevation engine (elevation/) from the decoded-tile cache the standard-grid
//! tiles share, admitted and bounded like every computed response
//! (serve/compute/).
//!
//! - A `GET` is cacheable: its ETag hashes the dataset's content and the query's
//!   parameters (sorted), and identical GETs in flight share one computation.
//! - A `POST` body is read only after its size (its `Content-Length`, or the limit
//!   when it is chunked) is reserved on the computed responses' memory budget, so
//!   many large bodies at once wait or get a 503 instead of growing the server;
//!   its answer is not cached.

use super::web_grid::{Failure, failure_error, footprint, source};
use super::{Params, Segments, dataset, pinned};
use crate::elevation::profile::Body;
use crate::elevation::request::{self, Raw, Request};
use crate::elevation::{self, Dem, Tiles, output};
use crate::http::cache;
use crate::http::error::{ApiError, ApiResult};
use crate::serve::AppState;
use crate::serve::compute::{Kind, Made, Stop, Ticket};
use crate::serve::dataset::Dataset;
use crate::serve::web_cache::WebTiles;
use crate::web::footprint::Footprint;
use crate::web::resample::SourceTile;
use axum::body::Body as HttpBody;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::Response;
use bytes::Bytes;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use tessera_shared::TileId;

/// The limits of elevation requests (`--max-points`, `--max-body-mib`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ElevationLimits {
    /// Points in one request (a profile's samples included).
    pub max_points: usize,
    /// Bytes of a `POST` body.
    pub max_body_bytes: u64,
}

impl Default for ElevationLimits {
    fn default() -> Self {
        Self {
            max_points: 100_000,
            max_body_bytes: 16 << 20,
        }
    }
}

/// The engine's tiles: the pyramid's index for what is stored, the shared cache of
/// decoded tiles for the rest, and the computation's ticket for cancellation
/// (`None` on the command line).
#[derive(Debug)]
pub struct CachedTiles<'a> {
    pub web: &'a WebTiles,
    pub ds: &'a Dataset,
    pub ticket: Option<&'a Ticket>,
}

impl Tiles for CachedTiles<'_> {
    type Error = Failure;

    fn stored(&self, tile: TileId) -> bool {
        self.ds.pyramid.entry(tile).is_some_and(|e| e.length > 0)
    }

    fn load(&self, tile: TileId) -> Result<Option<Arc<SourceTile>>, Failure> {
        source(self.web, self.ds, tile)
    }

    fn check(&self) -> Result<(), Failure> {
        match self.ticket {
            Some(t) => t.check().map_err(Failure::Stopped),
            None => Ok(()),
        }
    }
}

impl CachedTiles<'_> {
    /// A failure in words, for the command line.
    pub fn describe(f: &Failure) -> String {
        match f {
            Failure::Corrupt(t, _) => format!("{t} fails its checksum"),
            Failure::Undecodable(t, e) => format!("{t} does not decode: {e}"),
            Failure::Unavailable(r) => r.to_string(),
            Failure::TooDense(why) => why.clone(),
            other => format!("{other:?}"),
        }
    }
}

/// Working memory per point: its position, pending state and answer, and its JSON.
const BYTES_PER_POINT: u64 = 96 + output::JSON_BYTES_PER_ANSWER as u64;

/// The memory a batch's held tiles may take.
const HELD_BYTES: u64 = 64 << 20;

/// Decoded tiles a batch holds at once (elevation/mod.rs `Window`): at most 64 MiB
/// of them, no more than a level of the pyramid has, nor more than 9 a point.
pub fn tiles_held(ds: &Dataset, points: u64) -> usize {
    let g = ds.pyramid.geometry();
    let tile_bytes = 2 * u64::from(g.tile_size() + 1).pow(2);
    // The finest level has the most tiles: those whose origin is inside the DEM's
    // cells (`TileGeometry::is_present`), counted without walking the level.
    let across = |samples: u32| {
        u64::from(samples - 1)
            .div_ceil(u64::from(g.tile_size()))
            .max(1)
    };
    let present = across(g.width()) * across(g.height());
    (HELD_BYTES / tile_bytes)
        .min(present)
        .min(points.saturating_mul(9))
        .max(9) as usize
}

/// Every point's answer for `request` on `ds`, through the decoded-tile cache `web`
/// (the server's, or the command's own), cancellable through `ticket`.
pub fn answers(
    web: &WebTiles,
    ds: &Dataset,
    fp: &Footprint,
    request: &Request,
    shift: &elevation::Shift,
    ticket: Option<&Ticket>,
) -> Result<Vec<elevation::Answer>, Failure> {
    let m = ds.pyramid.metadata();
    let tiles = CachedTiles { web, ds, ticket };
    let dem = Dem {
        footprint: fp,
        geometry: ds.pyramid.geometry(),
        quantization: m.quantization,
    };
    let hold = tiles_held(ds, request.points.len() as u64);
    elevation::answer(&dem, &tiles, &request.points, &request.options, shift, hold)
}

/// The memory one request reserves before it computes: its points' working memory
/// and the tiles it may hold.
fn working_bytes(ds: &Dataset, points: usize) -> u64 {
    let n = points as u64;
    let tile_bytes = 2 * u64::from(ds.pyramid.geometry().tile_size() + 1).pow(2);
    n * BYTES_PER_POINT + tiles_held(ds, n) as u64 * tile_bytes
}

/// The answers to `request` as the API's JSON.
fn answer_json(
    state: &AppState,
    ds: &Dataset,
    fp: &Footprint,
    request: &Request,
    (shift, datum): &(elevation::Shift, &'static str),
    ticket: &Ticket,
) -> Result<Bytes, Failure> {
    let answers = answers(&state.web, ds, fp, request, shift, Some(ticket))?;
    let cx = output::Context {
        dataset: &ds.name,
        datum,
        interpolation: request.options.interpolation.name(),
        nodata_value: request.nodata_value,
    };
    Ok(Bytes::from(output::json(&answers, &cx)))
}

/// The admitted computation of `request`, on a blocking thread with its memory
/// reserved. (Answering requests of up to 1 000 points on the runtime's own threads
/// when their tiles were decoded was tried: in runs one after the other on this noisy
/// 2-core machine, about 20 000 100-point GETs a second either way, but a p99 of
/// 6.9–7.1 ms against 4.1–5.0 ms at 64 connections: a worker that computes holds up
/// every connection it serves.)
async fn made(
    state: Arc<AppState>,
    ds: Arc<Dataset>,
    fp: Arc<Footprint>,
    request: Request,
    ticket: Ticket,
) -> Result<Made, ApiError> {
    let shift = shift(&state, &ds, &fp, &request)?;
    let need = working_bytes(&ds, request.points.len());
    ticket
        .blocking(move |t| {
            let memory = t.reserve(need).map_err(Stop::into_error)?;
            let bytes = answer_json(&state, &ds, &fp, &request, &shift, t)
                .map_err(|f| failure_error(&state, &ds, "elevation", f))?;
            drop(memory);
            Ok(t.made(bytes, 0))
        })
        .await?
}

/// The datum shift `request` asks for, or 400.
fn shift(
    state: &AppState,
    ds: &Dataset,
    fp: &Footprint,
    request: &Request,
) -> ApiResult<(elevation::Shift, &'static str)> {
    elevation::shift(
        ds.pyramid.metadata().vertical_datum,
        request.options.datum,
        state.web.config.geoid.as_ref(),
        fp.crs().is_earth(),
    )
    .map_err(ApiError::bad_request)
}

/// A JSON response of `made`'s bytes.
fn json_response(made: &Made) -> Response {
    let mut r = Response::new(made.body());
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/json"),
    );
    h.insert(header::CONTENT_LENGTH, HeaderValue::from(made.bytes.len()));
    r
}

/// `GET /v1/datasets/{name}/elevation?locations=…|path=…&samples=…`.
pub async fn get(
    State(state): State<Arc<AppState>>,
    Segments((name,)): Segments<(String,)>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    let limits = state.elevation;
    let raw = Raw::from_query(&query, limits.max_points).map_err(ApiError::bad_request)?;
    let fp = footprint(&state, &ds)?;
    let request = raw
        .resolve(Body::of(&fp), limits.max_points)
        .map_err(ApiError::bad_request)?;
    shift(&state, &ds, &fp, &request)?;
    // The answer depends on the parameters, not on how they were spelled or ordered.
    let mut pairs: Vec<(&String, &String)> = query
        .iter()
        .filter(|(k, _)| !request::IGNORED.contains(&k.as_str()))
        .collect();
    pairs.sort();
    // A converted datum also depends on the server's geoid grid.
    let geoid = match request.options.datum {
        request::Datum::Native => None,
        _ => state
            .web
            .config
            .geoid
            .as_ref()
            .map(|g| g.name().to_string()),
    };
    let variant = format!("elevation {pairs:?} {geoid:?}");
    let pin = pinned(&ds, &query);
    let etag = cache::etag(ds.content_hash(), &variant);
    if let Some(r) = cache::revalidate(&headers, &etag, ds.last_modified, pin, state.cache_max_age)
    {
        return Ok(r);
    }
    let (st, d) = (state.clone(), ds.clone());
    let flight = format!("{} {}", ds.content_hash(), cache::etag("", &variant));
    let made = state
        .compute
        .run(Kind::Elevation, flight, move |ticket| {
            made(st, d, fp, request, ticket)
        })
        .await?;
    let mut r = json_response(&made);
    cache::set_headers(
        r.headers_mut(),
        &etag,
        ds.last_modified,
        pin,
        state.cache_max_age,
    );
    Ok(r)
}

/// A body of at most `limit` bytes; `Ok(Err(n))` once more than that has come (`n`
/// bytes so far), `Err` (400) when the body cannot be read (the client broke it off).
async fn read_body(body: HttpBody, limit: u64) -> ApiResult<Result<Bytes, u64>> {
    use futures_util::StreamExt;
    let mut stream = body.into_data_stream();
    let mut out = bytes::BytesMut::new();
    while let Some(chunk) = stream.next().await {
        let chunk = chunk
            .map_err(|e| ApiError::bad_request(format!("body: it could not be read ({e})")))?;
        let n = (out.len() + chunk.len()) as u64;
        if n > limit {
            return Ok(Err(n));
        }
        out.extend_from_slice(&chunk);
    }
    Ok(Ok(out.freeze()))
}

/// Distinct keys for `POST`s (each its own computation).
static POSTS: AtomicU64 = AtomicU64::new(0);

/// `POST /v1/datasets/{name}/elevation` with a JSON body (or a form-encoded one).
pub async fn post(
    State(state): State<Arc<AppState>>,
    Segments((name,)): Segments<(String,)>,
    Params(query): Params,
    headers: HeaderMap,
    body: HttpBody,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    if let Some(k) = query.keys().next() {
        return Err(ApiError::bad_request(format!(
            "query parameter {}: a POST takes its parameters in the body",
            crate::http::error::quoted(k)
        )));
    }
    let form = match headers
        .get(header::CONTENT_TYPE)
        .map(|v| {
            v.to_str()
                .unwrap_or("")
                .split(';')
                .next()
                .unwrap_or("")
                .trim()
                .to_ascii_lowercase()
        })
        .as_deref()
    {
        None | Some("application/json") => false,
        Some("application/x-www-form-urlencoded") => true,
        Some(other) => {
            return Err(ApiError::new(
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                format!(
                    "Content-Type {}: the body is JSON (application/json) or a form (application/x-www-form-urlencoded)",
                    crate::http::error::quoted(other)
                ),
            ));
        }
    };
    let limits = state.elevation;
    let too_large = move |n: u64| {
        ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!(
                "body: {n} bytes, more than the {} allowed (--max-body-mib)",
                limits.max_body_bytes
            ),
        )
    };
    let declared = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    if let Some(n) = declared.filter(|&n| n > limits.max_body_bytes) {
        return Err(too_large(n));
    }
    let fp = footprint(&state, &ds)?;
    let (st, d) = (state.clone(), ds.clone());
    let key = format!("post {}", POSTS.fetch_add(1, Ordering::Relaxed));
    let made = state
        .compute
        .run(Kind::Elevation, key, move |ticket| async move {
            // The body's bytes are reserved before they are read.
            let expected = declared.unwrap_or(limits.max_body_bytes);
            let reserved = ticket
                .reserve_async(expected)
                .await
                .map_err(Stop::into_error)?;
            let bytes = read_body(body, limits.max_body_bytes)
                .await?
                .map_err(too_large)?;
            let (max, body) = (limits.max_points, Body::of(&fp));
            let parse = move || -> Result<Request, ApiError> {
                let raw = if form {
                    let text = std::str::from_utf8(&bytes)
                        .map_err(|_| ApiError::bad_request("body: the form is not UTF-8"))?;
                    let Params(map) = Params::parse(text)?;
                    Raw::from_query(&map, max)
                } else {
                    Raw::from_json(&bytes, max)
                };
                raw.and_then(|r| r.resolve(body, max))
                    .map_err(ApiError::bad_request)
            };
            // A large body takes milliseconds to parse: not on the runtime's threads.
            let request = if declared.is_some_and(|n| n <= 64 << 10) {
                parse()?
            } else {
                tokio::task::spawn_blocking(parse)
                    .await
                    .map_err(|e| ApiError::internal(format!("parsing the body failed: {e}")))??
            };
            drop(reserved);
            made(st, d, fp, request, ticket).await
        })
        .await?;
    let mut r = json_response(&made);
    r.headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    Ok(r)
}
