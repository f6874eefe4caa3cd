//! Serverless reads (DECISIONS.md "Serverless reads"; docs/ARCHITECTURE.md#scale-out):
//! `tessera fly --pyramid URL` and `tessera load --pyramid URL` read a pyramid file
//! straight from a static host with HTTP Range, no Tessera server. nginx is the host,
//! started by the tests (`tessera_e2e::nginx`; `SKIPPED` without it, a failure when `CI`
//! is set), its access log recording every request's `Range`.
//!
//! - the same flight against `tessera-server` and against nginx converges to the same
//!   selection, with one Range request per run of contiguous records (a Morton
//!   range), each record fetched once;
//! - a record corrupt in the file is reported corrupt, retried, written off; the
//!   others of its request arrive, and the flight draws on;
//! - nginx killed mid-flight and restarted: the flight recovers;
//! - `tessera load --pyramid`: the server's statistics, no errors;
//! - hosts that ignore `Range` (nginx's `max_ranges 0`): a small file is read whole,
//!   a large one refused before its body is read; a file changed under the client,
//!   a short body and a 416 are reported as such, and the client recovers.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared fixtures
mod streaming_support;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU8, Ordering};
use std::time::Duration;
use streaming_support::{
    assert_no_holes, assert_recovered, glide, options, pyramid, run_flight, small_load_opened,
    start_server,
};
use tessera_client::app::fly::{FlyOptions, FlySummary};
use tessera_client::select::Wanted;
use tessera_client::stream::pool::TilePool;
use tessera_client::stream::{StreamConfig, Streamer, TileSource};
use tessera_e2e::nginx::{Logged, Nginx};
use tessera_shared::{FileSource, Level, Pyramid, TileId};

/// A directory holding `terrain.tess` (a link to the test pyramid) for nginx to serve.
fn www_with_pyramid() -> tempfile::TempDir {
    let www = tempfile::tempdir().unwrap();
    std::os::unix::fs::symlink(pyramid(), www.path().join("terrain.tess")).unwrap();
    www
}

fn serverless(mut opts: FlyOptions, url: String) -> FlyOptions {
    opts.source = TileSource::pyramid(url);
    opts
}

/// The requests for `/NAME` in nginx's log.
fn requests_for<'a>(log: &'a [Logged], name: &str) -> Vec<&'a Logged> {
    let uri = format!("/{name}");
    log.iter().filter(|l| l.uri == uri).collect()
}

/// Where each present record starts and ends, by byte offset: what a logged range
/// must line up with.
struct Records {
    starts: HashMap<u64, TileId>,
    ends: HashMap<u64, TileId>,
    header_region: u64,
}

impl Records {
    fn of(p: &Pyramid<FileSource>) -> Self {
        let g = *p.geometry();
        let (mut starts, mut ends) = (HashMap::new(), HashMap::new());
        for l in g.levels() {
            for t in g.present_tiles(l) {
                if let Some(e) = p.entry(t) {
                    starts.insert(e.offset, t);
                    ends.insert(e.end(), t);
                }
            }
        }
        Self {
            starts,
            ends,
            header_region: p.header().records_offset,
        }
    }

    /// A logged tile request: it starts at a record and ends at a record of the same
    /// level (one byte range of one level's contiguous records: a Morton range).
    fn run_of(&self, l: &Logged) -> (TileId, TileId) {
        let (a, b) = l.byte_range().unwrap_or_else(|| panic!("no Range: {l:?}"));
        let first = self.starts.get(&a).unwrap_or_else(|| {
            panic!("{l:?} does not start at a record");
        });
        let last = self.ends.get(&(b + 1)).unwrap_or_else(|| {
            panic!("{l:?} does not end at a record");
        });
        assert_eq!(first.level(), last.level(), "{l:?} spans two levels");
        (*first, *last)
    }

    /// How many records a logged tile request's range holds (all of them, whether
    /// or not the client read them to the end).
    fn count(&self, l: &Logged) -> u64 {
        let (a, b) = l.byte_range().unwrap_or_else(|| panic!("no Range: {l:?}"));
        self.starts
            .keys()
            .filter(|&&o| (a..=b).contains(&o))
            .count() as u64
    }
}

