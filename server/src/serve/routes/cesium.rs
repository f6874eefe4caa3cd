//! Cesium terrain (DECISIONS.md "Cesium terrain", docs/ARCHITECTURE.md#derived-outputs):
//! quantized-mesh-1.0 tiles, meshed per request from the pyramid (cesium/terrain/), and
//! their `layer.json`.
//!
//! - `GET /v1/datasets/{name}/cesium/layer.json`
//! - `GET /v1/datasets/{name}/cesium/{z}/{x}/{y}.terrain` — extensions as CesiumJS
//!   asks for them in `Accept: application/vnd.quantized-mesh;extensions=a-b`.

use super::base_url;
use super::web_grid::{Failure, failure_error, source};
use super::{Params, Segments, dataset, xml_escape};
use crate::cesium::quantized_mesh::{Extensions, encode};
use crate::cesium::terrain::{LevelData, Terrain};
use crate::cesium::tiling::CesiumTile;
use crate::http::cache;
use crate::http::error::{ApiError, ApiResult, quoted};
use crate::serve::compute::{Kind, Ticket};
use crate::serve::dataset::{Dataset, RecordError};
use crate::serve::web_cache::{TerrainKey, dataset_key};
use crate::serve::{AppState, TilesServed};
use crate::web::resample::SourceTile;
use axum::Json;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, header};
use axum::response::{IntoResponse, Response};
use bytes::Bytes;
use std::sync::Arc;
use tessera_shared::{Level, TileId, codec};

/// The media type of quantized-mesh tiles.
pub const MEDIA_TYPE: &str = "application/vnd.quantized-mesh";

/// The dataset's terrain plan, or 404 saying why it cannot be terrain.
fn terrain(state: &AppState, ds: &Dataset) -> ApiResult<Arc<Terrain>> {
    state
        .web
        .terrain(ds.content_hash(), || {
            Terrain::new(ds.pyramid.metadata(), state.web.config.geoid.clone())
        })
        .map_err(|e| {
            ApiError::not_found(format!("dataset {:?} has no Cesium terrain: {e}", ds.name))
        })
}

/// The pyramid as the mesher reads it: decoded tiles through the shared cache,
/// stopping when the computation's requesters are gone.
struct Pyramid<'a> {
    state: &'a AppState,
    ds: &'a Dataset,
    ticket: &'a Ticket,
}

impl LevelData for Pyramid<'_> {
    type Error = Failure;

    fn tile(&self, tile: TileId) -> Result<Option<Arc<SourceTile>>, Failure> {
        self.check()?;
        source(self.state, self.ds, tile)
    }

    fn check(&self) -> Result<(), Failure> {
        self.ticket.check().map_err(Failure::Stopped)
    }

    fn level_error(&self, level: Level) -> Result<f64, Failure> {
        let g = self.ds.pyramid.geometry();
        let mut worst = 0.0_f64;
        for tile in g.present_tiles(level) {
            self.check()?;
            let bytes = match self.ds.record(tile) {
                Ok(Some((_, bytes))) => bytes,
                Ok(None) => continue,
                Err(RecordError::Corrupt(c)) => return Err(Failure::Corrupt(c.tile, c.first)),
                Err(RecordError::Unavailable(r)) => return Err(Failure::Unavailable(r)),
            };
            let table = codec::decode_error_table(&bytes, g.tile_log2())
                .map_err(|e| Failure::Undecodable(tile, e))?;
            worst = worst.max(f64::from(table.full_resolution_error()));
        }
        Ok(worst)
    }
}

/// The extensions an `Accept` header asks for, among those we have.
fn extensions(headers: &HeaderMap) -> (bool, bool) {
    let mut normals = false;
    let mut metadata = false;
    for accept in headers.get_all(header::ACCEPT) {
        let Ok(v) = accept.to_str() else { continue };
        for range in v.split(',') {
            let mut parts = range.split(';').map(str::trim);
            if !parts
                .next()
                .is_some_and(|t| t.eq_ignore_ascii_case(MEDIA_TYPE))
            {
                continue;
            }
            for p in parts {
                let Some(list) = p.strip_prefix("extensions=") else {
                    continue;
                };
                for ext in list.trim_matches('"').split('-') {
                    match ext {
                        "octvertexnormals" => normals = true,
                        "metadata" => metadata = true,
                        _ => {}
                    }
                }
            }
        }
    }
    (normals, metadata)
}

