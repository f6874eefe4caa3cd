//! Standard-grid web tiles (DECISIONS.md "Standard-grid web tiles",
//! docs/ARCHITECTURE.md#derived-outputs): `WebMercatorQuad` (`webmercator`, the XYZ
//! scheme of MapLibre, Leaflet, OpenLayers, QGIS) and `WorldCRS84Quad` (`crs84`),
//! resampled per request from the pyramid whatever the dataset's CRS (web/resample.rs),
//! as Terrarium or Terrain-RGB PNG or lossless WebP, with a TileJSON 3.0.0 document per
//! grid and encoding.
//!
//! - `GET /v1/datasets/{name}/{grid}/{z}/{x}/{y}.png|.webp?encoding=&size=`
//! - `GET /v1/datasets/{name}/{grid}/tilejson.json?encoding=&size=`

use super::base_url;
use super::{Params, Segments, dataset, unavailable, xml_escape};
use crate::cesium::quantized_mesh;
use crate::http::cache;
use crate::http::error::{ApiError, ApiResult, quoted};
use crate::serve::compute::{Kind, Made, Reservation, Stop, Ticket};
use crate::serve::dataset::{Dataset, DatasetUnavailable, RecordError};
use crate::serve::web_cache::{EmptyTiles, Look, MadeKey, WebTiles, dataset_key};
use crate::serve::{AppState, TilesServed};
use crate::web::encoding::{Encoding, ImageEncodeError, ImageFormat, NoData, TileFormat, rgba};
use crate::web::footprint::Footprint;
use crate::web::resample::{self, SourceTile};
use crate::web::tile_matrix::{MAX_ZOOM, TileMatrixSet, WebTile};
use axum::Json;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, StatusCode, Uri, header};
use axum::response::{IntoResponse, Response};
use bytes::Bytes;
use std::collections::HashMap;
use std::sync::Arc;
use tessera_shared::TileId;
use tessera_shared::codec;

/// Tile sizes served, in pixels.
pub const SIZES: [u32; 2] = [256, 512];

/// The grid a path segment names, or 404 naming the grids there are.
pub fn grid(raw: &str) -> ApiResult<TileMatrixSet> {
    TileMatrixSet::parse(raw).ok_or_else(|| {
        ApiError::not_found(format!(
            "unknown tile grid {}: the grids are webmercator (WebMercatorQuad) and crs84 (WorldCRS84Quad)",
            quoted(raw)
        ))
    })
}

/// `?size=` (256 when absent), or 400.
pub fn size(query: &HashMap<String, String>) -> ApiResult<u32> {
    match query.get("size").map(String::as_str) {
        None => Ok(256),
        Some(s) => s
            .parse::<u32>()
            .ok()
            .filter(|v| SIZES.contains(v))
            .ok_or_else(|| {
                ApiError::bad_request(format!("unknown size {}: sizes are 256 and 512", quoted(s)))
            }),
    }
}

/// `?encoding=`, or 400.
pub fn encoding(query: &HashMap<String, String>) -> ApiResult<Encoding> {
    Ok(Encoding::from_query(
        query.get("encoding").map(String::as_str),
    )?)
}

/// The dataset's footprint, or 404 saying why it has no place on a map.
pub fn footprint(state: &AppState, ds: &Dataset) -> ApiResult<Arc<Footprint>> {
    state
        .web
        .footprint(ds.content_hash(), || Footprint::new(ds.pyramid.metadata()))
        .map_err(|e| {
            ApiError::not_found(format!(
                "dataset {:?} has no standard-grid tiles: {e}",
                ds.name
            ))
        })
}

