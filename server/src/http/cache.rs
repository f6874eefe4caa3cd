//! Standard HTTP caching: strong ETags from the dataset's content hash (and what
//! the request asked for), `Last-Modified` from the pyramid file's modification time,
//! `304 Not Modified` (`If-None-Match`, else `If-Modified-Since`: RFC 9110 §13.1.3),
//! and `Cache-Control` that lets CDNs keep immutable data (docs/ARCHITECTURE.md#serving).
//!
//! Every cacheable response goes through [`set_headers`] and every 304 through
//! [`not_modified`] and [`not_modified_response`]; each takes the dataset's
//! [`LastModified`] (`Dataset::last_modified`) beside the ETag.

use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// When a dataset's file was last modified, to the whole second (HTTP dates have no
/// finer resolution), for `Last-Modified` and `If-Modified-Since`. Captured once when
/// the dataset is opened; [`LastModified::UNKNOWN`] where the file system gives no
/// time, and then no `Last-Modified` is sent and `If-Modified-Since` never matches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LastModified(Option<SystemTime>);

impl LastModified {
    /// No modification time known.
    pub const UNKNOWN: Self = Self(None);

    /// `t` truncated to the second; unknown for `None` or a time before 1970.
    pub fn new(t: Option<SystemTime>) -> Self {
        Self(
            t.and_then(|t| t.duration_since(UNIX_EPOCH).ok())
                .map(|d| UNIX_EPOCH + Duration::from_secs(d.as_secs())),
        )
    }

    pub fn time(self) -> Option<SystemTime> {
        self.0
    }

    /// The `Last-Modified` value (an IMF-fixdate), if known.
    pub fn header_value(self) -> Option<HeaderValue> {
        let t = self.0?;
        HeaderValue::from_str(&httpdate::fmt_http_date(t)).ok()
    }
}

/// A strong ETag for `content_hash` and a request-specific `variant`.
pub fn etag(content_hash: &str, variant: &str) -> String {
    if variant.is_empty() {
        return format!("\"{content_hash}\"");
    }
    let v = xxhash_rust::xxh3::xxh3_64(variant.as_bytes());
    format!("\"{content_hash}-{v:016x}\"")
}

/// Whether the request's validators say the client already has this response
/// (RFC 9110 §13.1.2-3, §13.2.2): `If-None-Match` lists `etag` (weak comparison, as
/// RFC 9110 requires for it; `*` matches anything) or, only when the request has no
/// `If-None-Match`, `If-Modified-Since` is a valid HTTP date not before `last_modified`.
pub fn not_modified(req: &HeaderMap, etag: &str, last_modified: LastModified) -> bool {
    if req.contains_key(header::IF_NONE_MATCH) {
        return req.get_all(header::IF_NONE_MATCH).iter().any(|v| {
            v.to_str().is_ok_and(|s| {
                s.split(',')
                    .map(str::trim)
                    .any(|t| t == "*" || t == etag || t.strip_prefix("W/") == Some(etag))
            })
        });
    }
    let Some(modified) = last_modified.time() else {
        return false;
    };
    // One valid HTTP date, else the field is ignored (§13.1.3).
    let mut all = req.get_all(header::IF_MODIFIED_SINCE).iter();
    let (Some(v), None) = (all.next(), all.next()) else {
        return false;
    };
    v.to_str()
        .ok()
        .and_then(|s| httpdate::parse_http_date(s.trim()).ok())
        .is_some_and(|since| modified <= since)
}

/// The `304` for a request whose validators match this response ([`not_modified`]),
/// or `None` when the full response must be sent.
pub fn revalidate(
    req: &HeaderMap,
    etag: &str,
    last_modified: LastModified,
    pinned: bool,
    max_age: u64,
) -> Option<Response> {
    not_modified(req, etag, last_modified)
        .then(|| not_modified_response(etag, last_modified, pinned, max_age))
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

/// Sets `ETag`, `Last-Modified` (when known) and `Cache-Control` on a response's
/// headers.
///
/// Datasets with a malformed content hash are refused at load, so an ETag is always
/// a valid header value; should one ever not be, the response goes out uncacheable
/// rather than panicking the handler.
pub fn set_headers(
    h: &mut HeaderMap,
    etag: &str,
    last_modified: LastModified,
    pinned: bool,
    max_age: u64,
) {
    if let Ok(v) = HeaderValue::from_str(etag) {
        h.insert(header::ETAG, v);
        if let Some(lm) = last_modified.header_value() {
            h.insert(header::LAST_MODIFIED, lm);
        }
        h.insert(header::CACHE_CONTROL, cache_control(pinned, max_age));
    } else {
        tracing::error!(etag = %etag.escape_default(), "ETag is not a valid header value; sending no-store");
        h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    }
}

/// A `304 Not Modified` carrying the same `ETag`, `Last-Modified` and `Cache-Control`
/// as the full response.
pub fn not_modified_response(
    etag: &str,
    last_modified: LastModified,
    pinned: bool,
    max_age: u64,
) -> Response {
    let mut r = StatusCode::NOT_MODIFIED.into_response();
    set_headers(r.headers_mut(), etag, last_modified, pinned, max_age);
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bad_etag_never_panics() {
        let mut h = HeaderMap::new();
        set_headers(&mut h, "\"abc\r\nx\"", LastModified::UNKNOWN, false, 60);
        assert!(h.get(header::ETAG).is_none());
        assert_eq!(h.get(header::CACHE_CONTROL).unwrap(), "no-store");
    }

    #[test]
    fn if_none_match_compares_strongly() {
        let e = etag("abc", "level 3 0-15");
        assert_ne!(e, etag("abc", "level 3 0-16"));
        let not_modified = |h: &HeaderMap, e: &str| not_modified(h, e, LastModified::UNKNOWN);
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

    #[test]
    fn if_modified_since_counts_only_without_if_none_match() {
        let t = UNIX_EPOCH + Duration::from_secs(1_700_000_000);
        let lm = LastModified::new(Some(t + Duration::from_millis(700)));
        assert_eq!(lm.time(), Some(t), "truncated to the second");
        assert_eq!(lm.header_value().unwrap(), "Tue, 14 Nov 2023 22:13:20 GMT");
        let e = etag("abc", "x");
        let ims = |h: &mut HeaderMap, secs: u64| {
            h.insert(
                header::IF_MODIFIED_SINCE,
                HeaderValue::from_str(&httpdate::fmt_http_date(
                    UNIX_EPOCH + Duration::from_secs(secs),
                ))
                .unwrap(),
            );
        };
        let mut h = HeaderMap::new();
        ims(&mut h, 1_700_000_000);
        assert!(not_modified(&h, &e, lm), "same second");
        ims(&mut h, 1_700_000_001);
        assert!(not_modified(&h, &e, lm), "later");
        ims(&mut h, 1_699_999_999);
        assert!(!not_modified(&h, &e, lm), "earlier: modified since");
        assert!(!not_modified(&h, &e, LastModified::UNKNOWN));
        ims(&mut h, 1_700_000_000);
        // If-None-Match present and not matching: If-Modified-Since is ignored.
        h.insert(header::IF_NONE_MATCH, HeaderValue::from_static("\"other\""));
        assert!(!not_modified(&h, &e, lm));
        h.remove(header::IF_NONE_MATCH);
        h.insert(
            header::IF_MODIFIED_SINCE,
            HeaderValue::from_static("yesterday"),
        );
        assert!(!not_modified(&h, &e, lm), "an invalid date is ignored");
    }
}
