//! HTTP handlers, one module per group of endpoints (API.md).

pub mod datasets;
pub mod health;
pub mod pyramid;
pub mod tiles;
pub mod web_tiles;

use super::AppState;
use super::dataset::{Dataset, valid_name};
use super::error::{ApiError, ApiResult};
use axum::extract::{FromRequestParts, Query};
use axum::http::request::Parts;
use bytes::Bytes;
use std::collections::HashMap;
use std::sync::Arc;
use tessera_shared::format::IndexEntry;
use tessera_shared::{Level, TileId};

/// The query string as a map; an unparseable one is a 400 with a JSON reason
/// (axum's own `Query` rejection would answer in plain text).
#[derive(Debug, Clone, Default)]
pub struct Params(pub HashMap<String, String>);

impl<S: Send + Sync> FromRequestParts<S> for Params {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _state: &S) -> Result<Self, ApiError> {
        Query::<HashMap<String, String>>::try_from_uri(&parts.uri)
            .map(|Query(q)| Params(q))
            .map_err(|e| {
                ApiError::bad_request(format!("malformed query string: {}", e.body_text()))
            })
    }
}

/// The dataset `name`, or 400 for a name that could never exist, 404 for an unknown one.
pub fn dataset<'a>(state: &'a AppState, name: &str) -> ApiResult<&'a Arc<Dataset>> {
    if !valid_name(name) {
        return Err(ApiError::bad_request(format!(
            "invalid dataset name {name:?}: names are letters, digits, '_', '-' or '.'"
        )));
    }
    state
        .registry
        .get(name)
        .ok_or_else(|| ApiError::not_found(format!("unknown dataset {name:?}")))
}

/// A level of `ds`, or 404 naming the valid range.
pub fn level(ds: &Dataset, raw: &str) -> ApiResult<Level> {
    let finest = ds.pyramid.geometry().finest();
    raw.parse::<u8>()
        .ok()
        .and_then(Level::new)
        .filter(|l| *l <= finest)
        .ok_or_else(|| {
            ApiError::not_found(format!(
                "level {raw:?} is not in dataset {:?} (levels 0-{finest})",
                ds.name
            ))
        })
}

/// The tile `(x, y)` of `level`, or 404 naming the valid range.
pub fn tile(level: Level, x: &str, y: &str) -> ApiResult<TileId> {
    match (x.parse::<u32>(), y.parse::<u32>()) {
        (Ok(x), Ok(y)) => TileId::new(level, x, y),
        _ => None,
    }
    .ok_or_else(|| {
        ApiError::not_found(format!(
            "tile ({x}, {y}) is not in level {level} (x and y are 0-{})",
            level.tiles_per_side() - 1
        ))
    })
}

/// A present tile's checked record: 404 when the tile lies outside the DEM, 500 (and
/// counted) when its checksum fails.
pub fn stored_record(
    state: &AppState,
    ds: &Dataset,
    tile: TileId,
) -> ApiResult<(IndexEntry, Bytes)> {
    match ds.record(tile) {
        Ok(Some(found)) => Ok(found),
        Ok(None) => Err(ApiError::not_found(format!("{tile} lies outside the DEM"))),
        Err(c) => {
            state.metrics.corrupt.inc();
            Err(ApiError::internal(format!(
                "{}: record fails its checksum",
                c.tile
            )))
        }
    }
}

/// Whether the query pins the content with `v=<content hash>` (then responses are immutable).
pub fn pinned(ds: &Dataset, query: &HashMap<String, String>) -> bool {
    query.get("v").is_some_and(|v| v == ds.content_hash())
}