/// The web tile `z/x/y` of `tms`, or 404 naming the valid ranges.
pub fn web_tile(tms: TileMatrixSet, z: &str, x: &str, y: &str) -> ApiResult<WebTile> {
    let z_ok = z.parse::<u8>().ok().filter(|z| *z <= MAX_ZOOM);
    let Some(zv) = z_ok else {
        return Err(ApiError::not_found(format!(
            "zoom {} is not in {} (zooms 0-{MAX_ZOOM})",
            quoted(z),
            tms.id()
        )));
    };
    match (x.parse::<u32>(), y.parse::<u32>()) {
        (Ok(xv), Ok(yv)) => WebTile::new(tms, zv, xv, yv),
        _ => None,
    }
    .ok_or_else(|| {
        let (cols, rows) = tms.matrix_size(zv);
        ApiError::not_found(format!(
            "tile ({}, {}) is not in {} zoom {zv} (x 0-{}, y 0-{})",
            quoted(x),
            quoted(y),
            tms.id(),
            cols - 1,
            rows - 1
        ))
    })
}

/// Why a tile could not be made.
#[derive(Debug)]
pub enum Failure {
    Corrupt(TileId, bool),
    Undecodable(TileId, codec::CodecError),
    Unavailable(DatasetUnavailable),
    /// A PNG or WebP tile could not be encoded.
    EncodeImage(ImageEncodeError),
    /// A quantized-mesh tile could not be encoded (serve/routes/cesium.rs).
    EncodeMesh(quantized_mesh::EncodeError),
    /// A contour tile could not be encoded (serve/routes/contours.rs).
    EncodeVector(mvt::Error),
    /// A contour tile would hold more lines than a tile may (web/contour/): the
    /// asker's fault, named in the reason.
    TooDense(String),
    /// Its requesters are gone, or no memory came free in time (serve/compute/).
    Stopped(Stop),
}

/// A decoded source tile, through the cache; `None` when the pyramid has no such
/// tile (outside the DEM, or wholly no-data).
pub fn source(
    web: &WebTiles,
    ds: &Dataset,
    tile: TileId,
) -> Result<Option<Arc<SourceTile>>, Failure> {
    // Absent tiles are known from the index: nothing to decode. In a multi-resolution
    // pyramid a tile may be absent because only coarser data lies there: its finer
    // view is its nearest stored ancestor's surface.
    if ds.pyramid.entry(tile).is_none_or(|e| e.length == 0) {
        return if ds.multi_resolution {
            upsampled(web, ds, tile)
        } else {
            Ok(None)
        };
    }
    let layout = ds.pyramid.record_layout();
    let quantization = ds.pyramid.metadata().quantization;
    web.source(dataset_key(ds.content_hash()), tile, || {
        let record = match ds.record(tile) {
            Ok(Some((_, bytes))) => bytes,
            Ok(None) => return Err(None),
            Err(RecordError::Corrupt(c)) => {
                return Err(Some(Failure::Corrupt(c.tile, c.first)));
            }
            Err(RecordError::Unavailable(r)) => return Err(Some(Failure::Unavailable(r))),
        };
        let decoded = codec::decode_record(&record, layout)
            .map_err(|e| Some(Failure::Undecodable(tile, e)))?;
        Ok(Arc::new(SourceTile {
            block_errors: resample::block_errors(&decoded.errors),
            heights: decoded.heights,
            mask: decoded.mask,
            quantization,
        }))
    })
    .map(Some)
    .or_else(|e| e.map_or(Ok(None), Err))
}

/// An absent tile of a multi-resolution pyramid made from its nearest stored
/// ancestor: each of its samples bilinear between the ancestor's (the ancestor's
/// surface, which is what the pyramid says is there), each cell valid where the
/// ancestor's cell under its centre is; `None` where the ancestor has no terrain
/// there either (a wholly no-data tile) or no ancestor is stored. Cached like a
/// decoded tile.
fn upsampled(
    web: &WebTiles,
    ds: &Dataset,
    tile: TileId,
) -> Result<Option<Arc<SourceTile>>, Failure> {
    let mut ancestor = tile;
    let mut depth = 0u32;
    loop {
        let Some(parent) = ancestor.parent() else {
            return Ok(None);
        };
        ancestor = parent;
        depth += 1;
        if ds.pyramid.entry(ancestor).is_some_and(|e| e.length > 0) {
            break;
        }
    }
    let Some(a) = source(web, ds, ancestor)? else {
        return Ok(None);
    };
    let t = ds.pyramid.geometry().tile_size();
    let made = web.source(dataset_key(ds.content_hash()), tile, || -> Result<_, ()> {
        let made = crate::web::upsample::upsample(&a, t, tile, ancestor, depth);
        if made.mask.is_none_valid() {
            Err(())
        } else {
            Ok(Arc::new(made))
        }
    });
    Ok(made.ok())
}

