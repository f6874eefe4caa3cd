//! Cesium terrain as 3D Tiles 1.1 (DECISIONS.md "3D Tiles terrain"), for CesiumJS's
//! `Cesium3DTilesTerrainProvider` (cesium/tiles3d/):
//!
//! - `GET /v1/datasets/{name}/3dtiles/tileset.json`
//! - `GET /v1/datasets/{name}/3dtiles/{root}/{level}/{x}/{y}.subtree` — a subtree
//!   file, for a tile whose level is a multiple of the subtree levels;
//! - `GET /v1/datasets/{name}/3dtiles/{root}/{level}/{x}/{y}.glb` — a tile;
//!
//! where `{root}` is 0 (west) or 1 (east) and `{level}/{x}/{y}` the implicit tile of
//! that root (`y` from the south). Tiles are the quantized-mesh tiles with normals,
//! from the same cache and made the same way (routes/cesium.rs), read back and
//! re-encoded; which exist is the same availability.

use super::cesium::{availability, make, terrain};
use super::web_grid::failure_error;
use super::{Params, Segments, base_url, dataset};
use crate::cesium::terrain::Terrain;
use crate::cesium::terrain::availability::Availability;
use crate::cesium::tiles3d::reader::QuantizedTile;
use crate::cesium::tiles3d::subtree::{SubtreeAvailability, TileBounds};
use crate::cesium::tiles3d::tileset::Tileset;
use crate::cesium::tiles3d::{ImplicitTile, SUBTREE_LEVELS, glb};
use crate::cesium::tiling::MAX_ZOOM;
use crate::http::cache;
use crate::http::error::{ApiError, ApiResult, quoted};
use crate::serve::compute::{Kind, Ticket};
use crate::serve::dataset::Dataset;
use crate::serve::web_cache::{TerrainKey, dataset_key};
use crate::serve::{AppState, TilesServed};
use axum::Json;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, header};
use axum::response::{IntoResponse, Response};
use bytes::Bytes;
use std::sync::Arc;

/// The media type of the tiles.
pub const GLB_MEDIA_TYPE: &str = "model/gltf-binary";
/// Subtree files have none of their own.
pub const SUBTREE_MEDIA_TYPE: &str = "application/octet-stream";

/// `GET /v1/datasets/{name}/3dtiles/tileset.json`.
pub async fn tileset(
    State(state): State<Arc<AppState>>,
    Segments((name,)): Segments<(String,)>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    base_url::configured(&state, &headers)?;
    let pin = super::pinned(&ds, &query);
    let etag = cache::etag(ds.content_hash(), "3dtiles tileset");
    if let Some(r) = cache::revalidate(&headers, &etag, ds.last_modified, pin, state.cache_max_age)
    {
        return Ok(r);
    }
    let terrain = terrain(&state, &ds)?;
    let available = availability(&state, &ds, &terrain).await?;
    let m = ds.pyramid.metadata();
    // Heights above the ellipsoid: the data's, sea level, and the geoid's −107..+86 m.
    let heights = [m.min_height.min(0.0) - 110.0, m.max_height.max(0.0) + 90.0];
    let query = format!("?v={}", m.content_hash);
    let doc = Tileset {
        available_levels: available.max_zoom() + 1,
        level_zero_error: terrain.level_zero_error,
        heights,
        query: &query,
        version: &m.content_hash,
    }
    .json();
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

/// What a request names: a tile's GLB or the subtree file rooted at it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Asked {
    Glb,
    Subtree,
}

