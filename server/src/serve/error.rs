//! Every failure the API reports: a status and `{"error": "…"}` naming the problem.

use axum::Json;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};

#[derive(Debug, Clone)]
pub struct ApiError {
    pub status: StatusCode,
    pub message: String,
    /// Seconds for a `Retry-After` header (503s of a busy server: serve/compute.rs).
    pub retry_after: Option<u32>,
}

impl ApiError {
    pub fn new(status: StatusCode, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
            retry_after: None,
        }
    }

    /// 503 with `Retry-After: seconds`: the server is at its configured limit.
    pub fn busy(message: impl Into<String>, seconds: u32) -> Self {
        Self {
            retry_after: Some(seconds.max(1)),
            ..Self::unavailable(message)
        }
    }

    pub fn bad_request(message: impl Into<String>) -> Self {
        Self::new(StatusCode::BAD_REQUEST, message)
    }

    pub fn not_found(message: impl Into<String>) -> Self {
        Self::new(StatusCode::NOT_FOUND, message)
    }

    pub fn internal(message: impl Into<String>) -> Self {
        Self::new(StatusCode::INTERNAL_SERVER_ERROR, message)
    }

    pub fn unavailable(message: impl Into<String>) -> Self {
        Self::new(StatusCode::SERVICE_UNAVAILABLE, message)
    }
}

impl ApiError {
    /// The JSON body every error response carries.
    pub fn body(&self) -> serde_json::Value {
        serde_json::json!({ "error": self.message })
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = self.body();
        let mut r = (self.status, Json(body)).into_response();
        if let Some(s) = self.retry_after {
            r.headers_mut()
                .insert(axum::http::header::RETRY_AFTER, s.into());
        }
        r
    }
}

pub type ApiResult<T> = Result<T, ApiError>;

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::Level;
    use tessera_shared::range_query::{self, RangeLimits};

    /// The error bodies clients see (API.md "Errors"): one key, a message naming the
    /// input and the problem, no debug text.
    #[test]
    fn error_bodies_are_stable() {
        let limits = RangeLimits {
            max_ranges: 4,
            max_tiles: 100,
        };
        let level = Level::new(3).unwrap();
        let bodies: Vec<serde_json::Value> = [
            range_query::parse(None, level, limits),
            range_query::parse(Some("+5"), level, limits),
            range_query::parse(Some("0-64"), level, limits),
            range_query::parse(Some("0-10,5-6"), level, limits),
        ]
        .into_iter()
        .map(|r| ApiError::bad_request(r.unwrap_err().to_string()).body())
        .chain([ApiError::not_found("no such endpoint; see API.md").body()])
        .collect();
        insta::assert_snapshot!(serde_json::to_string_pretty(&bodies).unwrap());
    }
}
