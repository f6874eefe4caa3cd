//! Serving under abuse (DECISIONS.md "Reliability", RELIABILITY.md): what a hostile or
//! careless client or operator asks of a real `tessera-server serve` — range
//! amplification, reflected Host headers, bytes that are not UTF-8, sloppy queries,
//! corrupt records read again and again, zero limits, logs off a terminal — and what must
//! survive.
//!
//! No test measures time: deadlines are generous bounds on "eventually", many times
//! the configured timeout.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{
    Server, bin, fixtures, metric, parse_metrics, raw_get, raw_request, serve_must_refuse,
};
use std::io::{BufRead, BufReader};
use std::process::Stdio;
use tessera_shared::Pyramid;

// ---------------------------------------------------------------------------
// 9. Range amplification

#[test]
fn overlapping_byte_ranges_never_send_more_than_the_file() {
    let f = fixtures();
    let file = std::fs::read(&f.synth).unwrap();
    let size = file.len();
    let srv = Server::start(&[&f.synth], &[]);
    let url = "/v1/datasets/synth/pyramid";

    let spec = format!("bytes={}", vec!["0-"; 64].join(","));
    let r = srv.get_with(url, &[("range", &spec)]);
    assert!(
        r.body.len() <= size,
        "{} bytes for a {size}-byte file",
        r.body.len()
    );
    assert_eq!(r.status, 206);
    assert_eq!(
        r.must("content-range"),
        format!("bytes 0-{}/{size}", size - 1)
    );
    assert!(r.body == file);

    // Overlapping and touching ranges become one.
    let r = srv.get_with(url, &[("range", "bytes=0-9,5-19,20-29")]);
    assert_eq!(r.status, 206);
    assert_eq!(r.must("content-range"), format!("bytes 0-29/{size}"));
    assert!(r.body == file[..30]);

    // Many small overlapping ranges: still at most the bytes they cover, plus parts.
    let spec: Vec<String> = (0..64)
        .map(|i| format!("{}-{}", i * 1000, i * 1000 + 1500))
        .collect();
    let r = srv.get_with(url, &[("range", &format!("bytes={}", spec.join(",")))]);
    assert_eq!(r.status, 206);
    assert_eq!(r.must("content-range"), format!("bytes 0-64500/{size}"));
    assert!(r.body == file[..=64500]);
}

// ---------------------------------------------------------------------------
// 10. Host header

/// The TileJSON's first tile URL and its `Cache-Control` and `Vary` headers.
fn tiles_url(srv: &Server, headers: &str) -> (String, String, String) {
    let r = raw_request(srv.addr, "/v1/datasets/synth/tilejson.json", headers);
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    let j: serde_json::Value = serde_json::from_slice(&r.body).unwrap();
    let header = |name: &str| r.headers.get(name).cloned().unwrap_or_default();
    (
        j["tiles"][0].as_str().unwrap().to_string(),
        header("cache-control"),
        header("vary").to_ascii_lowercase(),
    )
}

/// A response built from the request's `Host` must never reach a shared cache.
fn assert_private(cache_control: &str, vary: &str, what: &str) {
    assert!(
        cache_control.starts_with("private"),
        "{what}: Cache-Control {cache_control:?}"
    );
    assert!(vary.contains("host"), "{what}: Vary {vary:?}");
}

