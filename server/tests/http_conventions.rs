//! `tessera-server serve` end to end: what browsers and CDNs need of every endpoint
//! (API.md "HTTP conventions") — CORS and preflights, gzip/br for text and never for
//! binary, `Last-Modified` and `If-Modified-Since`. HTTP/2 and TLS are in
//! `http2_tls.rs`.
//!
//! Every test starts its own server (real process, real sockets) on the shared
//! fixtures (`serve_support`).

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use reqwest::Method;
use serve_support::{CACHEABLE, Resp, Server, fixtures, gunzip};
use std::io::Read;
use std::time::Duration;

/// What a browser sends before a cross-origin `Range` request.
fn preflight(srv: &Server, path: &str, origin: &str) -> Resp {
    srv.send(
        Method::OPTIONS,
        path,
        &[
            ("origin", origin),
            ("access-control-request-method", "GET"),
            ("access-control-request-headers", "range,if-none-match"),
        ],
    )
}

/// The comma-separated values of every `name` header, lower-cased.
fn list(r: &Resp, name: &str) -> Vec<String> {
    r.headers
        .get_all(name)
        .iter()
        .flat_map(|v| v.to_str().unwrap().split(','))
        .map(|t| t.trim().to_ascii_lowercase())
        .filter(|t| !t.is_empty())
        .collect()
}

fn has(r: &Resp, name: &str, value: &str) -> bool {
    list(r, name).iter().any(|v| v == value)
}

// ---------------------------------------------------------------------------
// CORS

#[test]
fn a_browser_preflight_gets_204_with_what_it_asked_for() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth], &[]);
    for path in CACHEABLE.iter().copied().chain(["/healthz", "/nowhere"]) {
        let r = preflight(&srv, path, "https://map.example.org");
        assert_eq!(r.status, 204, "OPTIONS {path}: {:?}", r.headers);
        assert!(r.body.is_empty(), "OPTIONS {path} has a body");
        assert_eq!(r.must("access-control-allow-origin"), "*", "{path}");
        for m in ["get", "head", "options"] {
            assert!(has(&r, "access-control-allow-methods", m), "{path}: {m}");
        }
        for h in ["range", "if-none-match", "if-modified-since", "accept"] {
            assert!(has(&r, "access-control-allow-headers", h), "{path}: {h}");
        }
        let max_age: u64 = r.must("access-control-max-age").parse().unwrap();
        assert!(max_age >= 600, "{path}: preflight cached only {max_age} s");
        for m in ["get", "head", "options"] {
            assert!(has(&r, "allow", m), "{path}: Allow lacks {m}");
        }
        // `*` is the same answer for every origin: no per-origin copies in caches.
        assert!(!has(&r, "vary", "origin"), "{path}: Vary: Origin with `*`");
    }
}

#[test]
fn responses_allow_any_origin_and_expose_the_cache_and_range_headers() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth], &[]);
    for path in CACHEABLE
        .iter()
        .copied()
        .chain(["/healthz", "/v1/datasets/nope"])
    {
        let r = srv.get_with(path, &[("origin", "https://map.example.org")]);
        assert!(r.status == 200 || r.status == 404, "{path}: {}", r.status);
        assert_eq!(r.must("access-control-allow-origin"), "*", "{path}");
        for h in ["etag", "content-length", "content-range", "last-modified"] {
            assert!(
                has(&r, "access-control-expose-headers", h),
                "{path}: {h} not exposed"
            );
        }
        assert!(!has(&r, "vary", "origin"), "{path}: Vary: Origin with `*`");
    }
    // A range request from a page: the 206 too.
    let r = srv.get_with(
        "/v1/datasets/synth/pyramid",
        &[
            ("origin", "https://map.example.org"),
            ("range", "bytes=0-63"),
        ],
    );
    assert_eq!(r.status, 206);
    assert_eq!(r.must("access-control-allow-origin"), "*");
    assert_eq!(r.body.len(), 64);
}

