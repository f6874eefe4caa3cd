//! Expensive work (DECISIONS.md "Expensive work"): computed responses (Cesium meshes,
//! grid and PNG tiles, bootstrap bodies) under heavy and hostile requests, against a real
//! `tessera-server serve` of the SRTM tile N46E008 over real sockets (RELIABILITY.md
//! "Expensive work"): identical requests share one computation, a client that stops
//! reading pins no more than the memory budget, a busy server answers 503 with
//! `Retry-After`, cheap routes keep answering, and a request that goes away takes its
//! work with it.
//!
//! No test measures time: each waits for a state that `/metrics` reports, within
//! generous bounds on "eventually".

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{Sample, Server, compute, dem_pyramid, metrics, until};
use std::io::{Read, Write};
use std::net::TcpStream;

/// A Cesium tile of N46E008 that takes a real mesh (zoom 5: the whole DEM's level).
const TERRAIN: &str = "/v1/datasets/N46E008/cesium/5/33/24.terrain";

/// The single unlabelled value of `name`.
fn gauge(samples: &[Sample], name: &str) -> f64 {
    serve_support::metric(samples, name)
}

/// `n` concurrent GETs of `url`: (status, body) each.
fn identical(url: &str, n: usize) -> Vec<(u16, Vec<u8>)> {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let client = reqwest::Client::new();
    rt.block_on(async {
        let all: Vec<_> = (0..n)
            .map(|_| {
                let (c, u) = (client.clone(), url.to_string());
                tokio::spawn(async move {
                    let r = c.get(u).send().await.unwrap();
                    (r.status().as_u16(), r.bytes().await.unwrap().to_vec())
                })
            })
            .collect();
        let mut out = Vec::new();
        for t in all {
            out.push(t.await.unwrap());
        }
        out
    })
}

#[test]
fn identical_requests_for_a_terrain_tile_make_one_mesh() {
    let Some(p) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    // The server's defaults: nothing configured.
    let srv = Server::start(&[&p], &[]);
    let bodies = identical(&srv.url(TERRAIN), 64);
    assert!(
        bodies.iter().all(|(s, _)| *s == 200),
        "{:?}",
        bodies.iter().map(|b| b.0).collect::<Vec<_>>()
    );
    assert!(
        bodies.iter().all(|(_, b)| *b == bodies[0].1),
        "one mesh, the same bytes"
    );
    // The dataset's availability, which every first tile needs, was made once too.
    let made = srv.log().matches("terrain availability made").count();
    assert_eq!(made, 1, "availability made {made} times");
    let m = metrics(&srv);
    // One computation: the other 63 waited on it, or found it in the cache after.
    assert_eq!(
        compute(&m, "tessera_compute_total", "terrain", Some("started")),
        1.0
    );
    let joined = compute(&m, "tessera_compute_total", "terrain", Some("joined"));
    let hits: f64 = m
        .iter()
        .filter(|s| {
            s.name == "tessera_web_cache_requests_total"
                && s.labels.get("cache").is_some_and(|c| c == "terrain")
                && s.labels.get("result").is_some_and(|r| r == "hit")
        })
        .map(|s| s.value)
        .sum();
    assert_eq!(joined + hits, 63.0, "joined {joined}, cache hits {hits}");
}

/// A server with a 1 MiB compute budget and a `queue_secs` wait, and a bootstrap
/// body (~0.7 MB) made whole, then held by an HTTP/2 client that takes the head but
/// no body bytes (window 0): the rest of the budget is less than any mesh needs.
fn budget_held(
    p: &std::path::Path,
    queue_secs: &str,
) -> (
    Server,
    tokio::runtime::Runtime,
    reqwest::Client,
    reqwest::Response,
) {
    let srv = Server::start(
        &[p],
        &["--max-compute-mib", "1", "--compute-queue-secs", queue_secs],
    );
    let rt = tokio::runtime::Runtime::new().unwrap();
    let client = reqwest::Client::builder()
        .http2_prior_knowledge()
        .http2_initial_stream_window_size(Some(0))
        .build()
        .unwrap();
    let held = rt
        .block_on(client.get(srv.url("/v1/datasets/N46E008/bootstrap")).send())
        .unwrap();
    assert_eq!(held.status(), 200);
    (srv, rt, client, held)
}

#[test]
fn identical_requests_for_a_grid_tile_a_rendered_or_contour_tile_or_a_bootstrap_are_made_once() {
    let Some(p) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    let srv = Server::start(&[&p], &[]);
    for (path, kind) in [
        (
            "/v1/datasets/N46E008/webmercator/9/268/181.png",
            "grid_tile",
        ),
        (
            "/v1/datasets/N46E008/webmercator/hillshade/11/1072/724.png",
            "rendered",
        ),
        (
            "/v1/datasets/N46E008/webmercator/contours/11/1072/724.mvt",
            "contours",
        ),
        ("/v1/datasets/N46E008/bootstrap?focus=0.5,0.5", "bootstrap"),
    ] {
        let bodies = identical(&srv.url(path), 32);
        assert!(
            bodies.iter().all(|(s, b)| *s == 200 && *b == bodies[0].1),
            "{path}"
        );
        let m = metrics(&srv);
        assert_eq!(
            compute(&m, "tessera_compute_total", kind, Some("started")),
            1.0,
            "{path}"
        );
    }
}

