//! `tessera-server serve` end to end, operating it: `/metrics`, bad requests and
//! their JSON reasons on every route, graceful shutdown on SIGTERM, and the
//! configuration file, environment and flags (API.md).
//!
//! Pyramids are shared by every test (`serve_support`); every test starts its own
//! server on an ephemeral port (killed when the test ends) and checks responses
//! against the pyramid file read independently with the shared reader.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{
    Fixtures, Server, decode_stream, find, fixtures, metric, open, parse_head, parse_metrics,
    raw_get, split_trailer,
};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};
use tessera_shared::wire;

// ---------------------------------------------------------------------------
// Metrics

#[test]
fn metrics_count_requests_tiles_and_corruption() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth, &f.corrupt], &[]);
    let before = parse_metrics(&srv.get("/metrics").expect(200).text());
    let tiles_before = metric(&before, "tessera_tiles_served_total");

    let frames = decode_stream(&srv.get("/v1/datasets/synth/levels/3/tiles?ranges=0-9,20-24"));
    assert_eq!(frames.len(), 16);
    srv.get("/v1/datasets/synth/tiles/2/0/0").expect(200);
    srv.get("/v1/datasets/synth/tiles/9/0/0").error(404);
    let c = f.corrupt_tile;
    srv.get(&format!(
        "/v1/datasets/synth-corrupt/tiles/{}/{}/{}",
        c.level(),
        c.x(),
        c.y()
    ))
    .error(500);

    let r = srv.get("/metrics").expect(200);
    assert!(r.must("content-type").starts_with("text/plain"));
    let after = parse_metrics(&r.text());
    assert_eq!(
        metric(&after, "tessera_tiles_served_total") - tiles_before,
        16.0,
        "15 tiles in the stream and 1 single tile"
    );
    assert_eq!(metric(&after, "tessera_corrupt_records_total"), 1.0);
    assert_eq!(metric(&after, "tessera_corrupt_record_reads_total"), 1.0);
    let requests: Vec<_> = after
        .iter()
        .filter(|s| s.name == "tessera_http_requests_total")
        .collect();
    let count = |route: &str, status: &str| -> f64 {
        requests
            .iter()
            .filter(|s| {
                s.labels.get("route").map(String::as_str) == Some(route)
                    && s.labels.get("status").map(String::as_str) == Some(status)
            })
            .map(|s| s.value)
            .sum()
    };
    assert_eq!(
        count("/v1/datasets/{name}/levels/{level}/tiles", "200"),
        1.0,
        "{requests:?}"
    );
    assert_eq!(
        count("/v1/datasets/{name}/tiles/{level}/{x}/{y}", "200"),
        1.0
    );
    assert_eq!(
        count("/v1/datasets/{name}/tiles/{level}/{x}/{y}", "404"),
        1.0
    );
    assert_eq!(
        count("/v1/datasets/{name}/tiles/{level}/{x}/{y}", "500"),
        1.0
    );
    // Labels are route templates, never raw paths (bounded cardinality).
    assert!(
        requests
            .iter()
            .all(|s| !s.labels["route"].contains("synth")),
        "{requests:?}"
    );
}

// ---------------------------------------------------------------------------
// Bad input

