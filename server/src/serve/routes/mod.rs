//! HTTP handlers, one module per group of endpoints (API.md).

pub mod base_url;
pub mod bootstrap;
pub mod cesium;
pub mod cesium_tiles3d;
pub mod contours;
pub mod coverage;
pub mod datasets;
pub mod elevation;
pub mod health;
pub mod ogc_api;
pub mod pyramid;
pub mod rendered;
pub mod tiles;
pub mod web_grid;
pub mod web_tiles;
pub mod wmts;

use super::AppState;
use super::dataset::{Dataset, RecordError, valid_name};
use crate::http::error::{ApiError, ApiResult, quoted, requoted};
use crate::web::encoding::UnknownValue;
use axum::extract::{FromRequestParts, Path};
use axum::http::request::Parts;
use bytes::Bytes;
use std::collections::HashMap;
use std::sync::Arc;
use tessera_shared::format::IndexEntry;
use tessera_shared::{Level, TileId};

/// An unknown `?encoding=` or `?nodata=`: 400, the value quoted within bounds.
impl From<UnknownValue> for ApiError {
    fn from(e: UnknownValue) -> Self {
        ApiError::bad_request(requoted(&e.to_string(), &e.value))
    }
}

/// The query string as a map; an unparseable one, or one that names a parameter
/// twice (which one would win is up to each cache and proxy), is a 400 with a JSON
/// reason (axum's own `Query` rejection would answer in plain text, and it decodes
/// leniently: `%zz` passed through as itself).
#[derive(Debug, Clone, Default)]
pub struct Params(pub HashMap<String, String>);

impl Params {
    /// Parses `name=value` pairs joined by `&` (`application/x-www-form-urlencoded`,
    /// as browsers and `URLSearchParams` write them: `+` is a space, `%XX` a byte).
    /// Refused: a `%` not followed by two hex digits, a pair with an empty name
    /// (`=5`), a name or value that is not UTF-8 once decoded, and a name given twice.
    /// Empty pairs (`a=1&&b=2`, a trailing `&`) say nothing and are skipped.
    pub fn parse(query: &str) -> Result<Self, ApiError> {
        let mut map = HashMap::new();
        for pair in query.split('&').filter(|p| !p.is_empty()) {
            let (raw_name, raw_value) = pair.split_once('=').unwrap_or((pair, ""));
            if raw_name.is_empty() {
                return Err(ApiError::bad_request(format!(
                    "query parameter {} has an empty name: want name=value pairs joined by '&'",
                    quoted(pair)
                )));
            }
            let name = form_decode(raw_name).map_err(|why| {
                ApiError::bad_request(format!("query parameter name {}: {why}", quoted(raw_name)))
            })?;
            let value = form_decode(raw_value).map_err(|why| {
                ApiError::bad_request(format!("query parameter {}: {why}", quoted(&name)))
            })?;
            if map.contains_key(&name) {
                return Err(ApiError::bad_request(format!(
                    "query parameter {} is given more than once; give it once",
                    quoted(&name)
                )));
            }
            map.insert(name, value);
        }
        Ok(Params(map))
    }
}

/// Why a form-encoded name or value does not decode ([`form_decode`]).
#[derive(Debug, thiserror::Error)]
enum FormError {
    #[error("'%' at byte {0} is not followed by two hex digits (write a '%' as %25)")]
    BadPercent(usize),
    #[error("not UTF-8 once percent-decoded")]
    NotUtf8,
}

/// One form-encoded name or value, decoded; the error says what is wrong with it.
fn form_decode(raw: &str) -> Result<String, FormError> {
    let hex = |b: u8| char::from(b).to_digit(16);
    let bytes = raw.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
            b'+' => out.push(b' '),
            b'%' => {
                let (Some(hi), Some(lo)) = (
                    bytes.get(i + 1).copied().and_then(hex),
                    bytes.get(i + 2).copied().and_then(hex),
                ) else {
                    return Err(FormError::BadPercent(i));
                };
                out.push((hi * 16 + lo) as u8);
                i += 2;
            }
            b => out.push(b),
        }
        i += 1;
    }
    String::from_utf8(out).map_err(|_| FormError::NotUtf8)
}

