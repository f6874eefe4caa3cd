//! `/healthz` and `/metrics`.

use crate::serve::AppState;
use axum::extract::State;
use axum::http::{StatusCode, header};
use axum::response::IntoResponse;
use std::sync::Arc;

pub async fn healthz(State(state): State<Arc<AppState>>) -> impl IntoResponse {
    axum::Json(serde_json::json!({
        "status": "ok",
        "datasets": state.registry().datasets.len(),
    }))
}

/// `/healthz/live`: the process is up and answering (a liveness probe: restart it
/// if this fails). Says nothing about the stores.
pub async fn live() -> impl IntoResponse {
    axum::Json(serde_json::json!({ "status": "live" }))
}

/// `/healthz/ready`: every dataset's storage answers now and is still what was
/// opened (a readiness probe: route no traffic here while it fails). 503 with each
/// failing dataset's reason otherwise. Checks run at once, each within 2 s.
pub async fn ready(State(state): State<Arc<AppState>>) -> impl IntoResponse {
    let registry = state.registry();
    let checks = registry
        .datasets
        .iter()
        .map(|(name, ds)| async move { (name.clone(), ds.storage.ready().await) });
    let failing: serde_json::Map<String, serde_json::Value> =
        futures_util::future::join_all(checks)
            .await
            .into_iter()
            .filter_map(|(name, r)| r.err().map(|why| (name, why.to_string().into())))
            .collect();
    let status = if failing.is_empty() {
        StatusCode::OK
    } else {
        StatusCode::SERVICE_UNAVAILABLE
    };
    let body = if failing.is_empty() {
        serde_json::json!({ "status": "ready", "datasets": registry.datasets.len() })
    } else {
        serde_json::json!({
            "status": "not ready",
            "datasets": registry.datasets.len(),
            "error": format!("{} of {} datasets cannot be read now", failing.len(), registry.datasets.len()),
            "failing": failing,
        })
    };
    (status, axum::Json(body))
}

pub async fn metrics(State(state): State<Arc<AppState>>) -> impl IntoResponse {
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        state.metrics.render(),
    )
}