/// Working memory of a grid tile per pixel: its `f64` height, RGBA, and the
/// encoder's buffers.
const GRID_BYTES_PER_PIXEL: u64 = 24;

/// The encoded tile, or an empty body when it lies beyond the dataset's bounds
/// (what its TileJSON states). A tile within them but without data (a corner of a
/// rotated dataset, a wholly void one) is the fill, flat: web maps ask for every
/// tile within the bounds, and a 404 there would be an error in their console.
/// With `round`, heights are rounded to the nearest multiple of it first (PMTiles
/// export's `--precision auto`).
pub fn make(
    web: &WebTiles,
    ds: &Dataset,
    fp: &Footprint,
    key: MadeKey,
    round: Option<f64>,
    ticket: &Ticket,
) -> Result<Bytes, Failure> {
    let geometry = ds.pyramid.geometry();
    let px2 = u64::from(key.px).pow(2);
    let fill = ds.pyramid.metadata().min_height;
    let fill = round.map_or(fill, |q| (fill / q).round() * q);
    let (Look::Heights(encoding, nodata), TileFormat::Image(format)) = (key.look, key.format)
    else {
        unreachable!("height tiles are made with a height look, as images")
    };
    let encode = |heights: &[f64], data: &[bool]| {
        let rounded: Vec<f64>;
        let heights = if let Some(q) = round {
            rounded = heights.iter().map(|h| (h / q).round() * q).collect();
            &rounded
        } else {
            heights
        };
        let pixels = rgba(heights, data, encoding, nodata, fill);
        format
            .encode(&pixels, key.px)
            .map(Bytes::from)
            .map_err(Failure::EncodeImage)
    };
    let flat = || -> Result<Bytes, Failure> {
        if !fp.meets(key.tile) {
            return Ok(Bytes::new());
        }
        let _memory = ticket
            .reserve(px2 * GRID_BYTES_PER_PIXEL)
            .map_err(Failure::Stopped)?;
        let n = px2 as usize;
        encode(&vec![f64::NAN; n], &vec![false; n])
    };
    let Some(plan) = resample::plan(fp, geometry, key.tile, key.px) else {
        return flat();
    };
    let (sources, memory) = plan_sources(web, ds, &plan, px2 * GRID_BYTES_PER_PIXEL, ticket)?;
    let sampled = plan.sample(&sources);
    if sampled.is_empty() {
        // The flat tile reserves its own, smaller share.
        drop(memory);
        return flat();
    }
    let encoded = encode(&sampled.heights, &sampled.data);
    drop(memory);
    encoded
}

/// A plan's decoded source tiles, in its order (`None` where the pyramid has none).
pub type Sources = Vec<Option<Arc<SourceTile>>>;

/// The decoded source tiles a plan reads, in its order, with `working` bytes (the
/// output's own) plus the sources' reserved for the caller to hold while it works.
pub fn plan_sources(
    web: &WebTiles,
    ds: &Dataset,
    plan: &resample::Plan,
    working: u64,
    ticket: &Ticket,
) -> Result<(Sources, Reservation), Failure> {
    let stop = |s| Failure::Stopped(s);
    let tiles = plan.source_tiles();
    let t = u64::from(ds.pyramid.geometry().tile_size()) + 1;
    let memory = ticket
        .reserve(working + tiles.len() as u64 * t * t * 2)
        .map_err(stop)?;
    let sources = tiles
        .into_iter()
        .map(|t| {
            ticket.check().map_err(stop)?;
            source(web, ds, t)
        })
        .collect::<Result<Vec<_>, _>>()?;
    ticket.check().map_err(stop)?;
    Ok((sources, memory))
}

