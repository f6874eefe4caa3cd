//! Load testing (DECISIONS.md "Load testing: the proof"), the recording half: `tessera
//! load --record TRACE` writes the requests the full clients really sent. A real server
//! over the moon 4096² DEM, real clients in process, and a logging proxy between them
//! (`tessera-proxy`) that sees every request line on the wire, independently of the
//! client's code.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared fixtures
mod streaming_support;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use streaming_support::start_server_for;
use tessera_client::app::load_test::{LoadOptions, load};
use tessera_client::loadtest::trace::{RequestKind, StreamDigest, Trace, body_digest};
use tessera_client::stream::TileSource;
use tessera_server::builder::{BuildOptions, build};
use tessera_shared::wire::{Frame, FrameDecoder};

/// The moon 4096² built in `dir` as `moon.tess` (128-cell tiles: many requests); `None` when the
/// DEM is not there (`testdata::dem_or_skip` says so).
fn moon(dir: &Path) -> Option<PathBuf> {
    let dem = tessera_shared::testdata::dem_or_skip("moon_crisium_gld100_4096.png")?;
    let out = dir.join("moon.tess");
    let opts = BuildOptions {
        tile_size: 128,
        progress: false,
        ..BuildOptions::default()
    };
    build(dem.to_str().unwrap(), &out, &opts).unwrap();
    Some(out)
}

fn options(source: TileSource, clients: u32, seconds: u64, record: PathBuf) -> LoadOptions {
    LoadOptions {
        record: Some(record),
        ..LoadOptions::new(source, clients, Duration::from_secs(seconds))
    }
}

/// What the log holds once the proxy has read every request line that reached it:
/// the clients' connections are closed when `load` returns, so its length stops
/// changing (within a generous 10 s).
fn settled(log: &tessera_proxy::RequestLog) -> Vec<String> {
    let started = Instant::now();
    let mut last = log.targets();
    loop {
        std::thread::sleep(Duration::from_millis(200));
        let now = log.targets();
        if now.len() == last.len() || started.elapsed() > Duration::from_secs(10) {
            return now;
        }
        last = now;
    }
}

fn counts<'a>(targets: impl Iterator<Item = &'a str>) -> HashMap<&'a str, usize> {
    let mut m = HashMap::new();
    for t in targets {
        *m.entry(t).or_insert(0) += 1;
    }
    m
}

/// A direct `GET` of `target` from the server: status and body.
fn get(rt: &tokio::runtime::Runtime, base: &str, target: &str) -> (u16, Vec<u8>) {
    rt.block_on(async {
        let r = reqwest::get(format!("{base}{target}")).await.unwrap();
        let status = r.status().as_u16();
        (status, r.bytes().await.unwrap().to_vec())
    })
}

