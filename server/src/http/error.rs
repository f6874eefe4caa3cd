//! Every failure the API reports: a status and `{"error": "…"}` naming the problem.

use axum::Json;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};

#[derive(Debug, Clone)]
pub struct ApiError {
    pub status: StatusCode,
    pub message: String,
    /// Seconds for a `Retry-After` header (503s of a busy server: serve/compute/).
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
    /// The JSON body every error response carries. A message longer than
    /// [`MAX_MESSAGE_CHARS`] is cut (see [`quoted`]): a last bound for one that quotes
    /// request input without [`quoted`] (a parser's error passed through whole).
    pub fn body(&self) -> serde_json::Value {
        serde_json::json!({ "error": capped(&self.message, MAX_MESSAGE_CHARS) })
    }
}

/// Characters of request input an error message quotes (see [`quoted`]).
pub const QUOTED_CHARS: usize = 64;
/// Characters of an error message a client is sent ([`ApiError::body`]).
pub const MAX_MESSAGE_CHARS: usize = 1024;

/// Request input (a path segment, a dataset name, a query name or value) as an
/// error message quotes it: debug-quoted, so control characters are escaped, and cut
/// to its first [`QUOTED_CHARS`] characters with an ellipsis and its whole length
/// when longer, so that a 1 MB path is not echoed back (or logged) whole:
/// `"abc"`, or `"aaaa…"… (1048576 bytes)`.
pub fn quoted(input: &str) -> String {
    match input.char_indices().nth(QUOTED_CHARS) {
        None => format!("{input:?}"),
        Some((end, _)) => format!("{:?}… ({} bytes)", &input[..end], input.len()),
    }
}

/// `message`, from a parser outside this module that debug-quotes `input` whole
/// (`{input:?}`), with that quotation bounded as [`quoted`] bounds it.
pub fn requoted(message: &str, input: &str) -> String {
    message.replacen(&format!("{input:?}"), &quoted(input), 1)
}

/// `text` cut to its first `max` characters, saying how long it was.
fn capped(text: &str, max: usize) -> std::borrow::Cow<'_, str> {
    match text.char_indices().nth(max) {
        None => text.into(),
        Some((end, _)) => format!("{}… (cut: {} bytes in all)", &text[..end], text.len()).into(),
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

    #[test]
    fn quoted_input_is_bounded_and_escaped() {
        assert_eq!(quoted("N46E008"), "\"N46E008\"");
        assert_eq!(quoted("a\u{7}\r\n"), "\"a\\u{7}\\r\\n\"");
        let exact = "x".repeat(QUOTED_CHARS);
        assert_eq!(quoted(&exact), format!("{exact:?}"));
        let path = "é".repeat(1 << 19);
        let q = quoted(&path);
        assert_eq!(
            q,
            format!("{:?}… (1048576 bytes)", "é".repeat(QUOTED_CHARS))
        );
        let message = format!("unknown dataset {path:?}");
        assert_eq!(requoted(&message, &path), format!("unknown dataset {q}"));
        // Whatever a message holds, a client is sent a bounded one.
        let body = ApiError::not_found(message).body().to_string();
        assert!(
            body.len() < 2 * 4 * MAX_MESSAGE_CHARS,
            "{} bytes",
            body.len()
        );
        assert!(body.contains("bytes in all"), "{body}");
    }
}
