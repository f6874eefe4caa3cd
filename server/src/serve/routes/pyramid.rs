//! `GET /v1/datasets/{name}/pyramid`: the raw pyramid file, with HTTP byte ranges
//! (RFC 9110 §14), so a CDN or a client can read headers, indices and records
//! directly (FORMAT.md).
//!
//! Every body is made of `Bytes` views of the memory-mapped file (plus small part
//! headers for `multipart/byteranges`), never copies, and its exact length is sent
//! as `Content-Length`.
//!
//! - No `Range` (or one that does not parse, names another unit, comes with a
//!   method other than GET, or is outvoted by `If-Range`): 200 with the whole file.
//! - One satisfiable range: 206 with `Content-Range`.
//! - Several satisfiable ranges: 206 `multipart/byteranges`, the parts in the order
//!   requested (overlapping or touching ranges are first sorted and merged; ranges
//!   that lie wholly past the end are dropped; if only one range is left it is sent
//!   as a single-part 206). A multipart body that would be larger than the file
//!   (many tiny ranges: part headers outweigh the bytes) is replaced by a 200 with
//!   the whole file, so no request gets more bytes than the file has.
//! - No satisfiable range, or more than [`MAX_RANGES`] range-specs in the header:
//!   416 with `Content-Range: bytes */size` and a JSON reason.
//! - `If-Range` honours the `Range` only when it carries our strong ETag; any other
//!   value (another or weak ETag, or an HTTP date: our `Last-Modified` is a weak
//!   validator, one-second resolution, RFC 9110 §8.8.2.2) gets the full 200.
//! - `If-None-Match` matching our ETag: 304 (checked before any range).

use super::{Params, Segments, dataset, pinned};
use crate::http::cache;
use crate::http::cache::LastModified;
use crate::http::error::{ApiError, ApiResult};
use crate::http::range::{self, ByteRange, MAX_RANGES, RangeRequest};
use crate::serve::AppState;
use crate::storage::Storage;
use axum::body::Body;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, Method, StatusCode, header};
use axum::response::{IntoResponse, Response};
use bytes::Bytes;
use std::convert::Infallible;
use std::sync::Arc;

/// Media type of a pyramid file.
pub const CONTENT_TYPE: &str = "application/vnd.tessera.pyramid";

/// The `Range` header's value, if the request carries exactly one readable one.
fn range_header(headers: &HeaderMap) -> Option<&str> {
    let mut all = headers.get_all(header::RANGE).iter();
    let first = all.next()?;
    if all.next().is_some() {
        return None;
    }
    first.to_str().ok()
}

/// Whether `If-Range` (if present) lets the `Range` header apply: only an exact,
/// strong match of our ETag does.
fn if_range_allows(headers: &HeaderMap, etag: &str) -> bool {
    let mut all = headers.get_all(header::IF_RANGE).iter();
    match (all.next(), all.next()) {
        (None, _) => true,
        (Some(v), None) => v.to_str().is_ok_and(|s| s.trim() == etag),
        (Some(_), Some(_)) => false,
    }
}

/// Headers every non-error response carries.
fn common_headers(h: &mut HeaderMap, etag: &str, lm: LastModified, pin: bool, max_age: u64) {
    h.insert(header::ACCEPT_RANGES, HeaderValue::from_static("bytes"));
    cache::set_headers(h, etag, lm, pin, max_age);
}

async fn slice(storage: &dyn Storage, r: ByteRange) -> ApiResult<Bytes> {
    storage
        .read(r.start, r.byte_count())
        .await
        // The file changed under the server, or the object store is down (503 for
        // the dataset), never a crash.
        .map_err(|e| super::unavailable(&format!("cannot read the pyramid file: {e}")))
}

fn unsatisfiable(size: u64, message: String) -> Response {
    let mut r = ApiError::new(StatusCode::RANGE_NOT_SATISFIABLE, message).into_response();
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_RANGE,
        HeaderValue::from_str(&format!("bytes */{size}")).expect("ASCII"),
    );
    h.insert(header::ACCEPT_RANGES, HeaderValue::from_static("bytes"));
    r
}

