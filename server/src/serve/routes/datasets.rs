//! `/v1/datasets` and `/v1/datasets/{name}`: metadata as JSON.

use super::{Segments, dataset};
use crate::http::cache;
use crate::http::error::ApiResult;
use crate::serve::AppState;
use crate::serve::dataset::Dataset;
use axum::Json;
use axum::extract::State;
use axum::http::HeaderMap;
use axum::response::{IntoResponse, Response};
use std::sync::Arc;
use tessera_shared::api::{DatasetInfo, DatasetList};

/// The JSON description of one dataset (the contract's [`DatasetInfo`]).
pub fn describe(ds: &Dataset) -> DatasetInfo {
    let mut info = DatasetInfo::new(
        &ds.name,
        ds.pyramid.metadata(),
        ds.pyramid.header().version,
        ds.storage.size(),
    );
    info.imagery = ds.imagery.as_ref().and_then(|i| {
        let meta = i.pyramid.imagery()?;
        Some(tessera_shared::api::ImageryInfo::new(
            &ds.name,
            meta,
            i.storage.size(),
        ))
    });
    // The body from the projection library where it knows the CRS
    // (DECISIONS.md "The globe"); otherwise what `DatasetInfo::new` read from the
    // georeferencing stays.
    if let Some(crs) = ds
        .pyramid
        .metadata()
        .georef
        .as_ref()
        .and_then(crate::crs::Crs::of)
        && let Some((a, b)) = crs.body_radii()
    {
        info.body = tessera_shared::body::Body::new(a, b, crs.is_geographic());
    }
    info
}

/// [`describe`] with the links of every interface this server offers for the dataset
/// (standard grids, WMTS, OGC API, Cesium, preview, viewer: only those that apply).
/// What the document routes and the bootstrap send.
pub fn describe_served(state: &AppState, ds: &Dataset) -> DatasetInfo {
    let mut info = describe(ds);
    let offered = crate::serve::interfaces::offered(state, ds);
    crate::serve::interfaces::add_links(&mut info.links, &ds.name, &offered, state.viewer.enabled);
    info
}

/// The ETag variant of the document: its links name the viewer unless it is off.
pub fn document_variant(state: &AppState, base: &str) -> String {
    if state.viewer.enabled {
        base.to_string()
    } else {
        format!("{base} no-viewer")
    }
}

pub async fn list(State(state): State<Arc<AppState>>) -> impl IntoResponse {
    // A dataset whose file changed under the server is left out of the list (its own
    // URL answers 503 with the reason) rather than failing the whole list.
    let datasets: Vec<DatasetInfo> = state
        .registry()
        .datasets
        .values()
        .filter(|d| d.available().is_ok())
        .map(|d| describe_served(&state, d))
        .collect();
    Json(DatasetList { datasets })
}

pub async fn get_one(
    State(state): State<Arc<AppState>>,
    Segments(name): Segments<String>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    // The document names the imagery too: its hash is part of the tag.
    let variant = document_variant(
        &state,
        &ds.imagery.as_ref().map_or_else(
            || "metadata".to_string(),
            |i| format!("metadata {}", i.content_hash()),
        ),
    );
    let etag = cache::etag(ds.content_hash(), &variant);
    if cache::not_modified(&headers, &etag, ds.last_modified) {
        return Ok(cache::not_modified_response(
            &etag,
            ds.last_modified,
            false,
            state.cache_max_age,
        ));
    }
    let mut r = Json(describe_served(&state, &ds)).into_response();
    cache::set_headers(
        r.headers_mut(),
        &etag,
        ds.last_modified,
        false,
        state.cache_max_age,
    );
    Ok(r)
}