/// `GET /v1/datasets/{name}/cesium/{z}/{x}/{y}.terrain`.
pub async fn tile(
    State(state): State<Arc<AppState>>,
    Segments((name, z, x, y)): Segments<(String, String, String, String)>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let Some(y) = y.strip_suffix(".terrain") else {
        return Err(ApiError::not_found(
            "no such endpoint; terrain tiles are /v1/datasets/{name}/cesium/{z}/{x}/{y}.terrain (see API.md)",
        ));
    };
    let ds = dataset(&state, &name)?;
    let parsed = match (z.parse::<u8>(), x.parse::<u32>(), y.parse::<u32>()) {
        (Ok(z), Ok(x), Ok(y)) => CesiumTile::new(z, x, y),
        _ => None,
    };
    let Some(t) = parsed else {
        return Err(ApiError::not_found(format!(
            "terrain tile {}/{}/{} is not in the EPSG:4326 TMS grid (zooms 0-{}, x < 2^(z+1), y < 2^z)",
            quoted(&z),
            quoted(&x),
            quoted(y),
            crate::cesium::tiling::MAX_ZOOM
        )));
    };
    let (normals, metadata) = extensions(&headers);
    let pin = super::pinned(&ds, &query);
    // What the tile depends on besides the dataset: its ETag and its flight's key.
    let variant = format!(
        "terrain {}/{}/{} n{} m{}",
        t.z,
        t.x,
        t.y,
        u8::from(normals),
        u8::from(metadata)
    );
    let etag = cache::etag(ds.content_hash(), &variant);
    let vary = |r: &mut Response| {
        r.headers_mut()
            .append(header::VARY, HeaderValue::from_static("Accept"));
    };
    if let Some(mut r) =
        cache::revalidate(&headers, &etag, ds.last_modified, pin, state.cache_max_age)
    {
        vary(&mut r);
        return Ok(r);
    }
    let terrain = terrain(&state, &ds)?;
    if !terrain.is_available(t) {
        return Err(ApiError::not_found(format!(
            "{t} holds no data of dataset {:?} (layer.json lists the tiles that do)",
            ds.name
        )));
    }
    let key = TerrainKey {
        dataset: dataset_key(ds.content_hash()),
        tile: t,
        normals,
        metadata,
    };
    let made = if let Some(b) = state.web.terrain_tile(&key) {
        state.compute.hit(Kind::Terrain, b, 1)?
    } else {
        let (st, d, tr) = (state.clone(), ds.clone(), terrain.clone());
        let flight = format!("{} {variant}", ds.content_hash());
        // One mesh per distinct tile at a time, admitted and cancellable; meshing
        // takes milliseconds to a second: keep it off the runtime.
        state
            .compute
            .run_blocking(Kind::Terrain, flight, move |ticket| {
                let b = make(&st, &d, &tr, key, ticket)
                    .map_err(|f| failure_error(&st, &d, &t.to_string(), f))?;
                st.web.keep_terrain(key, b.clone());
                Ok(ticket.made(b, 1))
            })
            .await?
    };
    let len = made.bytes.len();
    let mut r = Response::new(made.body());
    let mut ctype = MEDIA_TYPE.to_string();
    let names: Vec<&str> = [(normals, "octvertexnormals"), (metadata, "metadata")]
        .into_iter()
        .filter_map(|(on, n)| on.then_some(n))
        .collect();
    if !names.is_empty() {
        ctype = format!("{ctype};extensions={}", names.join("-"));
    }
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_str(&ctype).expect("ascii media type"),
    );
    h.insert(header::CONTENT_LENGTH, HeaderValue::from(len));
    cache::set_headers(h, &etag, ds.last_modified, pin, state.cache_max_age);
    vary(&mut r);
    r.extensions_mut().insert(TilesServed(1));
    Ok(r)
}

