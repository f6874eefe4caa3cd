//! OGC API – Tiles (OGC 20-057) over the standard-grid tiles of web_grid.rs: a
//! landing page, conformance, the two tile matrix sets as OGC TMS 2.0 JSON, one
//! collection per dataset with a place on a map, its coverage tilesets (one per
//! grid) and their tiles (DECISIONS.md "WMTS capabilities and OGC API",
//! docs/ARCHITECTURE.md#derived-outputs).
//!
//! Links are relative to the server unless `--public-url` (or trusted forwarded
//! headers) give a base, as for TileJSON: JSON clients resolve them against the
//! document's URL (GDAL's OGCAPI driver resolves `/…` against the server root).
//! Tiles are the web_grid tiles themselves (`?encoding=`, `?size=` as there); the
//! tile path orders the row before the column, as the standard does.

use super::base_url;
use super::web_grid::{self, footprint};
use super::wmts::{
    ENCODINGS, MappedDataset, TILE_PX, combined_hash, decoding, latest, mapped_datasets,
    tile_limits,
};
use super::{Params, Segments, dataset, pinned};
use crate::http::cache::{self, LastModified};
use crate::http::error::ApiResult;
use crate::serve::AppState;
use crate::serve::dataset::Dataset;
use crate::web::encoding::Encoding;
use crate::web::footprint::Footprint;
use crate::web::tile_matrix::{MAX_ZOOM, TileMatrixSet};
use axum::Json;
use axum::extract::State;
use axum::http::HeaderMap;
use axum::response::{IntoResponse, Response};
use serde_json::{Value, json};
use std::sync::Arc;

const JSON: &str = "application/json";
const REL: &str = "http://www.opengis.net/def/rel/ogc/1.0/";

/// What the server conforms to (OGC API – Common, – Tiles, TMS 2.0).
pub const CONFORMANCE: [&str; 12] = [
    "http://www.opengis.net/spec/ogcapi-common-1/1.0/conf/core",
    "http://www.opengis.net/spec/ogcapi-common-1/1.0/conf/landing-page",
    "http://www.opengis.net/spec/ogcapi-common-1/1.0/conf/json",
    "http://www.opengis.net/spec/ogcapi-common-2/1.0/conf/collections",
    "http://www.opengis.net/spec/ogcapi-tiles-1/1.0/conf/core",
    "http://www.opengis.net/spec/ogcapi-tiles-1/1.0/conf/tileset",
    "http://www.opengis.net/spec/ogcapi-tiles-1/1.0/conf/tilesets-list",
    "http://www.opengis.net/spec/ogcapi-tiles-1/1.0/conf/geodata-tilesets",
    "http://www.opengis.net/spec/ogcapi-tiles-1/1.0/conf/png",
    "http://www.opengis.net/spec/tms/2.0/conf/tilematrixset",
    "http://www.opengis.net/spec/tms/2.0/conf/json-tilematrixset",
    "http://www.opengis.net/spec/tms/2.0/conf/tilesetmetadata",
];

fn link(rel: &str, href: &str, title: &str) -> Value {
    json!({"rel": rel, "type": JSON, "title": title, "href": href})
}

/// The standard's URI of a tile matrix set.
pub fn tms_uri(tms: TileMatrixSet) -> String {
    format!(
        "http://www.opengis.net/def/tilematrixset/OGC/1.0/{}",
        tms.id()
    )
}

/// The OGC TMS 2.0 JSON definition of a grid, zooms 0 to [`MAX_ZOOM`] at 256 px.
pub fn tile_matrix_set_doc(tms: TileMatrixSet, base: &str) -> Value {
    let [x0, _, _, y1] = tms.extent();
    let matrices: Vec<Value> = (0..=MAX_ZOOM)
        .map(|z| {
            let (cols, rows) = tms.matrix_size(z);
            json!({
                "id": z.to_string(),
                "scaleDenominator": tms.scale_denominator(z, TILE_PX),
                "cellSize": tms.cell_size(z, TILE_PX),
                "cornerOfOrigin": "topLeft",
                "pointOfOrigin": [x0, y1],
                "tileWidth": TILE_PX,
                "tileHeight": TILE_PX,
                "matrixWidth": cols,
                "matrixHeight": rows,
            })
        })
        .collect();
    let (title, axes, wkss) = match tms {
        TileMatrixSet::WebMercatorQuad => (
            "Google Maps Compatible for the World",
            ["X", "Y"],
            "http://www.opengis.net/def/wkss/OGC/1.0/GoogleMapsCompatible",
        ),
        TileMatrixSet::WorldCrs84Quad => (
            "CRS84 for the World",
            ["Lon", "Lat"],
            "http://www.opengis.net/def/wkss/OGC/1.0/GoogleCRS84Quad",
        ),
    };
    json!({
        "id": tms.id(),
        "title": title,
        "uri": tms_uri(tms),
        "crs": tms.crs_uri(),
        "orderedAxes": axes,
        "wellKnownScaleSet": wkss,
        "links": [link("self", &format!("{base}/ogcapi/tileMatrixSets/{}", tms.id()), tms.id())],
        "tileMatrices": matrices,
    })
}