#[test]
fn tilejson_urls_are_absolute_and_private_when_they_come_from_the_host_header() {
    let f = fixtures();
    let hash = Pyramid::open_file(&f.synth)
        .unwrap()
        .metadata()
        .content_hash
        .clone();
    let path = format!("/v1/datasets/synth/{{z}}/{{x}}/{{y}}.png?encoding=terrarium&v={hash}");

    // Default flags: absolute URLs on the Host the client used (a page on another
    // origin than the tiles needs them: MapLibre does not resolve relative ones),
    // private to that client, so a shared cache never hands one client's Host to
    // another; forwarded headers are not trusted.
    let srv = Server::start(&[&f.synth], &[]);
    for (headers, host) in [
        (format!("Host: {}\r\n", srv.addr), srv.addr.to_string()),
        (
            "Host: evil.example\r\n".to_string(),
            "evil.example".to_string(),
        ),
        (
            "Host: evil.example\r\nX-Forwarded-Host: evil2.example\r\nX-Forwarded-Proto: https\r\n"
                .to_string(),
            "evil.example".to_string(),
        ),
    ] {
        let (url, cc, vary) = tiles_url(&srv, &headers);
        assert_eq!(url, format!("http://{host}{path}"), "{headers:?}");
        assert_private(&cc, &vary, &headers);
    }
    // No Host, or one that is not a plain host[:port]: relative, and then shareable.
    for headers in ["", "Host: evil.example/x?y\r\n", "Host: a\r\nHost: b\r\n"] {
        let (url, cc, _) = tiles_url(&srv, headers);
        assert_eq!(url, path, "{headers:?}");
        assert!(!cc.starts_with("private"), "{headers:?}: {cc}");
    }
    // The absolute template, filled, is a tile of this server.
    let (url, ..) = tiles_url(&srv, &format!("Host: {}\r\n", srv.addr));
    let tile = url
        .strip_prefix(&format!("http://{}", srv.addr))
        .unwrap()
        .replace("{z}", "1")
        .replace("{x}", "0")
        .replace("{y}", "1");
    let png = srv.get(&tile);
    assert_eq!(png.expect(200).must("content-type"), "image/png");
    // A revalidation is private too.
    let r = raw_request(
        srv.addr,
        "/v1/datasets/synth/tilejson.json",
        "Host: a.example\r\n",
    );
    let etag = r.headers["etag"].clone();
    let r = raw_request(
        srv.addr,
        "/v1/datasets/synth/tilejson.json",
        &format!("Host: a.example\r\nIf-None-Match: {etag}\r\n"),
    );
    assert_eq!(r.status, 304);
    assert_private(
        &r.headers["cache-control"],
        &r.headers["vary"].to_ascii_lowercase(),
        "304",
    );
    // Another Host, another document: the ETag names the base.
    let other = raw_request(
        srv.addr,
        "/v1/datasets/synth/tilejson.json",
        "Host: b.example\r\n",
    );
    assert_ne!(other.headers["etag"], etag);
    drop(srv);

    // --public-url: exactly that, whatever the request says, and shareable.
    let srv = Server::start(&[&f.synth], &["--public-url", "https://tiles.example.org/"]);
    for headers in [
        "Host: evil.example\r\n",
        "",
        "X-Forwarded-Host: evil.example\r\n",
    ] {
        let (url, cc, vary) = tiles_url(&srv, headers);
        assert_eq!(
            url,
            format!("https://tiles.example.org{path}"),
            "{headers:?}"
        );
        assert!(cc.starts_with("public"), "{headers:?}: {cc}");
        assert!(!vary.contains("host"), "{headers:?}: {vary}");
    }
    drop(srv);

    // --trust-forwarded: the proxy's headers, checked, and shareable; the Host only
    // when the proxy sent none (then private again).
    let srv = Server::start(&[&f.synth], &["--trust-forwarded"]);
    let (url, cc, _) = tiles_url(
        &srv,
        "Host: evil.example\r\nX-Forwarded-Host: cdn.example\r\nX-Forwarded-Proto: https\r\n",
    );
    assert_eq!(url, format!("https://cdn.example{path}"));
    assert!(cc.starts_with("public"), "{cc}");
    let (url, cc, vary) = tiles_url(&srv, "Host: origin.example\r\n");
    assert_eq!(
        url,
        format!("http://origin.example{path}"),
        "no forwarded host"
    );
    assert_private(&cc, &vary, "no forwarded host");
    let r = raw_request(
        srv.addr,
        "/v1/datasets/synth/tilejson.json",
        "X-Forwarded-Host: evil.example/x?\r\n",
    );
    assert_eq!(r.status, 400);
    let r = raw_request(
        srv.addr,
        "/v1/datasets/synth/tilejson.json",
        "X-Forwarded-Host: cdn.example\r\nX-Forwarded-Proto: javascript\r\n",
    );
    assert_eq!(r.status, 400);
}

// ---------------------------------------------------------------------------
// 12. The smaller ones

fn json_error(r: &serve_support::RawResp) -> String {
    assert!(
        r.headers
            .get("content-type")
            .is_some_and(|t| t.starts_with("application/json")),
        "{:?}: {}",
        r.headers,
        String::from_utf8_lossy(&r.body)
    );
    let j: serde_json::Value = serde_json::from_slice(&r.body).unwrap();
    j["error"].as_str().unwrap().to_string()
}