/// Meshes and encodes one tile, within the memory the ticket reserves for it.
fn make(
    state: &AppState,
    ds: &Dataset,
    terrain: &Terrain,
    key: TerrainKey,
    ticket: &Ticket,
) -> Result<Bytes, Failure> {
    let data = Pyramid { state, ds, ticket };
    let plan = terrain.plan(key.tile.z, &data)?;
    let _memory = ticket
        .reserve(terrain.mesh_bytes(key.tile, &plan))
        .map_err(Failure::Stopped)?;
    let mesh = terrain.mesh_with(key.tile, &plan, &data)?;
    data.check()?;
    let ext = Extensions {
        normals: key.normals,
        metadata: key.metadata.then(|| {
            serde_json::json!({
                "geometricError": plan.geometric_error,
                "level": plan.level.get(),
            })
            .to_string()
        }),
    };
    encode(&mesh, key.tile.rect(), &terrain.ellipsoid, &ext)
        .map(Bytes::from)
        .map_err(Failure::EncodeMesh)
}

/// The `layer.json` document (quantized-mesh-1.0, TileJSON 2.1.0 fields).
pub fn layer_doc(ds: &Dataset, terrain: &Terrain, attribution: Option<&str>) -> serde_json::Value {
    let m = ds.pyramid.metadata();
    let available: Vec<serde_json::Value> = (0..=terrain.max_zoom)
        .map(|z| match terrain.available(z) {
            Some([x0, y0, x1, y1]) => serde_json::json!([
                {"startX": x0, "startY": y0, "endX": x1, "endY": y1}
            ]),
            None => serde_json::json!([]),
        })
        .collect();
    let mut meta = serde_json::json!({
        "generator": m.generator,
        "contentHash": m.content_hash,
        "verticalDatum": m.vertical_datum.name(),
        "heights": "metres above the ellipsoid",
        "ellipsoidRadii": terrain.ellipsoid.radii().to_array(),
        // What every tile keeps within (metres): CesiumJS's own estimate for a
        // 65-sample heightmap, halved per zoom.
        "levelZeroGeometricError": terrain.level_zero_error,
    });
    if let Some(w) = &terrain.datum_warning {
        meta["warning"] = serde_json::Value::String(w.clone());
    }
    let [w, s, e, n] = terrain.bounds;
    let mut doc = serde_json::json!({
        "tilejson": "2.1.0",
        "name": ds.name,
        "description": format!("{} as quantized-mesh terrain, meshed from Tessera's error tables", ds.name),
        "version": "1.0.0",
        "format": "quantized-mesh-1.0",
        "scheme": "tms",
        "projection": "EPSG:4326",
        "tiles": [format!("{{z}}/{{x}}/{{y}}.terrain?v={}", m.content_hash)],
        "minzoom": 0,
        "maxzoom": terrain.max_zoom,
        "bounds": [w, s, e, n],
        "available": available,
        // Not "metadata": CesiumJS (1.145) then expects `metadataAvailability` and
        // tile-carried availability, which this server does not make; tiles still
        // carry the metadata extension when a client asks for it in `Accept`.
        "extensions": ["octvertexnormals"],
        "metadata": meta,
    });
    if let Some(a) = attribution {
        doc["attribution"] = serde_json::Value::String(xml_escape(a));
    }
    doc
}

/// `GET /v1/datasets/{name}/cesium/layer.json`.
pub async fn layer(
    State(state): State<Arc<AppState>>,
    Segments((name,)): Segments<(String,)>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    // The base URL is not in the document (tiles are relative), but checking it
    // keeps a bad Host/X-Forwarded-Host answered as everywhere else.
    base_url::configured(&state, &headers)?;
    let pin = super::pinned(&ds, &query);
    let etag = cache::etag(
        ds.content_hash(),
        &format!("cesium layer {:?}", state.web.config.attribution),
    );
    if let Some(r) = cache::revalidate(&headers, &etag, ds.last_modified, pin, state.cache_max_age)
    {
        return Ok(r);
    }
    let terrain = terrain(&state, &ds)?;
    let doc = layer_doc(&ds, &terrain, state.web.config.attribution.as_deref());
    let mut r = Json(doc).into_response();
    cache::set_headers(
        r.headers_mut(),
        &etag,
        ds.last_modified,
        pin,
        state.cache_max_age,
    );
    Ok(r)
}