fn wgs84(fp: &Footprint) -> [f64; 4] {
    let [w, s, e, n] = fp.lon_lat;
    [
        w.clamp(-180.0, 180.0),
        s.clamp(-90.0, 90.0),
        e.clamp(-180.0, 180.0),
        n.clamp(-90.0, 90.0),
    ]
}

/// The collection of one dataset.
pub fn collection_doc(ds: &Dataset, fp: &Footprint, base: &str) -> Value {
    let here = format!("{base}/ogcapi/collections/{}", ds.name);
    let m = ds.pyramid.metadata();
    json!({
        "id": ds.name,
        "title": ds.name,
        "description": format!(
            "Elevation of {} as coverage tiles (PNG, Terrarium or Terrain-RGB; ?encoding=terrarium|mapbox). {} {}",
            ds.name, decoding(Encoding::Terrarium), decoding(Encoding::Mapbox)
        ),
        "attribution": m.source,
        "dataType": "coverage",
        "extent": {"spatial": {
            "bbox": [wgs84(fp)],
            "crs": "http://www.opengis.net/def/crs/OGC/1.3/CRS84",
        }},
        "crs": TileMatrixSet::ALL.map(TileMatrixSet::crs_uri),
        "links": [
            link("self", &here, &ds.name),
            link(&format!("{REL}tilesets-coverage"), &format!("{here}/coverage/tiles"), "coverage tilesets"),
        ],
    })
}

/// The tileset of one dataset in one grid, for one encoding.
pub fn tileset_doc(
    ds: &Dataset,
    fp: &Footprint,
    tms: TileMatrixSet,
    enc: Encoding,
    base: &str,
) -> Value {
    let here = format!(
        "{base}/ogcapi/collections/{}/coverage/tiles/{}",
        ds.name,
        tms.id()
    );
    let bounds = fp.grid_bounds(tms);
    let limits: Vec<Value> = (0..=fp.max_zoom(tms, TILE_PX))
        .map(|z| {
            let l = tile_limits(tms, bounds, z);
            json!({
                "tileMatrix": z.to_string(),
                "minTileRow": l.min_row, "maxTileRow": l.max_row,
                "minTileCol": l.min_col, "maxTileCol": l.max_col,
            })
        })
        .collect();
    let [x0, y0, x1, y1] = match tms {
        TileMatrixSet::WorldCrs84Quad => wgs84(fp),
        TileMatrixSet::WebMercatorQuad => bounds,
    };
    json!({
        "title": format!("{} on {} ({})", ds.name, tms.id(), enc.name()),
        "description": decoding(enc),
        "dataType": "coverage",
        "crs": tms.crs_uri(),
        "tileMatrixSetURI": tms_uri(tms),
        "tileMatrixSetLimits": limits,
        "boundingBox": {"lowerLeft": [x0, y0], "upperRight": [x1, y1], "crs": tms.crs_uri()},
        "links": [
            link("self", &format!("{here}?encoding={}", enc.name()), &ds.name),
            link(&format!("{REL}tiling-scheme"), &format!("{base}/ogcapi/tileMatrixSets/{}", tms.id()), tms.id()),
            {
                "rel": "item",
                "type": "image/png",
                "title": format!("{} tiles", enc.name()),
                "templated": true,
                // GDAL's OGC API driver reads PNG pixels exactly: alpha marks no-data.
                "href": format!(
                    "{here}/{{tileMatrix}}/{{tileRow}}/{{tileCol}}?encoding={}&nodata=transparent&v={}",
                    enc.name(),
                    ds.content_hash()
                ),
            },
        ],
    })
}

