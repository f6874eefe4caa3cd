//! Cesium terrain (DECISIONS.md "Cesium terrain", docs/ARCHITECTURE.md#derived-outputs):
//! quantized-mesh-1.0 tiles, meshed per request from the pyramid (cesium/terrain/), and
//! their `layer.json`.
//!
//! - `GET /v1/datasets/{name}/cesium/layer.json`
//! - `GET /v1/datasets/{name}/cesium/{z}/{x}/{y}.terrain` — extensions as CesiumJS
//!   asks for them in `Accept: application/vnd.quantized-mesh;extensions=a-b`.
//!
//! Which tiles exist is the dataset's [`Availability`], made once per dataset (its
//! content hash) from the pyramid's index and masks and kept here.

use super::base_url;
use super::web_grid::{Failure, failure_error, source};
use super::{Params, Segments, dataset, xml_escape};
use crate::cesium::quantized_mesh::{Extensions, encode};
use crate::cesium::terrain::availability::{
    AVAILABILITY_LEVELS, Availability, Stored, ranges_json,
};
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
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use bytes::Bytes;
use futures_util::FutureExt;
use futures_util::future::{BoxFuture, Shared};
use std::sync::{Arc, Mutex};
use tessera_shared::format::FLAG_PARTIAL;
use tessera_shared::{Level, TileId, codec};

/// The media type of quantized-mesh tiles.
pub const MEDIA_TYPE: &str = "application/vnd.quantized-mesh";

/// The dataset's terrain plan, or 404 saying why it cannot be terrain.
pub(super) fn terrain(state: &AppState, ds: &Dataset) -> ApiResult<Arc<Terrain>> {
    state
        .web
        .terrain(ds.content_hash(), || {
            Terrain::new(ds.pyramid.metadata(), state.web.config.geoid.clone())
        })
        .map_err(|e| {
            ApiError::not_found(format!("dataset {:?} has no Cesium terrain: {e}", ds.name))
        })
}

/// Availabilities made, by dataset content hash. Small (rows of runs of tiles); at
/// most [`KEPT_AVAILABILITIES`], the oldest dropped first (a reloaded dataset has a
/// new hash).
/// One dataset's availability: made once on a blocking thread, awaited by every
/// request that needs it.
type Making = Shared<BoxFuture<'static, Result<Arc<Availability>, ApiError>>>;

static AVAILABILITIES: Mutex<Vec<(u64, Making)>> = Mutex::new(Vec::new());
const KEPT_AVAILABILITIES: usize = 64;

/// The dataset's availability: made once (reading the index and the masks of its
/// partial finest tiles, off the runtime), then kept. The build starts with the
/// first request and runs to its end whatever happens to the requests: those that
/// arrive meanwhile await it, and a request after they have all gone finds it made.
/// (A flood of first requests on a fresh server used to make it once per request,
/// each on its own blocking thread: 243 threads and 1.9 CPU-s after 240 reset
/// streams.) A build that fails is forgotten, so the next request tries again.
pub(super) async fn availability(
    state: &Arc<AppState>,
    ds: &Arc<Dataset>,
    terrain: &Arc<Terrain>,
) -> ApiResult<Arc<Availability>> {
    let key = dataset_key(ds.content_hash());
    let lock = || {
        AVAILABILITIES
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    };
    let making = {
        let mut kept = lock();
        if let Some((_, m)) = kept.iter().find(|(k, _)| *k == key) {
            m.clone()
        } else {
            if kept.len() >= KEPT_AVAILABILITIES {
                drop(kept.remove(0));
            }
            let m = start_availability(state, ds, terrain);
            kept.push((key, m.clone()));
            m
        }
    };
    let made = making.await;
    if made.is_err() {
        lock().retain(|(k, _)| *k != key);
    }
    made
}

/// Starts making a dataset's availability on a blocking thread (now, not when first
/// polled).
fn start_availability(state: &Arc<AppState>, ds: &Arc<Dataset>, terrain: &Arc<Terrain>) -> Making {
    let (st, d, tr) = (state.clone(), ds.clone(), terrain.clone());
    let task = tokio::task::spawn_blocking(move || {
        let data = Pyramid {
            state: &st,
            ds: &d,
            ticket: None,
        };
        let stored = |tile: TileId| match d.pyramid.entry(tile) {
            Some(e) if e.flags & FLAG_PARTIAL != 0 => Stored::Partial,
            Some(_) => Stored::Full,
            // In a multi-resolution pyramid an absent tile may show a coarser one's
            // surface: its mask (through `source`) says.
            None if d.multi_resolution => Stored::Partial,
            None => Stored::Absent,
        };
        let started = std::time::Instant::now();
        let made = tr
            .availability(stored, &data)
            .map_err(|f| failure_error(&st, &d, "terrain availability", f));
        tracing::info!(
            dataset = %d.name,
            ms = started.elapsed().as_secs_f64() * 1e3,
            "terrain availability made"
        );
        made.map(Arc::new)
    });
    async move {
        task.await
            .map_err(|e| ApiError::internal(format!("terrain availability: {e}")))?
    }
    .boxed()
    .shared()
}

