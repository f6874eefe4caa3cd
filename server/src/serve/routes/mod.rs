//! HTTP handlers, one module per group of endpoints (API.md).

pub mod bootstrap;
pub mod cesium;
pub mod datasets;
pub mod health;
pub mod imagery;
pub mod ogc_api;
pub mod pyramid;
pub mod tiles;
pub mod web_grid;
pub mod web_tiles;
pub mod wmts;

use super::AppState;
use super::dataset::{Dataset, RecordError, valid_name};
use super::error::{ApiError, ApiResult};
use axum::extract::{FromRequestParts, Path, Query};
use axum::http::request::Parts;
use bytes::Bytes;
use std::collections::HashMap;
use std::sync::Arc;
use tessera_shared::format::IndexEntry;
use tessera_shared::{Level, TileId};

/// The query string as a map; an unparseable one, or one that names a parameter
/// twice (which one would win is up to each cache and proxy), is a 400 with a JSON
/// reason (axum's own `Query` rejection would answer in plain text).
#[derive(Debug, Clone, Default)]
pub struct Params(pub HashMap<String, String>);

impl<S: Send + Sync> FromRequestParts<S> for Params {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _state: &S) -> Result<Self, ApiError> {
        let Query(pairs) = Query::<Vec<(String, String)>>::try_from_uri(&parts.uri).map_err(
            |_| {
                ApiError::bad_request(
                    "malformed query string: want name=value pairs joined by '&', percent-encoded UTF-8",
                )
            },
        )?;
        let mut map = HashMap::with_capacity(pairs.len());
        for (k, v) in pairs {
            if map.contains_key(&k) {
                return Err(ApiError::bad_request(format!(
                    "query parameter {k:?} is given more than once; give it once"
                )));
            }
            map.insert(k, v);
        }
        Ok(Params(map))
    }
}

/// Path parameters, with a JSON 400 naming the problem when a segment does not
/// decode (axum's own `Path` rejection is plain text and quotes the raw bytes).
#[derive(Debug)]
pub struct Segments<T>(pub T);

impl<S: Send + Sync, T> FromRequestParts<S> for Segments<T>
where
    T: serde::de::DeserializeOwned + Send,
{
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, ApiError> {
        use axum::extract::path::ErrorKind;
        use axum::extract::rejection::PathRejection;
        match Path::<T>::from_request_parts(parts, state).await {
            Ok(Path(t)) => Ok(Segments(t)),
            Err(PathRejection::FailedToDeserializePathParams(e)) => {
                Err(ApiError::bad_request(match e.kind() {
                    ErrorKind::InvalidUtf8InPathParam { key } => {
                        format!("path segment {{{key}}} is not UTF-8 once percent-decoded")
                    }
                    _ => "malformed path: a segment does not decode".to_string(),
                }))
            }
            Err(_) => Err(ApiError::bad_request("malformed path")),
        }
    }
}

/// The dataset `name`, or 400 for a name that could never exist, 404 for an unknown
/// one, 503 for one whose file changed under the server.
pub fn dataset(state: &AppState, name: &str) -> ApiResult<Arc<Dataset>> {
    if !valid_name(name) {
        return Err(ApiError::bad_request(format!(
            "invalid dataset name {name:?}: names are letters, digits, '_', '-' or '.'"
        )));
    }
    let ds = state
        .registry()
        .get(name)
        .cloned()
        .ok_or_else(|| ApiError::not_found(format!("unknown dataset {name:?}")))?;
    ds.available().map_err(|r| unavailable(&r))?;
    Ok(ds)
}

/// 503 for a dataset whose file can no longer be read as opened.
pub fn unavailable(reason: &str) -> ApiError {
    tracing::warn!(%reason, "dataset unavailable");
    ApiError::unavailable(format!(
        "{reason}; replace pyramid files by renaming a complete new file over the old one, then send SIGHUP (API.md)"
    ))
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

/// A present tile's checked record: 404 when the tile is absent (outside the DEM, or
/// wholly no-data), 500 (and counted) when its checksum fails.
pub async fn stored_record(
    state: &AppState,
    ds: &Dataset,
    tile: TileId,
) -> ApiResult<(IndexEntry, Bytes)> {
    match ds.record_async(tile).await {
        Ok(Some(found)) => Ok(found),
        Ok(None) => Err(ApiError::not_found(format!(
            "{tile} is absent: it lies outside the DEM or holds no data"
        ))),
        Err(RecordError::Corrupt(c)) => {
            state.metrics.corrupt_read(c.first);
            Err(ApiError::internal(format!(
                "{}: record fails its checksum",
                c.tile
            )))
        }
        Err(RecordError::Unavailable(reason)) => Err(unavailable(&reason)),
    }
}

/// `&`, `<`, `>`, `"` and `'` as entities, for XML (WMTS) and HTML (TileJSON
/// attributions are shown as HTML); control characters other than tab,
/// newline and carriage return (not allowed in XML 1.0) are dropped.
pub fn xml_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            '\t' | '\n' | '\r' => out.push(c),
            c if c.is_control() => {}
            c => out.push(c),
        }
    }
    out
}

/// Whether the query pins the content with `v=<content hash>` (then responses are immutable).
pub fn pinned(ds: &Dataset, query: &HashMap<String, String>) -> bool {
    query.get("v").is_some_and(|v| v == ds.content_hash())
}