/// A JSON response with an ETag and Cache-Control, or its 304.
fn respond(
    state: &AppState,
    headers: &HeaderMap,
    etag: &str,
    last_modified: LastModified,
    pin: bool,
    body: impl FnOnce() -> Value,
) -> Response {
    if let Some(r) = cache::revalidate(headers, etag, last_modified, pin, state.cache_max_age) {
        return r;
    }
    let mut r = Json(body()).into_response();
    cache::set_headers(
        r.headers_mut(),
        etag,
        last_modified,
        pin,
        state.cache_max_age,
    );
    r
}

/// The ETag of a document that depends on no dataset: this server's version and the base.
fn static_etag(what: &str, base: &str) -> String {
    cache::etag(
        &format!(
            "{:016x}",
            xxhash_rust::xxh3::xxh3_64(env!("CARGO_PKG_VERSION").as_bytes())
        ),
        &format!("ogcapi {what} {base}"),
    )
}

/// `GET /ogcapi`.
pub async fn landing(
    State(state): State<Arc<AppState>>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let base = base_url::configured(&state, &headers)?;
    let etag = static_etag("landing", &base);
    Ok(respond(
        &state,
        &headers,
        &etag,
        LastModified::UNKNOWN,
        false,
        || {
            json!({
                "title": "Tessera DEM tiles",
                "description": "Elevation datasets as OGC API – Tiles coverage tilesets (PNG, Terrarium or Terrain-RGB), on the WebMercatorQuad and WorldCRS84Quad grids.",
                "links": [
                    link("self", &format!("{base}/ogcapi"), "this document"),
                    link("conformance", &format!("{base}/ogcapi/conformance"), "conformance classes"),
                    link(&format!("{REL}conformance"), &format!("{base}/ogcapi/conformance"), "conformance classes"),
                    link(&format!("{REL}tiling-schemes"), &format!("{base}/ogcapi/tileMatrixSets"), "tile matrix sets"),
                    link("data", &format!("{base}/ogcapi/collections"), "datasets"),
                    link(&format!("{REL}data"), &format!("{base}/ogcapi/collections"), "datasets"),
                ],
            })
        },
    ))
}

/// `GET /ogcapi/conformance`.
pub async fn conformance(
    State(state): State<Arc<AppState>>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let etag = static_etag("conformance", "");
    Ok(respond(
        &state,
        &headers,
        &etag,
        LastModified::UNKNOWN,
        false,
        || json!({"conformsTo": CONFORMANCE}),
    ))
}

/// `GET /ogcapi/tileMatrixSets`.
pub async fn tile_matrix_sets(
    State(state): State<Arc<AppState>>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let base = base_url::configured(&state, &headers)?;
    let etag = static_etag("tileMatrixSets", &base);
    Ok(respond(
        &state,
        &headers,
        &etag,
        LastModified::UNKNOWN,
        false,
        || {
            let sets: Vec<Value> = TileMatrixSet::ALL
            .into_iter()
            .map(|t| {
                json!({
                    "id": t.id(),
                    "title": t.id(),
                    "uri": tms_uri(t),
                    "crs": t.crs_uri(),
                    "links": [link("self", &format!("{base}/ogcapi/tileMatrixSets/{}", t.id()), t.id())],
                })
            })
            .collect();
            json!({
                "links": [link("self", &format!("{base}/ogcapi/tileMatrixSets"), "tile matrix sets")],
                "tileMatrixSets": sets,
            })
        },
    ))
}

/// A grid named by its standard identifier (or our path segment), or 404.
fn grid(raw: &str) -> ApiResult<TileMatrixSet> {
    web_grid::grid(raw)
}

/// `GET /ogcapi/tileMatrixSets/{tms}`.
pub async fn tile_matrix_set(
    State(state): State<Arc<AppState>>,
    Segments(id): Segments<String>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let tms = grid(&id)?;
    let base = base_url::configured(&state, &headers)?;
    let etag = static_etag(&format!("tileMatrixSet {}", tms.id()), &base);
    Ok(respond(
        &state,
        &headers,
        &etag,
        LastModified::UNKNOWN,
        false,
        || tile_matrix_set_doc(tms, &base),
    ))
}