/// Four full clients for three seconds through a logging proxy: the trace holds
/// exactly the requests on the wire, each client's opens with its bootstrap, and
/// every completed tile stream's expectation is what the real server answers to
/// the same target (tiles counted, and digested, by the shared frame decoder).
#[test]
fn the_trace_holds_what_the_clients_sent_and_what_the_server_answers() {
    let dir = tempfile::tempdir().unwrap();
    let Some(file) = moon(dir.path()) else { return };
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (server, _task) = start_server_for(&rt, "127.0.0.1:0".parse().unwrap(), &file);
    let (proxy, log) = rt.block_on(tessera_proxy::logging(server)).unwrap();
    let front = format!("http://{}", proxy.addr());
    let path = dir.path().join("moon.trace.jsonl");
    let clients = 4;

    let report = load(&options(
        TileSource::server(front.clone(), "moon"),
        clients,
        3,
        path.clone(),
    ))
    .unwrap();
    let logged = settled(&log);
    let trace = Trace::read(&path).unwrap();

    // The header names where, what and how many.
    let h = &trace.header;
    assert_eq!(h.server, front);
    assert_eq!(
        (h.dataset.as_str(), h.clients, h.mode.as_str()),
        ("moon", clients, "ranges")
    );
    assert!(h.seconds >= 3.0, "{} s recorded for a 3 s run", h.seconds);

    // The trace's requests are the ones on the wire. Every logged request is in the
    // trace; the trace may hold more only of requests that were registered but not
    // yet written when the run ended (the runtime stops with them), which cannot
    // have an answer.
    let (in_trace, on_wire) = (
        counts(trace.requests.iter().map(|r| r.target.as_str())),
        counts(logged.iter().map(String::as_str)),
    );
    for (t, n) in &on_wire {
        assert_eq!(
            in_trace.get(t).copied().unwrap_or(0),
            *n,
            "{t}: on the wire {n} times, in the trace {:?}",
            in_trace.get(t)
        );
    }
    let unsent: Vec<_> = in_trace
        .iter()
        .filter(|(t, n)| on_wire.get(*t).copied().unwrap_or(0) < **n)
        .map(|(t, _)| *t)
        .collect();
    for t in &unsent {
        assert!(
            trace
                .requests
                .iter()
                .filter(|r| r.target == *t)
                .any(|r| r.expect.is_none()),
            "{t}: in the trace more often than on the wire, yet every one was answered"
        );
    }
    assert!(
        unsent.len() <= (clients * 4) as usize,
        "{} requests in the trace never reached the wire (at most one per request in flight at the end)",
        unsent.len()
    );
    // The tile requests the report counts and one open per client, less any
    // cancelled before its task began (those were never sent, and are not recorded).
    assert!(
        trace.requests.len() as u64 <= report.requests + u64::from(clients),
        "{} requests in the trace, {} tile requests and {clients} opens counted",
        trace.requests.len(),
        report.requests
    );

    // Each client opened with one bootstrap, its first request, answered.
    for c in 0..clients {
        let mine: Vec<_> = trace.requests.iter().filter(|r| r.client == c).collect();
        assert!(mine.len() > 1, "client {c} sent {} requests", mine.len());
        assert_eq!(mine[0].kind, RequestKind::Bootstrap, "client {c}");
        assert_eq!(mine[0].target, "/v1/datasets/moon/bootstrap");
        assert!(mine[1..].iter().all(|r| r.kind == RequestKind::Tiles));
        let boot = mine[0].expect.as_ref().expect("the bootstrap was answered");
        let (status, body) = get(&rt, &format!("http://{server}"), &mine[0].target);
        assert_eq!((boot.status, boot.tiles), (status, 0));
        assert_eq!(
            (boot.bytes, boot.digest.as_str()),
            (body.len() as u64, body_digest(&body).as_str())
        );
    }

    // Every completed tile stream: what the real server answers to its target.
    let direct = format!("http://{server}");
    let completed: Vec<_> = trace
        .requests
        .iter()
        .filter(|r| r.kind == RequestKind::Tiles)
        .filter_map(|r| r.expect.as_ref().map(|e| (r, e)))
        .collect();
    assert!(
        completed.len() >= 10,
        "only {} tile requests completed: nothing much checked",
        completed.len()
    );
    let mut tiles = 0u64;
    for (r, e) in &completed {
        let level = r
            .target
            .split("/levels/")
            .nth(1)
            .and_then(|s| s.split('/').next());
        assert_eq!(
            r.level.map(|l| l.to_string()).as_deref(),
            level,
            "{}",
            r.target
        );
        let (status, body) = get(&rt, &direct, &r.target);
        let mut dec = FrameDecoder::new();
        dec.push(&body);
        let mut digest = StreamDigest::new();
        let mut frames = 0u32;
        while let Some(f) = dec.next_frame().unwrap() {
            frames += u32::from(matches!(f, Frame::Tile { .. }));
            digest.push(&f);
        }
        dec.finish().unwrap();
        assert_eq!(e.status, status, "{}", r.target);
        assert_eq!(e.tiles, frames, "{}: tile frames", r.target);
        assert_eq!(e.digest, digest.hex(), "{}", r.target);
        assert_eq!(e.bytes, body.len() as u64, "{}", r.target);
        tiles += u64::from(e.tiles);
    }
    eprintln!(
        "{} requests recorded ({} on the wire, {} not), {} tile streams completed with {tiles} tiles",
        trace.requests.len(),
        logged.len(),
        unsent.len(),
        completed.len()
    );
    assert!(tiles > 0, "the completed requests carried no tiles");
    assert!(
        tiles <= report.tiles,
        "the trace's completed streams hold {tiles} tiles, the clients decoded {}",
        report.tiles
    );
}