/// The first parameter of `query` (in name order, so the answer is stable) that is not
/// in `allowed`: strict routes refuse it with a 400 naming it, since a misspelt
/// option must not silently draw the default.
pub fn unknown_parameter<'q>(
    query: &'q HashMap<String, String>,
    allowed: &[&str],
) -> Option<&'q String> {
    let mut keys: Vec<&String> = query.keys().collect();
    keys.sort();
    keys.into_iter().find(|k| !allowed.contains(&k.as_str()))
}

/// `GET /v1/datasets/{name}/{grid}/{z}/{x}/{y}.{png,webp}?encoding=&size=`.
pub async fn tile(
    State(state): State<Arc<AppState>>,
    Segments((name, grid_name, z, x, y)): Segments<(String, String, String, String, String)>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let Some((y, format)) = ImageFormat::split(&y) else {
        return Err(ApiError::not_found(
            "no such endpoint; grid tiles are /v1/datasets/{name}/{grid}/{z}/{x}/{y}.png or .webp (see API.md)",
        ));
    };
    let ds = dataset(&state, &name)?;
    let tms = grid(&grid_name)?;
    let enc = encoding(&query)?;
    let px = size(&query)?;
    let nodata = NoData::from_query(query.get("nodata").map(String::as_str))?;
    let tile = web_tile(tms, &z, &x, y)?;
    let pin = super::pinned(&ds, &query);
    // What the tile depends on besides the dataset: its ETag and its flight's key.
    let variant = format!(
        "grid {} {px} {} {} {} {}/{}/{}",
        tms.path(),
        enc.name(),
        format.extension(),
        nodata.name(),
        tile.z,
        tile.x,
        tile.y
    );
    let asked = Asked {
        tile,
        px,
        look: Look::Heights(enc, nodata),
        format: TileFormat::Image(format),
        variant,
        pin,
    };
    image_tile(
        state,
        ds,
        &headers,
        asked,
        Kind::GridTile,
        |web, ds, fp, key, ticket| make(web, ds, fp, key, None, ticket),
    )
    .await
}

/// An image tile as asked for: what keys its cache entry, its ETag and its flight.
#[derive(Debug)]
pub struct Asked {
    pub tile: WebTile,
    pub px: u32,
    pub look: Look,
    pub format: TileFormat,
    /// What the tile depends on besides the dataset (the ETag's and the flight's key).
    pub variant: String,
    /// Whether the URL pins the content (`?v=`).
    pub pin: bool,
}

/// The answer to an image tile request: 304 when the client has it, else the tile
/// from the made-tile cache, else made by `make` — once per distinct tile at a time,
/// admitted as `kind` and cancellable, on a blocking thread (resampling and
/// compressing take milliseconds) — and kept.
pub async fn image_tile<F>(
    state: Arc<AppState>,
    ds: Arc<Dataset>,
    headers: &HeaderMap,
    asked: Asked,
    kind: Kind,
    make: F,
) -> ApiResult<Response>
where
    F: FnOnce(&WebTiles, &Dataset, &Footprint, MadeKey, &Ticket) -> Result<Bytes, Failure>
        + Send
        + 'static,
{
    let Asked {
        tile,
        px,
        look,
        format,
        variant,
        pin,
    } = asked;
    let etag = cache::etag(ds.content_hash(), &variant);
    if let Some(r) = cache::revalidate(headers, &etag, ds.last_modified, pin, state.cache_max_age) {
        return Ok(r);
    }
    let fp = footprint(&state, &ds)?;
    let key = MadeKey {
        dataset: dataset_key(ds.content_hash()),
        tile,
        px,
        look,
        format,
    };
    let made = if let Some(b) = state.web.made(&key) {
        state.compute.hit(kind, b, 1)?
    } else {
        let (st, d) = (state.clone(), ds.clone());
        let flight = format!("{} {variant}", ds.content_hash());
        state
            .compute
            .run_blocking(kind, flight, move |ticket| {
                let b = make(&st.web, &d, &fp, key, ticket)
                    .map_err(|f| failure_error(&st, &d, &tile.to_string(), f))?;
                st.web.keep(key, b.clone());
                Ok(ticket.made(b, 1))
            })
            .await?
    };
    Ok(image_response(&state, &ds, tile, &made, format, &etag, pin))
}