/// The open and the tile requests of one serverless flight, checked against the
/// file: the open is one request for the first 64 KiB (the whole header region of
/// the test pyramid), every other request one run of records; every request has a
/// Range header and was answered 206 (or cut off by a cancel, 499 in nginx's log).
fn check_requests(log: &[Logged], records: &Records, summary: &FlySummary) -> usize {
    let reqs = requests_for(log, "terrain.tess");
    assert!(
        records.header_region <= 65536,
        "the test pyramid's header region no longer fits the first request"
    );
    assert_eq!(
        reqs[0].range.as_deref(),
        Some("bytes=0-65535"),
        "the open: {:?}",
        reqs[0]
    );
    assert!(
        reqs.iter().all(|r| r.method == "GET" && r.range.is_some()),
        "a request without Range: {reqs:?}"
    );
    let tiles = &reqs[1..];
    for r in tiles {
        records.run_of(r);
        assert!(
            r.status == 206 || r.status == 499,
            "{r:?}: not answered with a range"
        );
        if r.status == 206 {
            let (a, b) = r.byte_range().unwrap();
            assert_eq!(r.bytes_sent, b - a + 1, "{r:?}");
        }
    }
    let s = &summary.stream;
    assert_eq!(s.ranges, s.requests, "one Morton range per request: {s:?}");
    assert!(
        tiles.len() as u64 <= s.requests && tiles.len() as u64 + s.cancelled >= s.requests,
        "nginx saw {} tile requests, the client counted {} ({} cancelled)",
        tiles.len(),
        s.requests,
        s.cancelled
    );
    tiles.len()
}