/// `--record` reads a Tessera server's routes only: with `--pyramid` it is an error
/// that names the flag and the source, before any request, and writes nothing.
#[test]
fn record_with_a_pyramid_source_is_a_named_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.jsonl");
    // No such file: the error must come before the source is opened.
    let file = format!("file://{}/nothing.tess", dir.path().display());
    let err = load(&options(TileSource::pyramid(file), 2, 1, path.clone())).unwrap_err();
    let msg = format!("{err:#}");
    assert!(msg.contains("--record"), "{msg}");
    assert!(msg.contains("--server"), "{msg}");
    assert!(!path.exists(), "a trace was written");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);

    // A trace in a directory that is not there: said before the run.
    let missing = dir.path().join("no/such/dir/t.jsonl");
    let err = load(&options(
        TileSource::server("http://127.0.0.1:9", "moon"),
        1,
        1,
        missing,
    ))
    .unwrap_err();
    assert!(format!("{err:#}").contains("does not exist"), "{err:#}");
}

/// The imagery feed records its requests too (kind `imagery`, with their level):
/// a streamer opened on the real Olinda DEM with its Landsat imagery, recording, asks
/// for every tile's imagery; each recorded answer is what the server sends again
/// for that target, frame for frame.
#[test]
fn the_imagery_feed_records_its_requests() {
    use tessera_client::loadtest::record::{RecordHook, Recorder};
    use tessera_client::stream::{StreamConfig, Streamer};
    let dir = tempfile::tempdir().unwrap();
    let Some(out) = streaming_support::olinda_with_imagery(dir.path()) else {
        return;
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (server, _task) = start_server_for(&rt, "127.0.0.1:0".parse().unwrap(), &out);
    let base = format!("http://{server}");
    let recorder = Recorder::new(&base);
    let config = StreamConfig {
        record: Some(RecordHook::new(recorder.clone(), 0)),
        ..StreamConfig::default()
    };
    let (streamer, info) =
        Streamer::open(&TileSource::server(base.clone(), "olinda"), config, None).unwrap();
    let mut feed = streamer.imagery_feed(64).expect("olinda has imagery");
    let g = tessera_shared::TileGeometry::new(info.width, info.height, info.tile_size).unwrap();
    let all: Vec<_> = g
        .levels()
        .flat_map(|l| g.present_tiles(l).collect::<Vec<_>>())
        .collect();
    assert!(
        feed.settle(&all, Duration::from_secs(60)),
        "imagery still pending"
    );
    drop(streamer);

    let trace = recorder.trace("olinda", 1, 0.0, "ranges");
    assert_eq!(trace.requests[0].kind, RequestKind::Bootstrap);
    let imagery: Vec<_> = trace
        .requests
        .iter()
        .filter(|r| r.kind == RequestKind::Imagery)
        .collect();
    // One request per level of the geometry (ranges_by_level), each answered.
    assert_eq!(imagery.len(), g.levels().count());
    let mut tiles = 0;
    for r in imagery {
        assert!(r.target.contains("/imagery/levels/"), "{}", r.target);
        let e = r.expect.as_ref().expect("answered");
        let (status, body) = get(&rt, &base, &r.target);
        let mut digest = StreamDigest::new();
        for f in tessera_shared::wire::decode_all(&body).unwrap() {
            digest.push(&f);
        }
        assert_eq!(
            (e.status, e.tiles, e.bytes, e.digest.as_str()),
            (
                status,
                digest.tiles(),
                body.len() as u64,
                digest.hex().as_str()
            ),
            "{}",
            r.target
        );
        tiles += e.tiles;
    }
    assert_eq!(
        tiles as usize,
        feed.pool().len(),
        "every pooled tile came in a recorded answer"
    );
}