#[test]
fn every_error_is_json_and_sloppy_queries_are_rejected() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth], &[]);
    for target in [
        "/v1/datasets/%ff%fe",
        "/v1/datasets/%ff%fe/pyramid",
        "/v1/datasets/synth/levels/%ff/tiles?ranges=0",
        "/v1/datasets/synth/tiles/1/%c3%28/0",
    ] {
        let r = raw_get(srv.addr, target);
        assert_eq!(r.status, 400, "{target}");
        let msg = json_error(&r);
        assert!(msg.contains("UTF-8"), "{target}: {msg}");
        assert!(
            !msg.contains('\u{fffd}') && !msg.contains("\\x"),
            "{target}: {msg}"
        );
    }
    for (query, want) in [
        ("ranges=+5", "digits only"),
        ("ranges=%205", "digits only"),
        ("ranges=5%20", "digits only"),
        ("ranges=0-%2B3", "digits only"),
        ("ranges=0&ranges=1", "more than once"),
        ("ranges=0&v=a&v=b", "more than once"),
    ] {
        let r = raw_get(
            srv.addr,
            &format!("/v1/datasets/synth/levels/1/tiles?{query}"),
        );
        assert_eq!(r.status, 400, "{query}");
        let msg = json_error(&r);
        assert!(msg.contains(want), "{query}: {msg}");
    }
    // Percent-encoded bytes that are not UTF-8 in the query: a JSON 400 too.
    let r = raw_get(srv.addr, "/v1/datasets/synth/levels/1/tiles?ranges=%ff");
    assert_eq!(r.status, 400);
    let msg = json_error(&r);
    assert!(msg.contains("\"ranges\"") && msg.contains("UTF-8"), "{msg}");
    // Percent-encoding that is not, and names that are empty, were taken as they
    // came (`%zz` as itself, `=5` as a parameter named ""): now a 400 naming them.
    for (query, want) in [
        (
            "ranges=0&%zz=1",
            "name \"%zz\": '%' at byte 0 is not followed by two hex digits",
        ),
        ("ranges=0&v=a%2", "parameter \"v\": '%' at byte 1"),
        ("ranges=0%2", "parameter \"ranges\": '%' at byte 1"),
        ("ranges=0&=5", "\"=5\" has an empty name"),
    ] {
        for path in [
            "/v1/datasets/synth/levels/1/tiles",
            "/v1/datasets/synth/webmercator/tilejson.json",
        ] {
            let r = raw_get(srv.addr, &format!("{path}?{query}"));
            assert_eq!(r.status, 400, "{path}?{query}");
            let msg = json_error(&r);
            assert!(msg.contains(want), "{path}?{query}: {msg}");
        }
    }
}

/// A request target longer than hyper's fixed limit (65 534 bytes) was answered by
/// hyper itself: a bare 414, no JSON, no CORS. Now it is the 414 every other error
/// is, and so is hyper's 400 for a request line that does not parse.
#[test]
fn the_http_layers_own_errors_are_json_with_cors() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth], &[]);
    let origin = "Origin: https://map.example\r\n";
    let long = format!("/v1/datasets/synth/tilejson.json?v={}", "a".repeat(70_000));
    let bad_line = "/v1/datasets/synth HTTP/1.1 junk";
    for (target, status, want) in [
        (&*long, 414, "65534 bytes"),
        (bad_line, 400, "malformed HTTP request"),
    ] {
        let r = raw_request(srv.addr, target, &format!("Host: x\r\n{origin}"));
        assert_eq!(r.status, status, "{:?}", r.headers);
        let msg = json_error(&r);
        assert!(msg.contains(want), "{msg}");
        assert_eq!(
            r.headers
                .get("access-control-allow-origin")
                .map(String::as_str),
            Some("*"),
            "{:?}",
            r.headers
        );
        assert!(
            r.headers["access-control-expose-headers"].contains("retry-after"),
            "{:?}",
            r.headers
        );
    }
    // The server answers on, and a long target it can parse gets our own 414.
    let r = raw_request(
        srv.addr,
        &format!("/v1/datasets/synth/tilejson.json?v={}", "a".repeat(9000)),
        &format!("Host: x\r\n{origin}"),
    );
    assert_eq!(r.status, 414);
    assert!(json_error(&r).contains("-byte limit"));
    assert_eq!(r.headers["access-control-allow-origin"], "*");
}