/// `GET /ogcapi/collections`: every dataset with a place on a map.
pub async fn collections(
    State(state): State<Arc<AppState>>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let base = base_url::configured(&state, &headers)?;
    let found = mapped_datasets(&state);
    let ds: Vec<Arc<Dataset>> = found.iter().map(|(d, _)| d.clone()).collect();
    let etag = cache::etag(
        &combined_hash(ds.iter().map(AsRef::as_ref)),
        &format!("ogcapi collections {base}"),
    );
    Ok(respond(&state, &headers, &etag, latest(&ds), false, || {
        let list: Vec<Value> = found
            .iter()
            .map(|(d, fp)| collection_doc(d, fp, &base))
            .collect();
        json!({
            "links": [link("self", &format!("{base}/ogcapi/collections"), "datasets")],
            "collections": list,
        })
    }))
}

/// The dataset and its footprint, or 400/404/503.
fn mapped(state: &AppState, name: &str) -> ApiResult<MappedDataset> {
    let ds = dataset(state, name)?;
    let fp = footprint(state, &ds)?;
    Ok((ds, fp))
}

/// `GET /ogcapi/collections/{name}`.
pub async fn collection(
    State(state): State<Arc<AppState>>,
    Segments(name): Segments<String>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let (ds, fp) = mapped(&state, &name)?;
    let base = base_url::configured(&state, &headers)?;
    let etag = cache::etag(ds.content_hash(), &format!("ogcapi collection {base}"));
    let pin = pinned(&ds, &query);
    Ok(respond(
        &state,
        &headers,
        &etag,
        ds.last_modified,
        pin,
        || collection_doc(&ds, &fp, &base),
    ))
}

/// `GET /ogcapi/collections/{name}/coverage/tiles?encoding=`: one tileset per grid.
pub async fn tilesets(
    State(state): State<Arc<AppState>>,
    Segments(name): Segments<String>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let (ds, fp) = mapped(&state, &name)?;
    let enc = web_grid::encoding(&query)?;
    let base = base_url::configured(&state, &headers)?;
    let etag = cache::etag(
        ds.content_hash(),
        &format!("ogcapi tilesets {base} {}", enc.name()),
    );
    let pin = pinned(&ds, &query);
    Ok(respond(
        &state,
        &headers,
        &etag,
        ds.last_modified,
        pin,
        || {
            let here = format!("{base}/ogcapi/collections/{}/coverage/tiles", ds.name);
            let sets: Vec<Value> = TileMatrixSet::ALL
                .into_iter()
                .map(|tms| {
                    let mut t = tileset_doc(&ds, &fp, tms, enc, &base);
                    // A tilesets list carries each tileset's summary, not its limits.
                    if let Some(o) = t.as_object_mut() {
                        o.remove("tileMatrixSetLimits");
                    }
                    t
                })
                .collect();
            let alternates: Vec<Value> = ENCODINGS
                .into_iter()
                .filter(|e| *e != enc)
                .map(|e| {
                    json!({"rel": "alternate", "type": JSON, "title": e.name(),
                       "href": format!("{here}?encoding={}", e.name())})
                })
                .collect();
            let mut links = vec![link(
                "self",
                &format!("{here}?encoding={}", enc.name()),
                &ds.name,
            )];
            links.extend(alternates);
            json!({"links": links, "tilesets": sets})
        },
    ))
}

/// `GET /ogcapi/collections/{name}/coverage/tiles/{tms}?encoding=`.
pub async fn tileset(
    State(state): State<Arc<AppState>>,
    Segments((name, id)): Segments<(String, String)>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let (ds, fp) = mapped(&state, &name)?;
    let tms = grid(&id)?;
    let enc = web_grid::encoding(&query)?;
    let base = base_url::configured(&state, &headers)?;
    let etag = cache::etag(
        ds.content_hash(),
        &format!("ogcapi tileset {} {base} {}", tms.id(), enc.name()),
    );
    let pin = pinned(&ds, &query);
    Ok(respond(
        &state,
        &headers,
        &etag,
        ds.last_modified,
        pin,
        || tileset_doc(&ds, &fp, tms, enc, &base),
    ))
}

/// `GET /ogcapi/collections/{name}/coverage/tiles/{tms}/{tileMatrix}/{tileRow}/{tileCol}`:
/// the PNG tile of web_grid.rs (same bytes, headers and errors), `?encoding=`,
/// `?size=` and `?v=` as there.
pub async fn tile(
    state: State<Arc<AppState>>,
    Segments((name, id, z, row, col)): Segments<(String, String, String, String, String)>,
    params: Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let tms = grid(&id)?;
    web_grid::tile(
        state,
        Segments((name, tms.path().to_string(), z, col, format!("{row}.png"))),
        params,
        headers,
    )
    .await
}
