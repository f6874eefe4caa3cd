//! PNG height tiles (Terrarium, Terrain-RGB) and TileJSON (being written).

use crate::serve::AppState;
use crate::serve::error::{ApiError, ApiResult};
use axum::extract::{Path, State};
use axum::response::Response;
use std::sync::Arc;

pub async fn tilejson(
    State(_state): State<Arc<AppState>>,
    Path(_name): Path<String>,
) -> ApiResult<Response> {
    Err(ApiError::not_found("not implemented yet"))
}

pub async fn png(
    State(_state): State<Arc<AppState>>,
    Path((_name, _z, _x, _y)): Path<(String, String, String, String)>,
) -> ApiResult<Response> {
    Err(ApiError::not_found("not implemented yet"))
}
