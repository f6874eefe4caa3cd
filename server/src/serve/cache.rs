//! Standard HTTP caching: strong ETags from the dataset's content hash (and what
//! the request asked for), `304 Not Modified`, and `Cache-Control` that lets CDNs
//! keep immutable data (DESIGN §4).

use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};

/// A strong ETag for `content_hash` and a request-specific `variant`.
pub fn etag(content_hash: &str, variant: &str) -> String {
    if variant.is_empty() {
        return format!("\"{content_hash}\"");
    }
    let v = xxhash_rust::xxh3::xxh3_64(variant.as_bytes());
    format!("\"{content_hash}-{v:016x}\"")
}

/// Whether `If-None-Match` matches `etag` (strong comparison; `*` matches anything).
pub fn not_modified(req: &HeaderMap, etag: &str) -> bool {
    req.get_all(header::IF_NONE_MATCH).iter().any(|v| {
        v.to_str().is_ok_and(|s| {
            s.split(',')
                .map(str::trim)
                .any(|t| t == "*" || t == etag || t.strip_prefix("W/") == Some(etag))
        })
    })
}

/// `Cache-Control` for a response: immutable for a year when the URL pins the
/// content (`?v=<content hash>` matches), otherwise `max_age` seconds with revalidation
/// by ETag.
pub fn cache_control(pinned: bool, max_age: u64) -> HeaderValue {
    let v = if pinned {
        "public, max-age=31536000, immutable".to_string()
    } else {
        format!("public, max-age={max_age}")
    };
    HeaderValue::from_str(&v).expect("ASCII")
}

/// Sets `ETag` and `Cache-Control` on a response's headers.
///
/// Datasets with a malformed content hash are refused at load, so an ETag is always
/// a valid header value; should one ever not be, the response goes out uncacheable
/// rather than panicking the handler.
pub fn set_headers(h: &mut HeaderMap, etag: &str, pinned: bool, max_age: u64) {
    if let Ok(v) = HeaderValue::from_str(etag) {
        h.insert(header::ETAG, v);
        h.insert(header::CACHE_CONTROL, cache_control(pinned, max_age));
    } else {
        tracing::error!(etag = %etag.escape_default(), "ETag is not a valid header value; sending no-store");
        h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    }
}

/// A `304 Not Modified` carrying the same `ETag` and `Cache-Control` as the full response.
pub fn not_modified_response(etag: &str, pinned: bool, max_age: u64) -> Response {
    let mut r = StatusCode::NOT_MODIFIED.into_response();
    set_headers(r.headers_mut(), etag, pinned, max_age);
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bad_etag_never_panics() {
        let mut h = HeaderMap::new();
        set_headers(&mut h, "\"abc\r\nx\"", false, 60);
        assert!(h.get(header::ETAG).is_none());
        assert_eq!(h.get(header::CACHE_CONTROL).unwrap(), "no-store");
    }

    #[test]
    fn if_none_match_compares_strongly() {
        let e = etag("abc", "level 3 0-15");
        assert_ne!(e, etag("abc", "level 3 0-16"));
        let mut h = HeaderMap::new();
        assert!(!not_modified(&h, &e));
        h.insert(
            header::IF_NONE_MATCH,
            HeaderValue::from_str(&format!("\"zzz\", {e}")).unwrap(),
        );
        assert!(not_modified(&h, &e));
        h.insert(header::IF_NONE_MATCH, HeaderValue::from_static("\"other\""));
        assert!(!not_modified(&h, &e));
        h.insert(header::IF_NONE_MATCH, HeaderValue::from_static("*"));
        assert!(not_modified(&h, &e));
    }
}