impl<S: Send + Sync> FromRequestParts<S> for Params {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _state: &S) -> Result<Self, ApiError> {
        Self::parse(parts.uri.query().unwrap_or(""))
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
            "invalid dataset name {}: names are letters, digits, '_', '-' or '.'",
            quoted(name)
        )));
    }
    let ds = state
        .registry()
        .get(name)
        .cloned()
        .ok_or_else(|| ApiError::not_found(format!("unknown dataset {}", quoted(name))))?;
    ds.available().map_err(|r| unavailable(&r))?;
    Ok(ds)
}

/// 503 for a dataset whose file can no longer be read as opened.
pub fn unavailable(reason: &dyn std::fmt::Display) -> ApiError {
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
                "level {} is not in dataset {:?} (levels 0-{finest})",
                quoted(raw),
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
            "tile ({}, {}) is not in level {level} (x and y are 0-{})",
            quoted(x),
            quoted(y),
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

/// `&`, `<`, `>`, `"` and `'` as entities (`quick-xml`'s escaper), for HTML (the
/// viewer's pages; TileJSON and `layer.json` attributions are shown as HTML);
/// control characters other than tab, newline and carriage return (not allowed in
/// XML 1.0) are dropped first.
pub fn xml_escape(s: &str) -> String {
    let kept: String = s
        .chars()
        .filter(|&c| !c.is_control() || matches!(c, '\t' | '\n' | '\r'))
        .collect();
    quick_xml::escape::escape(kept.as_str()).into_owned()
}

/// Whether the query pins the content with `v=<content hash>` (then responses are immutable).
pub fn pinned(ds: &Dataset, query: &HashMap<String, String>) -> bool {
    query.get("v").is_some_and(|v| v == ds.content_hash())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::web::encoding::{Encoding, NoData};

    fn refused(query: &str) -> String {
        let e = Params::parse(query).unwrap_err();
        assert_eq!(e.status, axum::http::StatusCode::BAD_REQUEST, "{query}");
        e.message
    }

    #[test]
    fn queries_decode_as_browsers_encode_them() {
        let p = Params::parse("ranges=0-15%2C32-47&v=abc&name=a+b%20c&flag&&empty=").unwrap();
        assert_eq!(p.0["ranges"], "0-15,32-47");
        assert_eq!(p.0["name"], "a b c");
        assert_eq!(p.0["flag"], "");
        assert_eq!(p.0["empty"], "");
        assert_eq!(p.0.len(), 5);
        assert!(Params::parse("").unwrap().0.is_empty());
        assert_eq!(
            Params::parse("%C3%A9t%C3%A9=%E2%9C%93").unwrap().0["été"],
            "✓"
        );
    }

    #[test]
    fn invalid_percent_encoding_and_empty_names_are_refused_naming_the_parameter() {
        let e = refused("&%zz=1");
        assert!(
            e.contains("name \"%zz\"") && e.contains("two hex digits"),
            "{e}"
        );
        let e = refused("ranges=0-3&v=ab%2");
        assert!(e.contains("parameter \"v\"") && e.contains("byte 2"), "{e}");
        let e = refused("ranges=%ff");
        assert!(e.contains("\"ranges\"") && e.contains("UTF-8"), "{e}");
        let e = refused("=5");
        assert!(e.contains("\"=5\" has an empty name"), "{e}");
        let e = refused("v=1&v=2");
        assert!(e.contains("\"v\" is given more than once"), "{e}");
        // A long name is quoted in part.
        let long = "n".repeat(10_000);
        let e = refused(&format!("{long}=1&{long}=2"));
        assert!(e.len() < 300 && e.contains("(10000 bytes)"), "{e}");
    }

    #[test]
    fn an_unknown_encoding_is_a_400_quoting_the_value_within_bounds() {
        let e = ApiError::from(Encoding::from_query(Some("webp")).unwrap_err());
        assert_eq!(e.status, axum::http::StatusCode::BAD_REQUEST);
        assert_eq!(
            e.message,
            "unknown encoding \"webp\": allowed values are terrarium, mapbox"
        );
        let long = "x".repeat(10_000);
        let e = ApiError::from(NoData::from_query(Some(&long)).unwrap_err());
        assert!(
            e.message.contains("(10000 bytes)") && e.message.ends_with("opaque, transparent"),
            "{}",
            e.message
        );
    }
}