#[test]
fn a_list_of_origins_allows_only_those_and_varies_by_origin() {
    let f = fixtures();
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("tessera.toml");
    std::fs::write(
        &cfg,
        "cors_origin = [\"https://a.example\", \"http://b.example:8080\"]\n",
    )
    .unwrap();
    let by_flag = Server::start(
        &[&f.synth],
        &["--cors-origin", "https://a.example,http://b.example:8080"],
    );
    let by_file = Server::start(&[&f.synth], &["--config", cfg.to_str().unwrap()]);
    let path = "/v1/datasets/synth";
    for srv in [&by_flag, &by_file] {
        for origin in ["https://a.example", "http://b.example:8080"] {
            let r = srv.get_with(path, &[("origin", origin)]).expect(200);
            assert_eq!(r.must("access-control-allow-origin"), origin);
            assert!(has(&r, "vary", "origin"), "{:?}", r.headers);
            let p = preflight(srv, path, origin);
            assert_eq!(p.status, 204);
            assert_eq!(p.must("access-control-allow-origin"), origin);
            assert!(has(&p, "vary", "origin"));
        }
        for evil in ["https://evil.example", "https://a.example.evil", "null"] {
            let r = srv.get_with(path, &[("origin", evil)]).expect(200);
            assert_eq!(r.header("access-control-allow-origin"), None, "{evil}");
            assert!(has(&r, "vary", "origin"), "a cache must not reuse it for a");
            let p = preflight(srv, path, evil);
            assert_eq!(p.header("access-control-allow-origin"), None, "{evil}");
        }
    }
}

#[test]
fn cors_none_sends_no_cors_headers_but_options_still_gets_204() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth], &["--cors-origin", "none"]);
    let r = srv
        .get_with("/v1/datasets/synth", &[("origin", "https://a.example")])
        .expect(200);
    for h in [
        "access-control-allow-origin",
        "access-control-expose-headers",
    ] {
        assert_eq!(r.header(h), None, "{h}");
    }
    let p = preflight(&srv, "/v1/datasets/synth", "https://a.example");
    assert_eq!(p.status, 204);
    assert_eq!(p.header("access-control-allow-origin"), None);
    assert_eq!(p.header("access-control-allow-methods"), None);
    assert!(has(&p, "allow", "get"));
}

// ---------------------------------------------------------------------------
// Compression

fn unbrotli(b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    brotli::Decompressor::new(b, 4096)
        .read_to_end(&mut out)
        .unwrap();
    out
}

#[test]
fn text_is_compressed_with_gzip_or_br_and_decompresses_to_the_same_body() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth], &[]);
    for path in [
        "/v1/datasets/synth",
        "/v1/datasets",
        "/v1/datasets/synth/tilejson.json",
        "/metrics",
    ] {
        let plain = srv.get(path).expect(200);
        assert_eq!(plain.header("content-encoding"), None, "{path}");
        // Caches must key on Accept-Encoding even for the uncompressed copy.
        assert!(has(&plain, "vary", "accept-encoding"), "{path}");
        for (coding, decode) in [("gzip", gunzip as fn(&[u8]) -> Vec<u8>), ("br", unbrotli)] {
            let r = srv
                .get_with(path, &[("accept-encoding", coding)])
                .expect(200);
            assert_eq!(r.header("content-encoding"), Some(coding), "{path}");
            assert!(has(&r, "vary", "accept-encoding"), "{path}");
            assert_eq!(
                r.header("content-type"),
                plain.header("content-type"),
                "{path}"
            );
            assert!(
                r.body.len() < plain.body.len(),
                "{path}: {coding} {} bytes, plain {}",
                r.body.len(),
                plain.body.len()
            );
            let decoded = decode(&r.body);
            if path == "/metrics" {
                // Counters move between the two requests; the text is still the format.
                assert!(
                    String::from_utf8(decoded)
                        .unwrap()
                        .contains("tessera_http_requests_total")
                );
            } else {
                assert_eq!(decoded, plain.body, "{path}: {coding} body differs");
            }
        }
    }
}

