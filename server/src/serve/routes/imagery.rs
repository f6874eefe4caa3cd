//! `GET /v1/datasets/{name}/imagery/levels/{level}/tiles?ranges=…`: a dataset's
//! imagery records (JPEG, FORMAT.md "Imagery pyramids") as a Morton-range stream,
//! framed exactly as the height records are (`tessera_shared::wire`), with the same
//! limits, ETags (from the imagery's own content hash) and caching; 404 for a dataset
//! without imagery.

use super::tiles::{Payload, stream};
use super::{Params, Segments};
use crate::http::error::{ApiError, ApiResult};
use crate::serve::AppState;
use crate::serve::dataset::Dataset;
use axum::extract::State;
use axum::http::HeaderMap;
use axum::response::Response;
use std::sync::Arc;

/// The imagery dataset of `ds`, or 404 saying it has none.
pub fn of(ds: &Dataset) -> ApiResult<Arc<Dataset>> {
    let imagery = ds.imagery.clone().ok_or_else(|| {
        ApiError::not_found(format!(
            "dataset {:?} has no imagery (build it with --imagery)",
            ds.name
        ))
    })?;
    imagery.available().map_err(|r| super::unavailable(&r))?;
    Ok(imagery)
}

pub async fn ranges(
    State(state): State<Arc<AppState>>,
    Segments((name, level)): Segments<(String, String)>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    stream(&state, &name, &level, &query, &headers, Payload::Imagery).await
}
