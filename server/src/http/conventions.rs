//! What browsers and CDNs expect of every response (API.md "HTTP conventions"):
//! CORS, compression of text, `OPTIONS`, and `Accept-Ranges: none` on PNG tiles.
//!
//! The layers, outermost first, wrapped around the whole API in `app()`:
//!
//! 1. [`options`]: any `OPTIONS` request (a CORS preflight or not) gets `204 No
//!    Content` with `Allow: GET, HEAD, OPTIONS` instead of a 405.
//! 2. [`cors`]: `Access-Control-Allow-Origin` (`*`, or the request's `Origin` when it
//!    is on the configured list, with `Vary: Origin`), preflight answers, and
//!    `Access-Control-Expose-Headers` for what range and cache-aware clients read.
//! 3. [`representation`]: a compressed response's `ETag` becomes weak (`W/"…"`), as
//!    RFC 9110 §8.8.3 asks of a different representation (nginx does the same); a 304
//!    answering the weak form repeats it; images (PNG, WebP tiles) get
//!    `Accept-Ranges: none`.
//! 4. [`compression`]: gzip or br (by `Accept-Encoding`) for JSON, XML and text
//!    only; never PNGs, tile records, tile streams or the pyramid (already compressed
//!    or read by byte range), never a `206`.
//!
//! The request log and metrics (`observe`) sit inside these, so `bytes` counts the
//! body before compression, and preflights are answered before they are logged.

use axum::extract::Request;
use axum::http::{HeaderName, HeaderValue, Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use std::time::Duration;
use tower_http::compression::predicate::{Predicate, SizeAbove};
use tower_http::compression::{CompressionLayer, CompressionLevel};
use tower_http::cors::{AllowOrigin, CorsLayer, ExposeHeaders};

/// Which browser origins may read responses (`Access-Control-Allow-Origin`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CorsOrigins {
    /// `*`: any origin (no credentials are ever involved: the API is public and read-only).
    Any,
    /// No CORS headers at all (`--cors-origin none`).
    Disabled,
    /// Exactly these origins (`scheme://host[:port]`, lower-cased); responses vary by `Origin`.
    List(Vec<String>),
}

/// The methods every endpoint answers.
pub const ALLOW: &str = "GET, HEAD, OPTIONS";

/// How long a browser may cache a preflight answer, in seconds (Chromium caps it at
/// 7200, Firefox at 86400).
pub const PREFLIGHT_MAX_AGE: Duration = Duration::from_secs(86_400);

/// Request headers that web-map and globe clients (MapLibre, OpenLayers, CesiumJS,
/// GDAL's `/vsicurl/` in a browser build) send and may need a preflight for.
const ALLOW_HEADERS: [HeaderName; 8] = [
    header::ACCEPT,
    header::ACCEPT_LANGUAGE,
    header::CONTENT_TYPE,
    header::RANGE,
    header::IF_NONE_MATCH,
    header::IF_MODIFIED_SINCE,
    header::IF_RANGE,
    header::CACHE_CONTROL,
];

/// Response headers scripts may read beyond the CORS-safelisted ones (also on the
/// answers conn.rs writes itself).
pub const EXPOSE_HEADERS: [&str; 10] = [
    "etag",
    "content-length",
    "content-range",
    "last-modified",
    "accept-ranges",
    "content-encoding",
    "x-tessera-checksum",
    "x-tessera-min",
    "x-tessera-max",
    "retry-after",
];

/// The CORS layer for `origins`. With [`CorsOrigins::Disabled`] it adds nothing (a
/// preflight still gets its 204 from [`options`], without the headers a browser needs
/// to proceed).
pub fn cors(origins: &CorsOrigins) -> CorsLayer {
    let base = CorsLayer::new().vary(Vec::<HeaderName>::new());
    let allow = match origins {
        CorsOrigins::Disabled => return base,
        // `*` is the same for every origin: no `Vary: Origin`, which would make CDNs
        // keep one copy per origin.
        CorsOrigins::Any => AllowOrigin::any(),
        CorsOrigins::List(list) => AllowOrigin::list(
            list.iter()
                .map(|o| HeaderValue::from_str(o).expect("origins are checked in config")),
        ),
    };
    let layer = base
        .allow_origin(allow)
        .allow_methods([Method::GET, Method::HEAD, Method::POST, Method::OPTIONS])
        .allow_headers(ALLOW_HEADERS)
        .expose_headers(ExposeHeaders::list(
            EXPOSE_HEADERS.map(HeaderName::from_static),
        ))
        .max_age(PREFLIGHT_MAX_AGE);
    match origins {
        // The answer depends on the Origin (and a preflight's on what it asks for).
        CorsOrigins::List(_) => layer.vary([
            header::ORIGIN,
            header::ACCESS_CONTROL_REQUEST_METHOD,
            header::ACCESS_CONTROL_REQUEST_HEADERS,
        ]),
        _ => layer,
    }
}