/// The pyramid as the mesher reads it: decoded tiles through the shared cache,
/// stopping when the computation's requesters are gone (when it has a ticket).
struct Pyramid<'a> {
    state: &'a AppState,
    ds: &'a Dataset,
    ticket: Option<&'a Ticket>,
}

impl LevelData for Pyramid<'_> {
    type Error = Failure;

    fn tile(&self, tile: TileId) -> Result<Option<Arc<SourceTile>>, Failure> {
        self.check()?;
        source(&self.state.web, self.ds, tile)
    }

    fn check(&self) -> Result<(), Failure> {
        match self.ticket {
            Some(t) => t.check().map_err(Failure::Stopped),
            None => Ok(()),
        }
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

/// The extensions a request asks for, among those this server makes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Asked {
    normals: bool,
    water_mask: bool,
    metadata: bool,
}

/// Media ranges of an `Accept` header a quantized-mesh tile satisfies.
const ACCEPTABLE: [&str; 4] = [
    MEDIA_TYPE,
    "application/octet-stream",
    "application/*",
    "*/*",
];

/// The extensions an `Accept` header asks for (names this server does not make are
/// ignored, as CesiumJS asks only for those `layer.json` lists), or 406 when the
/// header accepts no quantized-mesh tile at all (every range another type, or
/// `q=0`). No `Accept` accepts anything.
fn extensions(headers: &HeaderMap) -> ApiResult<Asked> {
    let mut asked = Asked::default();
    let mut any_header = false;
    let mut acceptable = false;
    for accept in headers.get_all(header::ACCEPT) {
        any_header = true;
        let Ok(v) = accept.to_str() else { continue };
        for range in v.split(',') {
            let mut parts = range.split(';').map(str::trim);
            let Some(media) = parts.next() else { continue };
            let params: Vec<&str> = parts.collect();
            let refused = params.iter().any(|p| {
                p.strip_prefix("q=")
                    .and_then(|q| q.trim().parse::<f64>().ok())
                    .is_some_and(|q| q <= 0.0)
            });
            if !refused && ACCEPTABLE.iter().any(|a| media.eq_ignore_ascii_case(a)) {
                acceptable = true;
            }
            if !media.eq_ignore_ascii_case(MEDIA_TYPE) || refused {
                continue;
            }
            for p in params {
                let Some(list) = p.strip_prefix("extensions=") else {
                    continue;
                };
                for ext in list.trim_matches('"').split('-') {
                    match ext {
                        "octvertexnormals" => asked.normals = true,
                        "watermask" => asked.water_mask = true,
                        "metadata" => asked.metadata = true,
                        _ => {}
                    }
                }
            }
        }
    }
    if any_header && !acceptable {
        return Err(ApiError::new(
            StatusCode::NOT_ACCEPTABLE,
            format!(
                "terrain tiles are {MEDIA_TYPE} (extensions octvertexnormals, watermask, metadata); the Accept header accepts none of {}",
                ACCEPTABLE.join(", ")
            ),
        ));
    }
    Ok(asked)
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
    let mut asked = extensions(&headers)?;
    // No water rule, no mask: `layer.json` does not list it then.
    asked.water_mask &= state.web.config.water.is_set();
    let pin = super::pinned(&ds, &query);
    // What the tile depends on besides the dataset: its ETag and its flight's key.
    let variant = format!(
        "terrain {}/{}/{} n{} w{} m{}",
        t.z,
        t.x,
        t.y,
        u8::from(asked.normals),
        u8::from(asked.water_mask),
        u8::from(asked.metadata)
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
    let available = availability(&state, &ds, &terrain).await?;
    if !available.contains(t) {
        return Err(ApiError::not_found(format!(
            "{t} holds no data of dataset {:?} (layer.json and the tiles' metadata list the tiles that do)",
            ds.name
        )));
    }
    let key = TerrainKey {
        dataset: dataset_key(ds.content_hash()),
        tile: t,
        normals: asked.normals,
        water_mask: asked.water_mask,
        metadata: asked.metadata,
    };
    let made = if let Some(b) = state.web.terrain_tile(&key) {
        state.compute.hit(Kind::Terrain, b, 1)?
    } else {
        let (st, d, tr) = (state.clone(), ds.clone(), terrain.clone());
        let av = available.clone();
        let flight = format!("{} {variant}", ds.content_hash());
        // One mesh per distinct tile at a time, admitted and cancellable; meshing
        // takes milliseconds to a second: keep it off the runtime.
        state
            .compute
            .run_blocking(Kind::Terrain, flight, move |ticket| {
                let b = make(&st, &d, &tr, &av, key, ticket)
                    .map_err(|f| failure_error(&st, &d, &t.to_string(), f))?;
                st.web.keep_terrain(key, b.clone());
                Ok(ticket.made(b, 1))
            })
            .await?
    };
    let len = made.bytes.len();
    let mut r = Response::new(made.body());
    let mut ctype = MEDIA_TYPE.to_string();
    let names: Vec<&str> = [
        (asked.normals, "octvertexnormals"),
        (asked.water_mask, "watermask"),
        (asked.metadata, "metadata"),
    ]
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
pub(super) fn make(
    state: &AppState,
    ds: &Dataset,
    terrain: &Terrain,
    available: &Availability,
    key: TerrainKey,
    ticket: &Ticket,
) -> Result<Bytes, Failure> {
    let data = Pyramid {
        state,
        ds,
        ticket: Some(ticket),
    };
    let plan = terrain.plan(key.tile.z, &data)?;
    let _memory = ticket
        .reserve(terrain.mesh_bytes(key.tile, &plan))
        .map_err(Failure::Stopped)?;
    let mesh = terrain.mesh_with(key.tile, &plan, &data)?;
    data.check()?;
    let water_mask = if key.water_mask {
        Some(terrain.water_mask(key.tile, &state.web.config.water, &data)?)
    } else {
        None
    };
    let ext = Extensions {
        normals: key.normals,
        water_mask,
        metadata: key
            .metadata
            .then(|| metadata_json(available, key.tile, plan.geometric_error, plan.level)),
    };
    encode(&mesh, key.tile.rect(), &terrain.ellipsoid, &ext)
        .map(Bytes::from)
        .map_err(Failure::EncodeMesh)
}

/// A tile's metadata extension: its geometric error and pyramid level, and, on a
/// tile whose zoom is a multiple of [`AVAILABILITY_LEVELS`], `available`: the tiles
/// under it for the next zooms (entry `k` for zoom `z + 1 + k`), as CesiumJS reads it.
pub fn metadata_json(
    available: &Availability,
    tile: CesiumTile,
    geometric_error: f64,
    level: Level,
) -> String {
    let mut m = serde_json::json!({
        "geometricError": geometric_error,
        "level": level.get(),
    });
    if let Some(carried) = available.carried(tile) {
        m["available"] = carried.iter().map(|r| ranges_json(r)).collect();
    }
    m.to_string()
}

/// The `layer.json` document (quantized-mesh-1.0, TileJSON 2.1.0 fields).
pub fn layer_doc(
    ds: &Dataset,
    terrain: &Terrain,
    availability: &Availability,
    water_mask: bool,
    attribution: Option<&str>,
) -> serde_json::Value {
    let m = ds.pyramid.metadata();
    // The first zooms only: the root tiles carry the next ones, and so on down.
    let available: Vec<serde_json::Value> = (0..=terrain.max_zoom.min(AVAILABILITY_LEVELS))
        .map(|z| ranges_json(&availability.ranges(z)))
        .collect();
    let mut extensions = vec!["octvertexnormals"];
    if water_mask {
        extensions.push("watermask");
    }
    extensions.push("metadata");
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
    // Across the antimeridian, east is given in −180..180 and is less than west
    // (TileJSON's convention for a box that crosses it).
    let e = if e > 180.0 { e - 360.0 } else { e };
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
        // Tiles at zooms 0, 10, 20 carry the availability of the ten zooms below them
        // (CesiumJS then asks for no tile that is not available).
        "metadataAvailability": AVAILABILITY_LEVELS,
        "extensions": extensions,
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
    let water_mask = state.web.config.water.is_set();
    let etag = cache::etag(
        ds.content_hash(),
        &format!(
            "cesium layer {:?} w{}",
            state.web.config.attribution,
            u8::from(water_mask)
        ),
    );
    if let Some(r) = cache::revalidate(&headers, &etag, ds.last_modified, pin, state.cache_max_age)
    {
        return Ok(r);
    }
    let terrain = terrain(&state, &ds)?;
    let available = availability(&state, &ds, &terrain).await?;
    let doc = layer_doc(
        &ds,
        &terrain,
        &available,
        water_mask,
        state.web.config.attribution.as_deref(),
    );
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
