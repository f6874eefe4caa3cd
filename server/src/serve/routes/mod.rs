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
use std::collections::HashMap;
use std::sync::Arc;
use tessera_shared::Level;

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

/// Whether the query pins the content with `v=<content hash>` (then responses are immutable).
pub fn pinned(ds: &Dataset, query: &HashMap<String, String>) -> bool {
    query.get("v").is_some_and(|v| v == ds.content_hash())
}