#[test]
fn bad_requests_get_json_reasons() {
    let f = fixtures();
    let srv = Server::start(
        &[&f.synth],
        &[
            "--max-ranges",
            "4",
            "--max-tiles",
            "16",
            "--max-query-bytes",
            "256",
        ],
    );
    // A wrong method gets a JSON reason and the Allow header, like every other error.
    let r = srv.send(reqwest::Method::POST, "/healthz", &[]);
    assert!(r.error(405).contains("read-only"));
    assert_eq!(r.header("allow"), Some("GET,HEAD"));
    let tiles = "/v1/datasets/synth/levels";
    // (path, status, words the message must contain, case-insensitively)
    let cases: Vec<(String, u16, Vec<&str>)> = vec![
        ("/v1/datasets/atlantis".into(), 404, vec!["atlantis"]),
        (
            "/v1/datasets/atlantis/levels/0/tiles?ranges=0".into(),
            404,
            vec!["atlantis"],
        ),
        (format!("{tiles}/5/tiles?ranges=0"), 404, vec!["level", "5"]),
        (format!("{tiles}/99/tiles?ranges=0"), 404, vec!["level"]),
        (format!("{tiles}/abc/tiles?ranges=0"), 404, vec!["level"]),
        (
            format!("{tiles}/4/tiles?ranges=abc"),
            400,
            vec!["malformed", "abc"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=1-2-3"),
            400,
            vec!["malformed"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=0-3,"),
            400,
            vec!["malformed"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=5-2"),
            400,
            vec!["reversed", "5-2"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=0-5,3-9"),
            400,
            vec!["overlap"],
        ),
        (
            format!("{tiles}/1/tiles?ranges=0-4"),
            400,
            vec!["outside", "0-4"],
        ),
        (format!("{tiles}/4/tiles?ranges=256"), 400, vec!["outside"]),
        (format!("{tiles}/4/tiles"), 400, vec!["missing", "ranges"]),
        (format!("{tiles}/4/tiles?ranges="), 400, vec!["ranges"]),
        (
            format!("{tiles}/4/errors?ranges=0-5,3-9"),
            400,
            vec!["overlap"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=0,2,4,6,8"),
            400,
            vec!["5 ranges", "at most 4"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=0-16"),
            400,
            vec!["17 tiles", "at most 16"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=0-7,10-18"),
            400,
            vec!["at most 16"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=0&pad={}", "x".repeat(300)),
            414,
            vec!["256"],
        ),
        ("/v2/everything".into(), 404, vec!["endpoint"]),
        ("/v1/datasets/synth/levels/4".into(), 404, vec!["endpoint"]),
    ];
    for (path, status, words) in &cases {
        let msg = srv.get(path).error(*status).to_lowercase();
        for w in words {
            assert!(
                msg.contains(&w.to_lowercase()),
                "GET {path}: message {msg:?} does not mention {w:?}"
            );
        }
    }
    // Within the limits is fine.
    decode_stream(&srv.get(&format!("{tiles}/4/tiles?ranges=0,2,4,6-18")));

    // Path traversal: never a 200, never a file's contents, always a JSON reason.
    for path in [
        "/v1/datasets/..%2F..%2Fetc/levels/0/tiles?ranges=0",
        "/v1/datasets/..%2F..%2F..%2F..%2Fetc%2Fpasswd",
        "/v1/datasets/%2e%2e/pyramid",
        "/v1/datasets/.hidden",
        "/v1/datasets/.hidden/tiles/0/0/0",
        "/v1/datasets/synth%2F..%2Fsynth/tiles/0/0/0",
    ] {
        let r = srv.get(path);
        assert!(
            r.status == 400 || r.status == 404,
            "GET {path}: {} {}",
            r.status,
            r.text()
        );
        r.json_error();
        assert!(!r.text().contains("root:"), "GET {path} leaked a file");
    }
    // Raw targets a client library would normalise away.
    for target in [
        "/v1/datasets/../../../../etc/passwd",
        "/v1/datasets/synth/../../../etc/passwd",
        "/v1/datasets/%2e%2e/%2e%2e/%2e%2e/etc/passwd",
    ] {
        let r = raw_get(srv.addr, target);
        assert!(
            (400..500).contains(&r.status),
            "GET {target}: {} {}",
            r.status,
            String::from_utf8_lossy(&r.body)
        );
        assert!(!String::from_utf8_lossy(&r.body).contains("root:"));
        assert!(
            r.headers
                .get("content-type")
                .is_some_and(|c| c.starts_with("application/json")),
            "GET {target}: {:?}",
            r.headers
        );
    }
    // The server is still healthy after all that.
    srv.get("/healthz").expect(200);
}

// ---------------------------------------------------------------------------
// Graceful shutdown

/// Whether a fresh connection gets an HTTP response (`false`: refused, reset,
/// closed or silent).
fn served(addr: std::net::SocketAddr) -> bool {
    let Ok(mut s) = TcpStream::connect_timeout(&addr, Duration::from_secs(2)) else {
        return false;
    };
    s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
    if write!(
        s,
        "GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
    )
    .is_err()
    {
        return false;
    }
    let mut buf = [0u8; 12];
    matches!(s.read(&mut buf), Ok(n) if n > 0)
}

#[test]
fn sigterm_finishes_in_flight_responses_then_exits() {
    let f = fixtures();
    let mut srv = Server::start(&[&f.synth4k], &[]);
    let p = open(&f.synth4k);
    let finest = p.geometry().finest();
    let slots = finest.tile_slots();

    let mut s = TcpStream::connect(srv.addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    write!(
        s,
        "GET /v1/datasets/synth4k/levels/{finest}/tiles?ranges=0-{} HTTP/1.1\r\nHost: x\r\n\r\n",
        slots - 1
    )
    .unwrap();
    // Read the head and a few body bytes only: the rest (~20 MB) is still in flight.
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    let head_end = loop {
        let n = s.read(&mut buf).unwrap();
        assert!(n > 0, "connection closed before the head");
        got.extend_from_slice(&buf[..n]);
        if let Some(e) = find(&got, b"\r\n\r\n")
            && got.len() > e + 4
        {
            break e;
        }
    };
    let (status, headers) = parse_head(std::str::from_utf8(&got[..head_end]).unwrap());
    assert_eq!(status, 200);
    let len: usize = headers["content-length"].parse().unwrap();
    let mut body = got[head_end + 4..].to_vec();
    assert!(
        len > 8 << 20,
        "fixture: body of {len} bytes is too small to be in flight"
    );

    srv.terminate();

    // New connections are refused or left unanswered once the signal is handled
    // (one accepted before that may still be served: retry within a deadline).
    let deadline = Instant::now() + Duration::from_secs(15);
    while served(srv.addr) {
        assert!(
            Instant::now() < deadline,
            "new connections still served long after SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(50));
    }

    // The server waits for the unfinished response (~20 MB, far more than socket
    // buffers hold while we do not read) rather than exiting under it.
    assert!(
        srv.try_wait().is_none(),
        "server exited with a response still in flight"
    );

    // The in-flight response completes.
    while body.len() < len {
        let n = s.read(&mut buf).unwrap();
        assert!(n > 0, "response cut off at {} of {len} bytes", body.len());
        body.extend_from_slice(&buf[..n]);
    }
    assert_eq!(body.len(), len);
    let frames = wire::decode_all(&body).unwrap();
    let (tiles_frames, tiles, errors, _) = split_trailer(&frames);
    assert_eq!(tiles, slots);
    assert_eq!(errors, 0);
    assert_eq!(tiles_frames.len() as u64, slots);

    let status = srv.wait_exit(Duration::from_secs(20));
    assert!(status.success(), "server exited with {status}");
}

// ---------------------------------------------------------------------------
// Configuration

#[test]
fn config_file_env_and_flags() {
    let f: &Fixtures = fixtures();
    let scratch = tempfile::tempdir().unwrap();
    let toml_path = scratch.path().join("serve-config.toml");
    std::fs::write(
        &toml_path,
        format!(
            "datasets = [{:?}]\nmax_ranges = 2\nmax_tiles = 4\n",
            f.synth.to_str().unwrap()
        ),
    )
    .unwrap();
    let cfg = toml_path.to_str().unwrap();
    let lvl = "/v1/datasets/synth/levels/4/tiles";

    // TOML alone: datasets and limits from the file.
    let srv = Server::start(&[], &["--config", cfg]);
    let list = srv.get("/v1/datasets").expect(200).json();
    assert_eq!(list["datasets"][0]["name"], "synth", "{list}");
    assert_eq!(list["datasets"].as_array().unwrap().len(), 1);
    let e = srv.get(&format!("{lvl}?ranges=0,2,4")).error(400);
    assert!(e.contains("at most 2"), "{e}");
    decode_stream(&srv.get(&format!("{lvl}?ranges=0,2")));
    let e = srv.get(&format!("{lvl}?ranges=0-4")).error(400);
    assert!(e.contains("at most 4"), "{e}");
    drop(srv);

    // The environment beats the file.
    let srv = Server::start_with(&[], &["--config", cfg], &[("TESSERA_MAX_TILES", "8")]);
    decode_stream(&srv.get(&format!("{lvl}?ranges=0-7")));
    let e = srv.get(&format!("{lvl}?ranges=0-8")).error(400);
    assert!(e.contains("at most 8"), "{e}");
    drop(srv);

    // TESSERA_* alone, and a flag beating it.
    let srv = Server::start_with(&[&f.synth], &[], &[("TESSERA_MAX_TILES", "8")]);
    let e = srv.get(&format!("{lvl}?ranges=0-8")).error(400);
    assert!(e.contains("at most 8"), "{e}");
    drop(srv);
    let srv = Server::start_with(
        &[&f.synth],
        &["--max-tiles", "32"],
        &[("TESSERA_MAX_TILES", "8")],
    );
    decode_stream(&srv.get(&format!("{lvl}?ranges=0-31")));
    let e = srv.get(&format!("{lvl}?ranges=0-32")).error(400);
    assert!(e.contains("at most 32"), "{e}");
    drop(srv);

    // A flag's dataset list replaces the file's.
    let srv = Server::start(&[&f.corrupt], &["--config", cfg]);
    let list = srv.get("/v1/datasets").expect(200).json();
    assert_eq!(list["datasets"].as_array().unwrap().len(), 1, "{list}");
    assert_eq!(list["datasets"][0]["name"], "synth-corrupt", "{list}");
}