#[test]
fn a_client_that_stops_reading_pins_only_the_budget_and_the_rest_get_503_with_retry_after() {
    let Some(p) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    let (srv, rt, client, held) = budget_held(&p, "1");
    let len: u64 = held.headers()["content-length"]
        .to_str()
        .unwrap()
        .parse()
        .unwrap();
    // The body stays reserved while the client holds it; what is left of the 1 MiB
    // budget is less than a zoom-5 mesh needs.
    let m = metrics(&srv);
    assert_eq!(gauge(&m, "tessera_compute_memory_bytes"), len as f64);
    assert!(len > 256 << 10, "{len}");

    // New work waits for memory, then is refused with a reason and Retry-After.
    let r = srv.get(TERRAIN);
    let why = r.error(503);
    assert!(why.contains("memory limit"), "{why}");
    assert_eq!(r.must("retry-after"), "1");
    let m = metrics(&srv);
    assert_eq!(
        compute(&m, "tessera_compute_total", "terrain", Some("busy")),
        1.0
    );

    // Cheap routes answer all along.
    srv.get("/healthz").expect(200);
    srv.get("/v1/datasets/N46E008/tiles/0/0/0").expect(200);
    srv.get("/v1/datasets/N46E008/cesium/layer.json")
        .expect(200);

    // The client goes (RST_STREAM): the body and its memory go with it, and the
    // same request is now made.
    drop(held);
    until(&srv, "the held body's memory given back", |m| {
        gauge(m, "tessera_compute_memory_bytes") == 0.0
    });
    let r = srv.get(TERRAIN).expect(200);
    assert!(!r.body.is_empty());

    // A body from a cache pins its memory alike while a client holds it unread.
    let again = rt
        .block_on(client.get(srv.url("/v1/datasets/N46E008/bootstrap")).send())
        .unwrap();
    assert_eq!(again.status(), 200);
    let m = metrics(&srv);
    assert_eq!(gauge(&m, "tessera_compute_memory_bytes"), len as f64);
    assert_eq!(
        compute(&m, "tessera_compute_total", "bootstrap", Some("started")),
        1.0,
        "the second one was the kept body"
    );
    // (TERRAIN itself is in the tile cache now: another tile of the same window.)
    srv.get("/v1/datasets/N46E008/cesium/4/16/12.terrain")
        .error(503);
    drop(again);
}

#[test]
fn work_whose_requesters_are_gone_stops() {
    let Some(p) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    // The budget held, so admitted work waits inside its computation.
    let (srv, rt, _client, held) = budget_held(&p, "600");

    // HTTP/1: a request admitted (it holds a slot, waiting for memory), then the
    // connection closed.
    let mut s = TcpStream::connect(srv.addr).unwrap();
    write!(s, "GET {TERRAIN} HTTP/1.1\r\nHost: x\r\n\r\n").unwrap();
    until(&srv, "the terrain mesh admitted", |m| {
        compute(m, "tessera_compute_running", "terrain", None) == 1.0
    });
    drop(s);
    until(&srv, "the closed request's work stopped", |m| {
        compute(m, "tessera_compute_running", "terrain", None) == 0.0
            && compute(m, "tessera_compute_total", "terrain", Some("cancelled")) == 1.0
    });

    // HTTP/2: the same with RST_STREAM on a connection that stays open.
    let h2 = reqwest::Client::builder()
        .http2_prior_knowledge()
        .build()
        .unwrap();
    let url = srv.url("/v1/datasets/N46E008/cesium/6/67/48.terrain");
    let task = rt.spawn(async move { h2.get(url).send().await.map(|r| r.status()) });
    until(&srv, "the second mesh admitted", |m| {
        compute(m, "tessera_compute_running", "terrain", None) == 1.0
    });
    task.abort();
    let m = until(&srv, "the reset stream's work stopped", |m| {
        compute(m, "tessera_compute_running", "terrain", None) == 0.0
            && compute(m, "tessera_compute_total", "terrain", Some("cancelled")) == 2.0
    });
    // Neither ever made a mesh.
    assert_eq!(
        compute(&m, "tessera_compute_total", "terrain", Some("started")),
        2.0
    );
    let misses: f64 = m
        .iter()
        .filter(|s| {
            s.name == "tessera_web_cache_bytes"
                && s.labels.get("cache").is_some_and(|c| c == "terrain")
        })
        .map(|s| s.value)
        .sum();
    assert_eq!(misses, 0.0, "no terrain tile was kept");
    drop(held);

    // A request whose connection is still open is answered once memory frees.
    let mut s = TcpStream::connect(srv.addr).unwrap();
    write!(
        s,
        "GET {TERRAIN} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut head = [0u8; 12];
    s.read_exact(&mut head).unwrap();
    assert_eq!(&head, b"HTTP/1.1 200");
}