/// The response for a made image tile: the image, or [`empty`]'s answer for an
/// empty body (a tile beyond the dataset's bounds).
pub fn image_response(
    state: &AppState,
    ds: &Dataset,
    tile: WebTile,
    made: &Made,
    format: TileFormat,
    etag: &str,
    pin: bool,
) -> Response {
    if made.bytes.is_empty() {
        return empty(state, ds, tile, etag, pin);
    }
    let len = made.bytes.len();
    let mut r = Response::new(made.body());
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(format.mime()),
    );
    h.insert(header::CONTENT_LENGTH, HeaderValue::from(len));
    cache::set_headers(h, etag, ds.last_modified, pin, state.cache_max_age);
    r.extensions_mut().insert(TilesServed(1));
    r
}

/// The answer for a tile without data: 404 with a reason, or 204 (`--empty-tiles
/// 204`); cacheable like a full tile, since it is as immutable.
pub fn empty(state: &AppState, ds: &Dataset, tile: WebTile, etag: &str, pin: bool) -> Response {
    let mut r = match state.web.config.empty_tiles {
        EmptyTiles::NotFound => ApiError::not_found(format!(
            "{tile} holds no data of dataset {:?}: it lies outside the dataset or over no-data",
            ds.name
        ))
        .into_response(),
        EmptyTiles::NoContent => StatusCode::NO_CONTENT.into_response(),
    };
    cache::set_headers(
        r.headers_mut(),
        etag,
        ds.last_modified,
        pin,
        state.cache_max_age,
    );
    r
}

/// The API error for a tile (`tile` names it) that could not be made.
pub fn failure_error(state: &AppState, ds: &Dataset, tile: &str, f: Failure) -> ApiError {
    match f {
        Failure::Corrupt(t, first) => {
            state.metrics.corrupt_read(first);
            ApiError::internal(format!("{tile}: source {t} fails its checksum"))
        }
        Failure::Undecodable(t, e) => {
            state.metrics.corrupt_read(ds.mark_undecodable(t));
            tracing::error!(dataset = %ds.name, tile = %t, error = %e, "record does not decode");
            ApiError::internal(format!(
                "{tile}: source {t} passes its checksum but its height data does not decode"
            ))
        }
        Failure::Unavailable(r) => unavailable(&r),
        Failure::Stopped(s) => s.into_error(),
        Failure::EncodeImage(e) => encode_failed(ds, tile, &e),
        Failure::EncodeMesh(e) => encode_failed(ds, tile, &e),
        Failure::EncodeVector(e) => encode_failed(ds, tile, &e),
        Failure::TooDense(why) => ApiError::bad_request(why),
    }
}

/// The 500 for a tile that could not be encoded; the encoder's detail goes to the log.
fn encode_failed(ds: &Dataset, tile: &str, e: &dyn std::error::Error) -> ApiError {
    tracing::error!(dataset = %ds.name, %tile, error = %e, "tile encoding failed");
    ApiError::internal(format!("{tile}: cannot encode the tile"))
}

/// The TileJSON 3.0.0 document of a dataset's tiles in `tms` (see the module doc).
pub fn tilejson_doc(
    ds: &Dataset,
    fp: &Footprint,
    tms: TileMatrixSet,
    base: &str,
    enc: Encoding,
    px: u32,
    attribution: Option<&str>,
) -> serde_json::Value {
    let tiles = format!(
        "{base}/v1/datasets/{}/{}/{{z}}/{{x}}/{{y}}.png?encoding={}&size={px}&v={}",
        ds.name,
        tms.path(),
        enc.name(),
        ds.content_hash()
    );
    let mut doc = grid_tilejson(ds, fp, tms, px, tiles, attribution);
    doc.other.insert("encoding".into(), enc.name().into());
    // As a JSON value, whose keys serialize sorted as the documents always were.
    serde_json::to_value(doc).expect("a TileJSON document serializes")
}