/// The key test: the same flight against the server and against nginx serving the
/// same file converges to the same selection, fetching the same tiles, with one
/// Range request per Morton range.
#[test]
fn serverless_flight_matches_the_server_flight() {
    let www = www_with_pyramid();
    let Some(nginx) = Nginx::serve(www.path()) else {
        return;
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (addr, _server) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let dir = tempfile::tempdir().unwrap();
    let path = glide(dir.path());
    // The server opened the old way (its document, then tiles as frames ask), as
    // a static file is opened: the bootstrap would bring whole levels the static
    // file fetches only as the view needs them.
    let mut server_opts = options(addr, path.clone(), 150);
    server_opts.stream.bootstrap = false;
    // Transitions over time off: a merge or split still morphing at the last frame
    // draws raised patches (more triangles), and when the last tiles arrive differs
    // between the two sources by a frame or two. The selection is what must match.
    server_opts.morph_seconds = 0.0;
    let (server_frames, server) = run_flight(&server_opts);
    let mut static_opts = serverless(options(addr, path, 150), nginx.url("terrain.tess"));
    static_opts.morph_seconds = 0.0;
    let (static_frames, serverless) = run_flight(&static_opts);
    let log = nginx.log();

    let p = Pyramid::open_file(pyramid()).unwrap();
    let records = Records::of(&p);
    let logged = check_requests(&log, &records, &serverless);
    eprintln!(
        "{:<12} {:>7} {:>7} {:>6} {:>6} {:>9} {:>8} {:>7}",
        "", "within", "2tau", "tiles", "reqs", "ranges", "bytes", "cancel"
    );
    for (name, s) in [("server", &server), ("serverless", &serverless)] {
        eprintln!(
            "{name:<12} {:>7.3} {:>7.3} {:>6} {:>6} {:>9} {:>8} {:>7}",
            s.within_tau,
            s.within_2tau,
            s.stream.tiles,
            s.stream.requests,
            s.stream.ranges,
            s.stream.bytes,
            s.stream.cancelled
        );
    }
    eprintln!("nginx: {} requests ({logged} for tiles)", log.len());

    for (frames, s) in [(&server_frames, &server), (&static_frames, &serverless)] {
        assert_no_holes(frames);
        let last = frames.last().unwrap();
        assert!(
            last.select.deficit.is_some_and(|d| d <= 1.0),
            "not converged: {:?}",
            last.select
        );
        assert_eq!(last.wanted, 0);
        assert_eq!(s.stream.failures + s.stream.corrupt, 0, "{:?}", s.stream);
    }
    // Converged, both draw the same selection of the same view.
    let (a, b) = (
        &server_frames.last().unwrap().select,
        &static_frames.last().unwrap().select,
    );
    assert_eq!(
        (a.tiles, a.coarsest_level),
        (b.tiles, b.coarsest_level),
        "{a:?} against {b:?}"
    );
    assert_eq!(a.patches, b.patches, "{a:?} against {b:?}");
    assert_eq!(a.triangles, b.triangles, "{a:?} against {b:?}");
    // Within 2τ alike (timing differs by a frame or two).
    assert!(
        (server.within_2tau - serverless.within_2tau).abs() <= 0.05,
        "within 2τ: {} against {}",
        server.within_2tau,
        serverless.within_2tau
    );
    // How many tiles each flight fetches depends on when they arrive (prefetch looks
    // ahead from what is resident), so the two counts are not compared. What holds
    // whatever the timing: the client counts no tile nginx did not send; and when
    // nothing was cancelled, it fetched each record once (the answered runs do not
    // overlap) and counted exactly the records and bytes nginx sent.
    let tile_reqs = &requests_for(&log, "terrain.tess")[1..];
    let sent_records: u64 = tile_reqs.iter().map(|l| records.count(l)).sum();
    assert!(
        serverless.stream.tiles <= sent_records,
        "{} tiles counted, {sent_records} records sent",
        serverless.stream.tiles
    );
    if serverless.stream.cancelled == 0 {
        let mut runs: Vec<(u64, u64)> = tile_reqs.iter().filter_map(|l| l.byte_range()).collect();
        runs.sort_unstable();
        for w in runs.windows(2) {
            assert!(w[0].1 < w[1].0, "a record fetched twice: {w:?}");
        }
        assert_eq!(serverless.stream.tiles, sent_records);
        let sent: u64 = tile_reqs.iter().map(|l| l.bytes_sent).sum();
        assert_eq!(serverless.stream.bytes, sent);
    }
}

/// One byte flipped in the middle of `tile`'s record, in a copy in `dir`.
fn corrupt_copy(dir: &Path, tile: TileId) -> PathBuf {
    use std::io::{Read, Seek, SeekFrom, Write};
    let out = dir.join("terrain.tess");
    std::fs::copy(pyramid(), &out).unwrap();
    let e = *Pyramid::open_file(&out).unwrap().entry(tile).unwrap();
    let at = e.offset + u64::from(e.length) / 2;
    let mut f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(&out)
        .unwrap();
    let mut b = [0u8];
    f.seek(SeekFrom::Start(at)).unwrap();
    f.read_exact(&mut b).unwrap();
    f.seek(SeekFrom::Start(at)).unwrap();
    f.write_all(&[b[0] ^ 0x5a]).unwrap();
    out
}

/// A corrupted copy served by nginx: the record fails its index checksum, so that
/// tile is reported corrupt (not a failed request), retried with backoff and written
/// off after `corrupt_attempts` reports; its siblings, fetched with it in one Range
/// request, arrive whole and are never asked for again; the flight draws on. The
/// same copy served by `tessera-server` ends the same way (the server reports the
/// record corrupt in an error frame): the same tiles written off and drawn.
#[test]
fn a_record_corrupt_in_the_file_is_reported_and_the_others_arrive() {
    let www = tempfile::tempdir().unwrap();
    // Level 1's north-west tile: under the glide, and one of four records fetched
    // with one Range request.
    let bad = TileId::new(Level::new(1).unwrap(), 0, 0).unwrap();
    let file = corrupt_copy(www.path(), bad);
    let Some(nginx) = Nginx::serve(www.path()) else {
        return;
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (addr, _server) =
        streaming_support::start_server_for(&rt, "127.0.0.1:0".parse().unwrap(), &file);
    let dir = tempfile::tempdir().unwrap();
    let opts = options(addr, glide(dir.path()), 150);
    let (server_frames, server) = run_flight(&opts);
    let opts = serverless(opts, nginx.url("terrain.tess"));
    let (frames, summary) = run_flight(&opts);
    assert_no_holes(&frames);
    let s = &summary.stream;
    assert!(s.corrupt >= 3, "{s:?}");
    assert_eq!(s.written_off, 1, "only one record is corrupt: {s:?}");
    assert_eq!(
        s.failures, 0,
        "a corrupt record is not a failed request: {s:?}"
    );
    let error = summary.last_error.as_deref().unwrap_or_default();
    assert!(
        error.contains(&bad.to_string()) && error.contains("checksum"),
        "the last error {error:?} does not name the corrupt tile"
    );
    summary.verdict().unwrap();
    // As against the server: the same write-off, the same tiles drawn at the end
    // (the root stands in for the tile it cannot refine into).
    assert_eq!(server.stream.written_off, 1, "{:?}", server.stream);
    let (a, b) = (
        &server_frames.last().unwrap().select,
        &frames.last().unwrap().select,
    );
    assert_eq!(
        (a.tiles, a.coarsest_level, a.missing),
        (b.tiles, b.coarsest_level, b.missing),
        "{a:?} against {b:?}"
    );

    // Its record was asked for at most `corrupt_attempts` times, the first time
    // together with its three siblings, which arrived whole then: their records are
    // never asked for again.
    let p = Pyramid::open_file(&file).unwrap();
    let log = nginx.log();
    let asked = |t: TileId| -> Vec<(u64, u64)> {
        let e = *p.entry(t).unwrap();
        requests_for(&log, "terrain.tess")
            .iter()
            .filter_map(|l| l.byte_range())
            .filter(|(a, b)| *a <= e.offset && e.end() <= b + 1 && *a >= p.header().records_offset)
            .collect()
    };
    let covering = asked(bad);
    assert!(
        (3..=opts.stream.corrupt_attempts as usize).contains(&covering.len()),
        "the corrupt record was asked for {} times",
        covering.len()
    );
    let siblings: Vec<TileId> = p
        .geometry()
        .present_tiles(bad.level())
        .filter(|t| *t != bad)
        .collect();
    assert_eq!(siblings.len(), 3);
    for t in siblings {
        assert_eq!(asked(t), [covering[0]], "{t}");
    }
    assert!(s.tiles >= 4, "{s:?}");
}

/// nginx killed (SIGKILL) mid-flight and restarted a second later on the same port:
/// the flight keeps drawing what it has, notices, and converges after the restart.
#[test]
fn recovers_after_nginx_is_killed_and_restarted() {
    let www = www_with_pyramid();
    let Some(mut nginx) = Nginx::serve(www.path()) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let leg = dir.path().join("leg.json");
    std::fs::write(
        &leg,
        r#"{"waypoints": [[0.1, 0.1], [0.6, 0.6]], "speed_mps": 40000, "altitude_agl_m": 400, "pitch_deg": -20}"#,
    )
    .unwrap();
    let opts = serverless(
        options(nginx.addr(), leg.to_string_lossy().into_owned(), 300),
        nginx.url("terrain.tess"),
    );
    let restarter = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(400));
        nginx.kill();
        std::thread::sleep(Duration::from_secs(1));
        nginx.start().unwrap();
        nginx
    });
    // Joined even when the flight fails, so that nginx (restarted by the thread) is
    // killed before the test ends rather than left running.
    let flight = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run_flight(&opts)));
    let nginx = restarter.join().unwrap();
    let (frames, summary) = flight.unwrap_or_else(|e| std::panic::resume_unwind(e));
    assert_recovered(&frames, &summary);
    assert!(!nginx.log().is_empty());
}

