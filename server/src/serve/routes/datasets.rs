//! `/v1/datasets` and `/v1/datasets/{name}`: metadata as JSON.

use super::{Segments, dataset};
use crate::serve::dataset::Dataset;
use crate::serve::error::ApiResult;
use crate::serve::{AppState, cache};
use axum::Json;
use axum::extract::State;
use axum::http::HeaderMap;
use axum::response::{IntoResponse, Response};
use std::sync::Arc;

/// The JSON description of one dataset.
pub fn describe(ds: &Dataset) -> serde_json::Value {
    let m = ds.pyramid.metadata();
    let base = format!("/v1/datasets/{}", ds.name);
    serde_json::json!({
        "name": ds.name,
        "width": m.width,
        "height": m.height,
        "tile_size": m.tile_size,
        "levels": m.levels,
        "finest_level": m.levels - 1,
        "min_height": m.min_height,
        "max_height": m.max_height,
        "quantization": m.quantization,
        "nodata_count": m.nodata_count,
        "nodata_fill": m.nodata_fill,
        "crs": m.georef.as_ref().and_then(tessera_shared::GeoRef::crs),
        "extent": m.georef.as_ref().map(|g| g.extent(m.width, m.height)),
        "georef": m.georef,
        "source": m.source,
        "content_hash": m.content_hash,
        "bytes": ds.storage.size(),
        "links": {
            "self": base,
            "tilejson": format!("{base}/tilejson.json"),
            "pyramid": format!("{base}/pyramid"),
            "tiles": format!("{base}/levels/{{level}}/tiles?ranges={{ranges}}"),
            "errors": format!("{base}/levels/{{level}}/errors?ranges={{ranges}}"),
            "tile": format!("{base}/tiles/{{level}}/{{x}}/{{y}}"),
            "png": format!("{base}/{{z}}/{{x}}/{{y}}.png?encoding=terrarium"),
        },
    })
}

pub async fn list(State(state): State<Arc<AppState>>) -> impl IntoResponse {
    // A dataset whose file changed under the server is left out of the list (its own
    // URL answers 503 with the reason) rather than failing the whole list.
    let all: Vec<serde_json::Value> = state
        .registry()
        .datasets
        .values()
        .filter(|d| d.available().is_ok())
        .map(|d| describe(d))
        .collect();
    Json(serde_json::json!({ "datasets": all }))
}

pub async fn get_one(
    State(state): State<Arc<AppState>>,
    Segments(name): Segments<String>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    let etag = cache::etag(ds.content_hash(), "metadata");
    if cache::not_modified(&headers, &etag) {
        return Ok(cache::not_modified_response(
            &etag,
            false,
            state.cache_max_age,
        ));
    }
    let mut r = Json(describe(&ds)).into_response();
    cache::set_headers(r.headers_mut(), &etag, false, state.cache_max_age);
    Ok(r)
}