/// A TileJSON 3.0.0 document of `px`-pixel tiles at URL template `tiles` over the
/// dataset's place in `tms`: bounds, centre, zooms, and the grid named.
pub fn grid_tilejson(
    ds: &Dataset,
    fp: &Footprint,
    tms: TileMatrixSet,
    px: u32,
    tiles: String,
    attribution: Option<&str>,
) -> tilejson::TileJSON {
    let max = fp.max_zoom(tms, px);
    let [w, s, e, n] = fp.lon_lat;
    let [lon, lat] = fp.centre();
    let mut doc = tilejson::tilejson! {
        tiles: vec![tiles],
        name: ds.name.clone(),
        scheme: "xyz".to_string(),
        minzoom: 0,
        maxzoom: max,
        bounds: tilejson::Bounds::new(
            w.clamp(-180.0, 180.0),
            s.clamp(-90.0, 90.0),
            e.clamp(-180.0, 180.0),
            n.clamp(-90.0, 90.0),
        ),
        center: tilejson::Center::new(lon, lat, fp.overview_zoom(tms).min(max)),
    };
    doc.attribution = attribution.map(xml_escape);
    // Beyond TileJSON's own fields.
    let more = &mut doc.other;
    more.insert("tileSize".into(), px.into());
    more.insert("tileMatrixSet".into(), tms.id().into());
    more.insert("crs".into(), format!("EPSG:{}", tms.epsg()).into());
    doc
}

/// `GET /v1/datasets/{name}/{grid}/tilejson.json?encoding=&size=`. Its URLs are
/// absolute (routes/base_url.rs), from the request's `Host` when nothing is
/// configured, so a map on another origin fetches the tiles from this server.
pub async fn tilejson(
    State(state): State<Arc<AppState>>,
    Segments((name, grid_name)): Segments<(String, String)>,
    Params(query): Params,
    headers: HeaderMap,
    uri: Uri,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    let tms = grid(&grid_name)?;
    let enc = encoding(&query)?;
    let px = size(&query)?;
    let variant = format!("grid tilejson {} {} {px}", tms.path(), enc.name());
    tilejson_response(
        &state,
        &ds,
        &headers,
        &uri,
        &query,
        &variant,
        |fp, url, attribution| tilejson_doc(&ds, fp, tms, url, enc, px, attribution),
    )
}

/// A standard-grid TileJSON response: the document `doc` makes from the footprint, the
/// absolute base URL and the attribution, under an ETag over the content hash,
/// `variant`, the base URL and the attribution (304 when the client has it), private
/// when its URLs came from the request's `Host` (routes/base_url.rs).
pub fn tilejson_response(
    state: &AppState,
    ds: &Dataset,
    headers: &HeaderMap,
    uri: &Uri,
    query: &HashMap<String, String>,
    variant: &str,
    doc: impl FnOnce(&Footprint, &str, Option<&str>) -> serde_json::Value,
) -> ApiResult<Response> {
    let base = base_url::absolute(state, headers, uri)?;
    let (url, from_host) = base.map_or((String::new(), false), |b| (b.url, b.from_host));
    let pin = super::pinned(ds, query);
    let attribution = state.web.config.attribution.as_deref();
    let etag = cache::etag(
        ds.content_hash(),
        &format!("{variant} {url} {attribution:?}"),
    );
    let revalidated = cache::revalidate(headers, &etag, ds.last_modified, pin, state.cache_max_age);
    let mut r = if let Some(r) = revalidated {
        r
    } else {
        let fp = footprint(state, ds)?;
        let mut r = Json(doc(&fp, &url, attribution)).into_response();
        cache::set_headers(
            r.headers_mut(),
            &etag,
            ds.last_modified,
            pin,
            state.cache_max_age,
        );
        r
    };
    base_url::private(r.headers_mut(), from_host, state.cache_max_age);
    Ok(r)
}