/// Error messages quote request input (path segments, dataset names, query names
/// and values) in part: a 60 KB dataset name used to come back whole.
#[test]
fn errors_quote_long_request_input_in_part() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth], &[]);
    let long = "n".repeat(60_000);
    for (target, length) in [
        (format!("/v1/datasets/{long}"), 60_000),
        (format!("/v1/datasets/{}", "%E2%9C%93".repeat(6000)), 18_000),
        (
            format!("/v1/datasets/synth/levels/{long}/tiles?ranges=0"),
            60_000,
        ),
        (format!("/v1/datasets/synth/tiles/0/{long}/0"), 60_000),
        (
            format!("/v1/datasets/synth/webmercator/{long}/0/0.png"),
            60_000,
        ),
        (format!("/v1/datasets/synth/{long}/tilejson.json"), 60_000),
        (
            format!("/v1/datasets/synth/cesium/{long}/0/0.terrain"),
            60_000,
        ),
        (
            format!("/v1/datasets/synth/bootstrap?focus={}", "1".repeat(8000)),
            8000,
        ),
        (
            format!(
                "/v1/datasets/synth/levels/1/tiles?ranges={}",
                "9".repeat(8000)
            ),
            8000,
        ),
        (
            format!(
                "/v1/datasets/synth/webmercator/tilejson.json?encoding={}",
                "x".repeat(8000)
            ),
            8000,
        ),
        (
            format!(
                "/v1/datasets/synth/levels/1/tiles?ranges=0&{k}=1&{k}=2",
                k = "k".repeat(4000)
            ),
            4000,
        ),
    ] {
        let r = raw_get(srv.addr, &target);
        assert!(
            r.status == 400 || r.status == 404,
            "{}: {}",
            r.status,
            &target[..60]
        );
        let msg = json_error(&r);
        assert!(msg.len() < 400, "{} bytes: {msg}", msg.len());
        assert!(msg.contains(&format!("… ({length} bytes)")), "{msg}");
    }
}

#[test]
fn corrupt_records_are_counted_once_and_reads_every_time() {
    let f = fixtures();
    let srv = Server::start(&[&f.corrupt], &[]);
    let c = f.corrupt_tile;
    let single = format!(
        "/v1/datasets/synth-corrupt/tiles/{}/{}/{}",
        c.level(),
        c.x(),
        c.y()
    );
    let stream = format!(
        "/v1/datasets/synth-corrupt/levels/{}/tiles?ranges={}",
        c.level(),
        c.morton()
    );
    for _ in 0..3 {
        srv.get(&single).error(500);
    }
    srv.get(&stream).expect(200);
    let m = parse_metrics(&srv.get("/metrics").expect(200).text());
    assert_eq!(metric(&m, "tessera_corrupt_records_total"), 1.0);
    assert_eq!(metric(&m, "tessera_corrupt_record_reads_total"), 4.0);
}

#[test]
fn zero_limits_are_refused_naming_the_flag() {
    let f = fixtures();
    let file = f.synth.to_str().unwrap();
    for flag in [
        "--max-ranges",
        "--max-tiles",
        "--timeout-secs",
        "--concurrency",
        "--header-timeout-secs",
        "--idle-timeout-secs",
        "--max-connections",
    ] {
        let err = serve_must_refuse(&[file, flag, "0"]);
        assert!(err.contains(flag), "{flag}: {err}");
    }
}

#[test]
fn logs_have_no_colour_codes_off_a_terminal_and_quiet_keeps_only_errors() {
    let f = fixtures();
    let file = f.synth.to_str().unwrap();
    // A warning at start-up: the cap asked for is above the fd limit.
    let run = |extra: &[&str]| -> String {
        let mut child = bin()
            .arg("serve")
            .arg(file)
            .args(["--listen", "127.0.0.1:0", "--max-connections", "100000000"])
            .args(extra)
            .env_remove("NO_COLOR")
            .env_remove("RUST_LOG")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut out = BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        out.read_line(&mut line).unwrap();
        let addr = line
            .trim()
            .strip_prefix("listening on http://")
            .unwrap()
            .to_string();
        let r = raw_get(addr.parse().unwrap(), "/v1/datasets/nope");
        assert_eq!(r.status, 404);
        let _ = child.kill();
        let _ = child.wait();
        serve_support::take_stderr(&mut child)
    };
    let loud = run(&[]);
    assert!(loud.contains("WARN"), "{loud}");
    assert!(loud.contains("request"), "{loud}");
    assert!(!loud.contains('\x1b'), "ANSI codes in a pipe: {loud:?}");
    let quiet = run(&["-q"]);
    assert!(
        !quiet.contains("WARN") && !quiet.contains("INFO"),
        "{quiet}"
    );
}