/// `tessera load --pyramid`: the report of a load against the server, field for
/// field, without errors, and about the same tiles for the same paths.
#[test]
fn load_against_nginx_reports_like_the_server() {
    use tessera_client::stream::RequestMode;
    let www = www_with_pyramid();
    let Some(nginx) = Nginx::serve(www.path()) else {
        return;
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (addr, _server) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    // The server's clients open the old way, as in the flight comparison above.
    let open = tessera_client::stream::OpenArgs {
        no_bootstrap: true,
        ..Default::default()
    };
    let run =
        |source| small_load_opened(source, 3, Duration::from_secs(3), RequestMode::Ranges, open);
    let server = run(TileSource::server(format!("http://{addr}"), "terrain"));
    let serverless = run(TileSource::pyramid(nginx.url("terrain.tess")));
    eprintln!("server:     {server}\nserverless: {serverless}");
    let keys = |r| {
        let v = serde_json::to_value(r).unwrap();
        v.as_object().unwrap().keys().cloned().collect::<Vec<_>>()
    };
    assert_eq!(keys(&server), keys(&serverless));
    for r in [&server, &serverless] {
        assert_eq!(r.errors, 0, "{r:?}");
        assert!(r.tiles_per_s > 0.0 && r.tiles > 20, "{r:?}");
    }
    let ratio = serverless.tiles as f64 / server.tiles as f64;
    assert!(
        (0.85..=1.15).contains(&ratio),
        "tiles: {} against {}",
        serverless.tiles,
        server.tiles
    );
    // Every tile request nginx saw carried a Range.
    let log = nginx.log();
    let tiles = requests_for(&log, "terrain.tess");
    assert!(tiles.iter().all(|l| l.range.is_some()), "{tiles:?}");
    assert!(
        tiles.len() as u64 <= serverless.requests + 3,
        "more than three opens and the tile requests: {}",
        tiles.len()
    );
}

/// Hosts that ignore `Range` (nginx with `max_ranges 0` answers 200 with the whole
/// file): a small pyramid is read whole, once, and flown from memory; a large file is
/// refused before its body is read, with a reason that says so.
#[test]
fn hosts_that_ignore_range_small_files_are_read_whole_large_ones_refused() {
    let www = www_with_pyramid();
    let norange = www.path().join("norange");
    std::fs::create_dir(&norange).unwrap();
    std::os::unix::fs::symlink(pyramid(), norange.join("terrain.tess")).unwrap();
    // A sparse 1 GiB file: nothing of it may be downloaded.
    let big = std::fs::File::create(norange.join("big.tess")).unwrap();
    big.set_len(1 << 30).unwrap();
    let Some(nginx) = Nginx::serve_with(www.path(), "location /norange/ { max_ranges 0; }") else {
        return;
    };
    let config = StreamConfig::default();
    let err = Streamer::open(
        &TileSource::pyramid(nginx.url("norange/big.tess")),
        config.clone(),
        None,
    )
    .unwrap_err();
    let msg = format!("{err:#}");
    assert!(
        msg.contains("ignores HTTP Range") && msg.contains("1073741824"),
        "{msg}"
    );
    let big_sent: u64 = requests_for(&nginx.log(), "norange/big.tess")
        .iter()
        .map(|l| l.bytes_sent)
        .sum();
    assert!(
        big_sent < 16 << 20,
        "{big_sent} bytes of the big file were sent: it was not refused before its body"
    );

    // The small one: read whole with one request, then every tile from memory.
    let (mut streamer, info) = Streamer::open(
        &TileSource::pyramid(nginx.url("norange/terrain.tess")),
        config,
        None,
    )
    .unwrap();
    assert_eq!(info.name, "terrain");
    let p = Pyramid::open_file(pyramid()).unwrap();
    let level1: Vec<TileId> = p.geometry().present_tiles(Level::new(1).unwrap()).collect();
    let mut pool = TilePool::new(64);
    fetch(&mut streamer, &mut pool, &level1);
    assert!(level1.iter().all(|t| pool.contains(*t)));
    let log = nginx.log();
    let reqs = requests_for(&log, "norange/terrain.tess");
    assert_eq!(reqs.len(), 1, "{reqs:?}");
    assert_eq!(reqs[0].status, 200);
}

/// Asks for `tiles` until they are resident (at most 10 s).
fn fetch(streamer: &mut Streamer, pool: &mut TilePool, tiles: &[TileId]) {
    let wanted: Vec<Wanted> = tiles
        .iter()
        .map(|&tile| Wanted { tile, rho: 1.0 })
        .collect();
    let started = std::time::Instant::now();
    while !tiles
        .iter()
        .all(|t| pool.contains(*t) || pool.is_absent(*t))
    {
        assert!(
            started.elapsed() < Duration::from_secs(10),
            "tiles never arrived: {:?}",
            streamer.last_error
        );
        streamer.frame(pool, &wanted, &[]);
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Runs `frame` until a request fails; the last error.
fn first_failure(streamer: &mut Streamer, pool: &mut TilePool, tiles: &[TileId]) -> String {
    let wanted: Vec<Wanted> = tiles
        .iter()
        .map(|&tile| Wanted { tile, rho: 1.0 })
        .collect();
    let before = streamer.stats.failures;
    let started = std::time::Instant::now();
    while streamer.stats.failures == before {
        assert!(
            started.elapsed() < Duration::from_secs(10),
            "no request failed; {:?}",
            streamer.stats
        );
        streamer.frame(pool, &wanted, &[]);
        std::thread::sleep(Duration::from_millis(5));
    }
    streamer.last_error.clone().unwrap()
}

/// A pyramid file replaced under the client (nginx's ETag and Last-Modified change
/// with the file's time): the next answer's headers say so, and it is reported as
/// the pyramid having changed under the client, its body never read as part of the
/// file.
#[test]
fn a_file_changed_under_the_client_is_reported() {
    let www = tempfile::tempdir().unwrap();
    let file = www.path().join("terrain.tess");
    std::fs::copy(pyramid(), &file).unwrap();
    let Some(nginx) = Nginx::serve(www.path()) else {
        return;
    };
    let config = StreamConfig {
        retry_base: Duration::from_millis(10),
        ..StreamConfig::default()
    };
    let (mut streamer, _) = Streamer::open(
        &TileSource::pyramid(nginx.url("terrain.tess")),
        config,
        None,
    )
    .unwrap();
    let mut pool = TilePool::new(64);
    let root = TileId::new(Level::ROOT, 0, 0).unwrap();
    fetch(&mut streamer, &mut pool, &[root]);
    // Nothing of the old file still on its way: a request that left before the file
    // changed would be answered with the old ETag, and its bytes counted, after the
    // count below is taken (seen under load).
    let wanted = [Wanted {
        tile: root,
        rho: 1.0,
    }];
    let started = std::time::Instant::now();
    while streamer.frame(&mut pool, &wanted, &[]).in_flight > 0 {
        assert!(
            started.elapsed() < Duration::from_secs(10),
            "requests never settled"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    // A new modification time: a new ETag and Last-Modified.
    let f = std::fs::File::options().write(true).open(&file).unwrap();
    f.set_modified(std::time::SystemTime::now() + Duration::from_secs(3600))
        .unwrap();
    drop(f);
    let level1: Vec<TileId> = Pyramid::open_file(&file)
        .unwrap()
        .geometry()
        .present_tiles(Level::new(1).unwrap())
        .collect();
    let bytes = streamer.stats.bytes;
    let error = first_failure(&mut streamer, &mut pool, &level1);
    assert!(
        error.contains("the pyramid changed under the client") && error.contains("ETag"),
        "{error}"
    );
    assert!(level1.iter().all(|t| !pool.contains(*t)));
    assert_eq!(
        streamer.stats.bytes, bytes,
        "bytes of the new file were counted"
    );
    // Asked for a range (no If-Range), nginx sent that range of the new file only.
    let last = nginx.log().last().cloned().unwrap();
    let (a, b) = last.byte_range().unwrap();
    assert_eq!(last.status, 206, "{last:?}");
    assert!(last.bytes_sent <= b - a + 1, "{last:?}");
}

/// What [`misbehaving_host`] does to the tile requests after the open.
const WELL: u8 = 0;
const SHORT_BODY: u8 = 1;
const NOT_SATISFIABLE: u8 = 2;

/// A static host that misbehaves on demand: it answers Range requests for the test
/// pyramid from the file, or (`mode`) with a body half as long as the range (its
/// Content-Length saying so), or with 416. Plain HTTP/1.1 over tokio, one request per
/// connection.
fn misbehaving_host(rt: &tokio::runtime::Runtime, mode: Arc<AtomicU8>) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let listener = rt
        .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
        .unwrap();
    let addr = listener.local_addr().unwrap();
    let bytes = Arc::new(std::fs::read(pyramid()).unwrap());
    rt.spawn(async move {
        loop {
            let Ok((mut sock, _)) = listener.accept().await else {
                return;
            };
            let (bytes, mode) = (bytes.clone(), mode.clone());
            tokio::spawn(async move {
                let mut req = Vec::new();
                let mut buf = [0u8; 4096];
                while !req.windows(4).any(|w| w == b"\r\n\r\n") {
                    match sock.read(&mut buf).await {
                        Ok(0) | Err(_) => return,
                        Ok(n) => req.extend_from_slice(&buf[..n]),
                    }
                }
                let text = String::from_utf8_lossy(&req).to_ascii_lowercase();
                let range = text
                    .lines()
                    .find_map(|l| l.strip_prefix("range: bytes="))
                    .and_then(|r| r.trim().split_once('-'))
                    .and_then(|(a, b)| Some((a.parse::<u64>().ok()?, b.parse::<u64>().ok()?)));
                let total = bytes.len() as u64;
                let Some((a, b)) = range else { return };
                let b = b.min(total - 1);
                let open = a == 0;
                let head = |status: &str, len: u64| {
                    format!(
                        "HTTP/1.1 {status}\r\nContent-Range: bytes {a}-{b}/{total}\r\nContent-Length: {len}\r\nETag: \"v1\"\r\nConnection: close\r\n\r\n"
                    )
                };
                let (head, body) = match mode.load(Ordering::SeqCst) {
                    NOT_SATISFIABLE if !open => (
                        format!(
                            "HTTP/1.1 416 Range Not Satisfiable\r\nContent-Range: bytes */{total}\r\nContent-Length: 0\r\nETag: \"v1\"\r\nConnection: close\r\n\r\n"
                        ),
                        &bytes[0..0],
                    ),
                    SHORT_BODY if !open => {
                        let half = (b - a).div_ceil(2);
                        (head("206 Partial Content", half), &bytes[a as usize..(a + half) as usize])
                    }
                    _ => (
                        head("206 Partial Content", b - a + 1),
                        &bytes[a as usize..=b as usize],
                    ),
                };
                let _ = sock.write_all(head.as_bytes()).await;
                let _ = sock.write_all(body).await;
                let _ = sock.shutdown().await;
            });
        }
    });
    format!("http://{addr}/terrain.tess")
}

/// A body shorter than the range asked for, and a 416: each fails its request with
/// a reason that says so; the records of a short body that did arrive whole are
/// kept; and once the host behaves again, everything arrives.
#[test]
fn short_bodies_and_416_are_reported_and_survived() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let mode = Arc::new(AtomicU8::new(WELL));
    let url = misbehaving_host(&rt, mode.clone());
    let config = StreamConfig {
        retry_base: Duration::from_millis(10),
        retry_max: Duration::from_millis(50),
        ..StreamConfig::default()
    };
    let (mut streamer, _) = Streamer::open(&TileSource::pyramid(url), config, None).unwrap();
    let p = Pyramid::open_file(pyramid()).unwrap();
    let level1: Vec<TileId> = p.geometry().present_tiles(Level::new(1).unwrap()).collect();
    let level2: Vec<TileId> = p
        .geometry()
        .present_tiles(Level::new(2).unwrap())
        .take(4)
        .collect();
    let mut pool = TilePool::new(64);

    mode.store(SHORT_BODY, Ordering::SeqCst);
    let error = first_failure(&mut streamer, &mut pool, &level1);
    assert!(error.contains("short body"), "{error}");
    // Half of four records' bytes hold the first one or two whole: those arrived.
    let arrived = level1.iter().filter(|t| pool.contains(**t)).count();
    assert!((1..level1.len()).contains(&arrived), "{arrived} arrived");

    mode.store(NOT_SATISFIABLE, Ordering::SeqCst);
    let error = first_failure(&mut streamer, &mut pool, &level2);
    assert!(error.contains("416"), "{error}");

    mode.store(WELL, Ordering::SeqCst);
    let all: Vec<TileId> = level1.iter().chain(&level2).copied().collect();
    fetch(&mut streamer, &mut pool, &all);
    assert_eq!(streamer.stats.corrupt, 0, "{:?}", streamer.stats);
}

/// `--pyramid file:///…`: the same reads from a local file, no HTTP at all.
#[test]
fn file_urls_read_the_local_file() {
    let (mut streamer, info) = Streamer::open(
        &TileSource::pyramid(format!("file://{}", pyramid().display())),
        StreamConfig::default(),
        None,
    )
    .unwrap();
    let p = Pyramid::open_file(pyramid()).unwrap();
    assert_eq!(
        info,
        tessera_shared::api::DatasetInfo::new(
            "terrain",
            p.metadata(),
            p.header().version,
            std::fs::metadata(pyramid()).unwrap().len()
        ),
        "the document the server would send"
    );
    let tiles: Vec<TileId> = p.geometry().present_tiles(Level::new(2).unwrap()).collect();
    let mut pool = TilePool::new(64);
    fetch(&mut streamer, &mut pool, &tiles);
    for t in &tiles {
        let want = p.read_tile(*t).unwrap().unwrap();
        assert_eq!(pool.get(*t).unwrap().heights, want.heights, "{t}");
    }
}
