//! `GET /v1/datasets/{name}/coverage.geojson`: where each input of the pyramid lies and
//! how fine it is (DECISIONS.md "Provenance"), as a GeoJSON FeatureCollection (RFC 7946)
//! in priority order: a Polygon per source, its outline in WGS 84 longitude/latitude,
//! with its name, CRS, ground spacing, vertical datum and the deepest pyramid level
//! its data supports. Cacheable like the dataset's other documents (its ETag is the
//! content hash's).

use super::{Segments, dataset};
use crate::http::cache;
use crate::http::error::ApiResult;
use crate::serve::AppState;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, header};
use axum::response::{IntoResponse, Response};
use serde_json::{Value, json};
use std::sync::Arc;
use tessera_shared::Metadata;

/// The FeatureCollection of a pyramid's sources (none for a pyramid that records
/// none: files before format version 3, synthetic terrain).
pub fn collection(m: &Metadata) -> Value {
    let features: Vec<Value> = m
        .sources
        .iter()
        .enumerate()
        .map(|(priority, s)| {
            json!({
                "type": "Feature",
                "geometry": if s.footprint.len() >= 4 {
                    json!({"type": "Polygon", "coordinates": [s.footprint]})
                } else {
                    Value::Null
                },
                "properties": {
                    "name": s.name,
                    "priority": priority,
                    "crs": s.crs,
                    "spacing_m": s.spacing.map(|g| [g.x, g.y]),
                    "vertical_datum": s.vertical_datum.name(),
                    "level": s.level,
                },
            })
        })
        .collect();
    json!({
        "type": "FeatureCollection",
        "features": features,
        "levels": m.levels,
        "vertical_datum": m.vertical_datum.name(),
    })
}

pub async fn get(
    State(state): State<Arc<AppState>>,
    Segments(name): Segments<String>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    let etag = cache::etag(ds.content_hash(), "coverage");
    if let Some(r) = cache::revalidate(
        &headers,
        &etag,
        ds.last_modified,
        false,
        state.cache_max_age,
    ) {
        return Ok(r);
    }
    let body = collection(ds.pyramid.metadata()).to_string();
    let mut r = body.into_response();
    r.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/geo+json"),
    );
    cache::set_headers(
        r.headers_mut(),
        &etag,
        ds.last_modified,
        false,
        state.cache_max_age,
    );
    Ok(r)
}