/// A `multipart/byteranges` boundary: fixed for a given file and request, so equal
/// requests get equal bodies, and long and random-looking enough not to occur in
/// the file.
fn boundary(etag: &str, ranges: &[ByteRange]) -> String {
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    h.update(etag.as_bytes());
    for r in ranges {
        h.update(&r.start.to_le_bytes());
        h.update(&r.end.to_le_bytes());
    }
    format!("tessera-byteranges-{:016x}", h.digest())
}

/// The chunks of a `multipart/byteranges` body (RFC 9110 §14.6).
async fn multipart(
    storage: &dyn Storage,
    ranges: &[ByteRange],
    boundary: &str,
) -> ApiResult<Vec<Bytes>> {
    let size = storage.size();
    let mut chunks = Vec::with_capacity(2 * ranges.len() + 1);
    for (i, &r) in ranges.iter().enumerate() {
        let sep = if i == 0 { "" } else { "\r\n" };
        chunks.push(Bytes::from(format!(
            "{sep}--{boundary}\r\nContent-Type: {CONTENT_TYPE}\r\nContent-Range: {}\r\n\r\n",
            r.content_range(size)
        )));
        chunks.push(slice(storage, r).await?);
    }
    chunks.push(Bytes::from(format!("\r\n--{boundary}--\r\n")));
    Ok(chunks)
}

/// The length of [`multipart`]'s body, computed without reading the file.
fn multipart_len(size: u64, ranges: &[ByteRange], boundary: &str) -> u64 {
    let mut len = 0u64;
    for (i, &r) in ranges.iter().enumerate() {
        let sep = if i == 0 { 0 } else { 2 };
        let head = format!(
            "--{boundary}\r\nContent-Type: {CONTENT_TYPE}\r\nContent-Range: {}\r\n\r\n",
            r.content_range(size)
        );
        len += sep + head.len() as u64 + r.byte_count();
    }
    len + format!("\r\n--{boundary}--\r\n").len() as u64
}