/// `GET /v1/datasets/{name}/3dtiles/{root}/{level}/{x}/{y}.glb` and `….subtree`.
pub async fn tile(
    State(state): State<Arc<AppState>>,
    Segments((name, root, z, x, y)): Segments<(String, String, String, String, String)>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let (asked, y) = if let Some(y) = y.strip_suffix(".glb") {
        (Asked::Glb, y)
    } else if let Some(y) = y.strip_suffix(".subtree") {
        (Asked::Subtree, y)
    } else {
        return Err(ApiError::not_found(
            "no such endpoint; 3D Tiles terrain is /v1/datasets/{name}/3dtiles/{root}/{level}/{x}/{y}.glb or .subtree (see API.md)",
        ));
    };
    let ds = dataset(&state, &name)?;
    let parsed = match (
        root.parse::<u8>(),
        z.parse::<u8>(),
        x.parse::<u32>(),
        y.parse::<u32>(),
    ) {
        (Ok(r), Ok(z), Ok(x), Ok(y)) => ImplicitTile::new(r, z, x, y),
        _ => None,
    };
    let Some(t) = parsed else {
        return Err(ApiError::not_found(format!(
            "3D Tiles tile {}/{}/{}/{} is not in the two implicit quadtrees (root 0 or 1, levels 0-{MAX_ZOOM}, x and y < 2^level)",
            quoted(&root),
            quoted(&z),
            quoted(&x),
            quoted(y),
        )));
    };
    if asked == Asked::Subtree && !t.roots_subtree() {
        return Err(ApiError::not_found(format!(
            "subtrees are rooted at levels that are multiples of {SUBTREE_LEVELS}; {t} is not one"
        )));
    }
    let pin = super::pinned(&ds, &query);
    let variant = format!("3dtiles {:?} {}/{}/{}/{}", asked, t.root, t.level, t.x, t.y);
    let etag = cache::etag(ds.content_hash(), &variant);
    if let Some(r) = cache::revalidate(&headers, &etag, ds.last_modified, pin, state.cache_max_age)
    {
        return Ok(r);
    }
    let terrain = terrain(&state, &ds)?;
    let available = availability(&state, &ds, &terrain).await?;
    if !available.contains(t.cesium()) {
        let what = match asked {
            Asked::Glb => "it",
            Asked::Subtree => "the subtree rooted at it",
        };
        return Err(ApiError::not_found(format!(
            "{t} holds no data of dataset {:?}, so {what} does not exist (the subtrees list the tiles that do)",
            ds.name
        )));
    }
    let (st, d, tr, av) = (
        state.clone(),
        ds.clone(),
        terrain.clone(),
        available.clone(),
    );
    let flight = format!("{} {variant}", ds.content_hash());
    let made = state
        .compute
        .run_blocking(Kind::Terrain, flight, move |ticket| {
            let bytes = match asked {
                Asked::Glb => {
                    let q = quantized(&st, &d, &tr, &av, t, ticket)?;
                    glb::encode(&q, t.cesium().rect(), &tr.ellipsoid)
                }
                Asked::Subtree => {
                    let a = SubtreeAvailability::of(t, SUBTREE_LEVELS, |i| av.contains(i.cesium()));
                    let mut bounds = Vec::new();
                    for i in a.available_tiles() {
                        bounds.push(TileBounds::of(&quantized(&st, &d, &tr, &av, i, ticket)?));
                    }
                    a.encode(&bounds)
                }
            };
            Ok(ticket.made(Bytes::from(bytes), 1))
        })
        .await?;
    let len = made.bytes.len();
    let mut r = Response::new(made.body());
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(match asked {
            Asked::Glb => GLB_MEDIA_TYPE,
            Asked::Subtree => SUBTREE_MEDIA_TYPE,
        }),
    );
    h.insert(header::CONTENT_LENGTH, HeaderValue::from(len));
    cache::set_headers(h, &etag, ds.last_modified, pin, state.cache_max_age);
    r.extensions_mut().insert(TilesServed(1));
    Ok(r)
}

/// The quantized-mesh tile (with normals) of `t`, read back: from the terrain cache
/// the quantized-mesh route shares, or made as it makes it and kept there.
fn quantized(
    state: &AppState,
    ds: &Dataset,
    terrain: &Terrain,
    available: &Availability,
    t: ImplicitTile,
    ticket: &Ticket,
) -> Result<QuantizedTile, ApiError> {
    let key = TerrainKey {
        dataset: dataset_key(ds.content_hash()),
        tile: t.cesium(),
        normals: true,
        water_mask: false,
        metadata: false,
    };
    let bytes = if let Some(b) = state.web.terrain_tile(&key) {
        b
    } else {
        let b = make(state, ds, terrain, available, key, ticket)
            .map_err(|f| failure_error(state, ds, &key.tile.to_string(), f))?;
        state.web.keep_terrain(key, b.clone());
        b
    };
    QuantizedTile::decode(&bytes).map_err(|e| {
        ApiError::internal(format!(
            "{}: the quantized-mesh tile does not read back: {e}",
            key.tile
        ))
    })
}