#[test]
fn binary_responses_are_never_compressed() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth], &[]);
    let accept = ("accept-encoding", "gzip, br, deflate, zstd");
    for path in [
        "/v1/datasets/synth/levels/2/tiles?ranges=0-15",
        "/v1/datasets/synth/levels/2/errors?ranges=0-15",
        "/v1/datasets/synth/tiles/2/1/1",
        "/v1/datasets/synth/2/1/1.png",
        "/v1/datasets/synth/2/1/1.png?encoding=mapbox",
        "/v1/datasets/synth/pyramid",
    ] {
        let plain = srv.get(path).expect(200);
        let r = srv.get_with(path, &[accept]).expect(200);
        assert_eq!(r.header("content-encoding"), None, "{path} was compressed");
        assert_eq!(r.body, plain.body, "{path}");
        assert_eq!(
            r.must("content-length").parse::<usize>().unwrap(),
            r.body.len(),
            "{path}: exact Content-Length kept"
        );
        assert_eq!(r.must("etag"), plain.must("etag"), "{path}");
    }
    // Byte ranges of the raw pyramid stay byte ranges.
    let r = srv
        .get_with(
            "/v1/datasets/synth/pyramid",
            &[accept, ("range", "bytes=10-19")],
        )
        .expect(206);
    assert_eq!(r.header("content-encoding"), None);
    assert_eq!(r.must("accept-ranges"), "bytes");
    assert_eq!(r.body, std::fs::read(&f.synth).unwrap()[10..20]);
    // PNG tiles are made per request: no ranges (GDAL's /vsicurl/ then reads them whole).
    let png = srv.get("/v1/datasets/synth/2/1/1.png").expect(200);
    assert_eq!(png.must("accept-ranges"), "none");
}

#[test]
fn compressed_responses_revalidate_and_head_matches_get() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth], &[]);
    let path = "/v1/datasets/synth";
    let plain = srv.get(path).expect(200);
    let strong = plain.must("etag").to_string();
    assert!(!strong.starts_with("W/"));
    let gz = srv
        .get_with(path, &[("accept-encoding", "gzip")])
        .expect(200);
    // Another representation of the same content: a weak ETag of the same tag.
    assert_eq!(gz.must("etag"), format!("W/{strong}"));
    let r = srv
        .get_with(
            path,
            &[
                ("accept-encoding", "gzip"),
                ("if-none-match", gz.must("etag")),
            ],
        )
        .expect(304);
    assert!(r.body.is_empty());
    assert_eq!(r.must("etag"), gz.must("etag"));
    let r = srv
        .get_with(path, &[("if-none-match", &strong)])
        .expect(304);
    assert_eq!(r.must("etag"), strong);
    let head = srv.send(Method::HEAD, path, &[("accept-encoding", "gzip")]);
    assert_eq!(head.status, 200);
    assert!(head.body.is_empty());
    assert_eq!(head.must("etag"), gz.must("etag"));
    assert_eq!(head.header("content-encoding"), Some("gzip"));
    let head = srv.send(Method::HEAD, path, &[]);
    assert_eq!(head.status, 200);
    assert_eq!(head.must("etag"), strong);
    assert_eq!(head.must("content-length"), plain.body.len().to_string());
}

// ---------------------------------------------------------------------------
// Last-Modified

#[test]
fn last_modified_is_the_files_mtime_and_if_modified_since_gives_304() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth], &[]);
    let mtime = std::fs::metadata(&f.synth).unwrap().modified().unwrap();
    let want = httpdate::fmt_http_date(mtime);
    let before = httpdate::fmt_http_date(mtime - Duration::from_secs(2));
    for path in CACHEABLE {
        let r = srv.get(path).expect(200);
        assert_eq!(r.must("last-modified"), want, "{path}");
        let etag = r.must("etag").to_string();
        let r = srv
            .get_with(path, &[("if-modified-since", &want)])
            .expect(304);
        assert!(r.body.is_empty(), "{path}");
        assert_eq!(r.must("etag"), etag, "{path}");
        assert_eq!(r.must("last-modified"), want, "{path}");
        srv.get_with(path, &[("if-modified-since", &before)])
            .expect(200);
        srv.get_with(path, &[("if-modified-since", "not a date")])
            .expect(200);
        // If-None-Match wins over If-Modified-Since (RFC 9110 §13.1.3).
        srv.get_with(
            path,
            &[("if-modified-since", &want), ("if-none-match", "\"other\"")],
        )
        .expect(200);
        srv.get_with(
            path,
            &[("if-modified-since", &before), ("if-none-match", &etag)],
        )
        .expect(304);
    }
    // Uncacheable responses carry none.
    for path in ["/healthz", "/metrics", "/v1/datasets", "/v1/datasets/nope"] {
        assert_eq!(srv.get(path).header("last-modified"), None, "{path}");
    }
}