/// `GET /v1/datasets/{name}/pyramid`: see the module documentation.
pub async fn raw(
    State(state): State<Arc<AppState>>,
    Segments(name): Segments<String>,
    Params(query): Params,
    method: Method,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    let pin = pinned(&ds, &query);
    let etag = cache::etag(ds.content_hash(), "pyramid");
    let max_age = state.cache_max_age;
    if cache::not_modified(&headers, &etag, ds.last_modified) {
        let mut r = StatusCode::NOT_MODIFIED.into_response();
        common_headers(r.headers_mut(), &etag, ds.last_modified, pin, max_age);
        return Ok(r);
    }
    let storage = ds.storage.as_ref();
    let size = storage.size();
    // RFC 9110 §14.2: range handling is defined for GET only (HEAD gets the 200 headers).
    let request = match range_header(&headers) {
        Some(v) if method == Method::GET && if_range_allows(&headers, &etag) => {
            range::parse(v, size)
        }
        _ => RangeRequest::Full,
    };
    let (status, body, len, content_type, content_range) = match request {
        RangeRequest::Full => {
            let whole = ByteRange {
                start: 0,
                end: size.saturating_sub(1),
            };
            let bytes = if size == 0 {
                Bytes::new()
            } else {
                slice(storage, whole).await?
            };
            (StatusCode::OK, Body::from(bytes), size, None, None)
        }
        RangeRequest::Partial(ranges) if ranges.len() == 1 => {
            let r = ranges[0];
            let bytes = slice(storage, r).await?;
            (
                StatusCode::PARTIAL_CONTENT,
                Body::from(bytes),
                r.byte_count(),
                None,
                Some(r.content_range(size)),
            )
        }
        RangeRequest::Partial(ranges)
            if multipart_len(size, &ranges, &boundary(&etag, &ranges)) > size =>
        {
            let whole = ByteRange {
                start: 0,
                end: size.saturating_sub(1),
            };
            (
                StatusCode::OK,
                Body::from(slice(storage, whole).await?),
                size,
                None,
                None,
            )
        }
        RangeRequest::Partial(ranges) => {
            let b = boundary(&etag, &ranges);
            let chunks = multipart(storage, &ranges, &b).await?;
            let len: u64 = chunks.iter().map(|c| c.len() as u64).sum();
            let body = Body::from_stream(futures_util::stream::iter(
                chunks.into_iter().map(Ok::<_, Infallible>),
            ));
            (
                StatusCode::PARTIAL_CONTENT,
                body,
                len,
                Some(format!("multipart/byteranges; boundary={b}")),
                None,
            )
        }
        RangeRequest::Unsatisfiable => {
            return Ok(unsatisfiable(
                size,
                format!("no requested byte range starts inside the file ({size} bytes)"),
            ));
        }
        RangeRequest::TooMany(n) => {
            return Ok(unsatisfiable(
                size,
                format!("{n} byte ranges requested; at most {MAX_RANGES} per request"),
            ));
        }
    };
    let mut r = Response::new(body);
    *r.status_mut() = status;
    let h = r.headers_mut();
    let content_type = match content_type {
        Some(t) => HeaderValue::from_str(&t).expect("ASCII"),
        None => HeaderValue::from_static(CONTENT_TYPE),
    };
    h.insert(header::CONTENT_TYPE, content_type);
    h.insert(header::CONTENT_LENGTH, HeaderValue::from(len));
    if let Some(cr) = content_range {
        h.insert(
            header::CONTENT_RANGE,
            HeaderValue::from_str(&cr).expect("ASCII"),
        );
    }
    common_headers(h, &etag, ds.last_modified, pin, max_age);
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug)]
    struct Mem(Bytes);

    impl Storage for Mem {
        fn size(&self) -> u64 {
            self.0.len() as u64
        }

        fn slice(&self, offset: u64, len: u64) -> std::io::Result<Bytes> {
            Ok(self.0.slice(offset as usize..(offset + len) as usize))
        }

        fn check_unchanged(&self) -> Result<(), crate::storage::StorageUnavailable> {
            Ok(())
        }

        fn label(&self) -> String {
            "memory".into()
        }
    }

    #[test]
    fn multipart_body_is_well_formed() {
        let s = Mem(Bytes::from_static(b"0123456789"));
        let ranges = [
            ByteRange { start: 8, end: 9 },
            ByteRange { start: 0, end: 2 },
        ];
        let b = boundary("\"e\"", &ranges);
        assert_ne!(b, boundary("\"e\"", &ranges[..1]));
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        let body: Vec<u8> = rt.block_on(multipart(&s, &ranges, &b)).unwrap().concat();
        assert_eq!(multipart_len(10, &ranges, &b), body.len() as u64);
        let want = format!(
            "--{b}\r\nContent-Type: {CONTENT_TYPE}\r\nContent-Range: bytes 8-9/10\r\n\r\n89\r\n\
             --{b}\r\nContent-Type: {CONTENT_TYPE}\r\nContent-Range: bytes 0-2/10\r\n\r\n012\r\n\
             --{b}--\r\n"
        );
        assert_eq!(String::from_utf8(body).unwrap(), want);
    }

    #[test]
    fn if_range_needs_our_strong_etag() {
        let etag = "\"abc-0123\"";
        let mut h = HeaderMap::new();
        assert!(if_range_allows(&h, etag));
        h.insert(header::IF_RANGE, HeaderValue::from_static("\"abc-0123\""));
        assert!(if_range_allows(&h, etag));
        for other in [
            "\"other\"",
            "W/\"abc-0123\"",
            "Sat, 01 Jan 2000 00:00:00 GMT",
        ] {
            h.insert(header::IF_RANGE, HeaderValue::from_static(other));
            assert!(!if_range_allows(&h, etag), "{other}");
        }
    }
}