/// Whether a content type is worth compressing: JSON, XML, `text/*`, and quantized-mesh
/// terrain (which its spec serves gzipped).
fn compressible(content_type: &str) -> bool {
    let t = content_type
        .split(';')
        .next()
        .unwrap_or("")
        .trim()
        .to_ascii_lowercase();
    t.starts_with("text/")
        || t == "application/json"
        || t == "application/xml"
        || t.ends_with("+json")
        || t.ends_with("+xml")
        // Quantized-mesh tiles are served gzipped, as the format's spec says.
        || t == "application/vnd.quantized-mesh"
        // 3D Tiles terrain's GLBs: float positions and indices, 1.25–1.9× smaller.
        || t == "model/gltf-binary"
        // Vector tiles: varint geometry, still ~1.4× smaller gzipped (API.md
        // "Contour tiles"), and served so by vector tile servers.
        || t == "application/vnd.mapbox-vector-tile"
}

/// Compress only text (see `compressible`), and only above a few hundred bytes.
#[derive(Debug, Clone, Copy)]
pub struct TextOnly;

impl Predicate for TextOnly {
    fn should_compress<B>(&self, response: &axum::http::Response<B>) -> bool
    where
        B: axum::body::HttpBody,
    {
        response.status() != StatusCode::PARTIAL_CONTENT
            && response
                .headers()
                .get(header::CONTENT_TYPE)
                .and_then(|v| v.to_str().ok())
                .is_some_and(compressible)
    }
}

/// gzip and br for text responses larger than 256 bytes, at the default (fast) levels.
pub fn compression() -> CompressionLayer<impl Predicate> {
    CompressionLayer::new()
        .no_deflate()
        .no_zstd()
        .quality(CompressionLevel::Default)
        .compress_when(SizeAbove::new(256).and(TextOnly))
}

/// Answers every `OPTIONS` request with `204` and `Allow` (a CORS preflight's
/// `Access-Control-*` headers come from the [`cors`] layer inside).
pub async fn options(req: Request, next: Next) -> Response {
    if req.method() != Method::OPTIONS {
        return next.run(req).await;
    }
    let inner = next.run(req).await;
    let mut r = StatusCode::NO_CONTENT.into_response();
    // The CORS layer answers preflights itself (200, empty body); keep its headers.
    if inner.status().is_success() {
        for (name, value) in inner.headers() {
            if name != header::CONTENT_LENGTH && name != header::CONTENT_TYPE {
                r.headers_mut().append(name.clone(), value.clone());
            }
        }
    }
    r.headers_mut()
        .insert(header::ALLOW, HeaderValue::from_static(ALLOW));
    r
}

/// `W/` before an ETag that is strong.
fn weaken(etag: &HeaderValue) -> Option<HeaderValue> {
    let s = etag.to_str().ok()?;
    if s.starts_with("W/") {
        return None;
    }
    HeaderValue::from_str(&format!("W/{s}")).ok()
}

/// Weak ETags for compressed responses (and for 304s that confirm a weak one), and
/// `Accept-Ranges: none` for image tiles (PNG, WebP), whose bytes are made per request.
pub async fn representation(req: Request, next: Next) -> Response {
    // The weak form of each tag the client holds, to answer a 304 in kind.
    let held_weak: Vec<String> = req
        .headers()
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|s| s.split(','))
        .map(str::trim)
        .filter(|t| t.starts_with("W/"))
        .map(str::to_string)
        .collect();
    let mut r = next.run(req).await;
    let status = r.status();
    let h = r.headers_mut();
    let compressed = h
        .get(header::CONTENT_ENCODING)
        .is_some_and(|v| v != "identity");
    if compressed {
        if let Some(weak) = h.get(header::ETAG).and_then(weaken) {
            h.insert(header::ETAG, weak);
        }
    } else if status == StatusCode::NOT_MODIFIED
        && let Some(weak) = h.get(header::ETAG).and_then(weaken)
        && held_weak.iter().any(|t| weak == t.as_str())
    {
        // The client revalidates the compressed representation it holds.
        h.insert(header::ETAG, weak);
        h.append(header::VARY, HeaderValue::from_static("accept-encoding"));
    }
    // Every image we send (PNG, WebP tiles) is made per request.
    let is_image = h
        .get(header::CONTENT_TYPE)
        .is_some_and(|v| v.as_bytes().starts_with(b"image/"));
    if is_image && !h.contains_key(header::ACCEPT_RANGES) {
        h.insert(header::ACCEPT_RANGES, HeaderValue::from_static("none"));
    }
    r
}

#[cfg(test)]
mod tests {
    use super::compressible;

    #[test]
    fn only_text_and_meshes_are_compressible() {
        for yes in [
            "application/vnd.quantized-mesh",
            "application/vnd.quantized-mesh;extensions=octvertexnormals-metadata",
            "application/json",
            "application/json; charset=utf-8",
            "text/plain; version=0.0.4; charset=utf-8",
            "application/xml",
            "text/xml",
            "application/vnd.oai.openapi+json",
            "Application/JSON",
        ] {
            assert!(compressible(yes), "{yes}");
        }
        for no in [
            "image/png",
            "application/octet-stream",
            "application/vnd.tessera.tiles",
            "application/vnd.tessera.tile",
            "application/vnd.tessera.pyramid",
            "multipart/byteranges; boundary=x",
            "",
        ] {
            assert!(!compressible(no), "{no}");
        }
    }
}
