//! `/v1/datasets/{name}/pyramid`: the raw file with HTTP Range (being written).

use crate::serve::AppState;
use crate::serve::error::{ApiError, ApiResult};
use axum::extract::{Path, State};
use axum::response::Response;
use std::sync::Arc;

pub async fn raw(
    State(_state): State<Arc<AppState>>,
    Path(_name): Path<String>,
) -> ApiResult<Response> {
    Err(ApiError::not_found("not implemented yet"))
}
