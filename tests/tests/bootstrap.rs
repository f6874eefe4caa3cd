//! One round trip to the first drawable frame (DECISIONS.md "The first view in one round
//! trip"). The bootstrap (`GET /v1/datasets/{name}/bootstrap`, API.md) against the routes
//! it stands in for, its caching, its damage, and flights that open with it (or without
//! it) through a proxy that adds 150 ms to every response — all over real sockets to a
//! real server.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared fixtures
mod streaming_support;

use std::fmt::Write as _;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::PathBuf;
use std::time::Duration;
use streaming_support::{glide, options, run_flight, start_server, start_server_for};
use tessera_client::paths::FlyPath;
use tessera_proxy::{Config, Delay, Proxy, RequestLog, Responses};
use tessera_shared::api::DatasetInfo;
use tessera_shared::bootstrap::{Bootstrap, BootstrapError};
use tessera_shared::focus::Focus;
use tessera_shared::wire::{self, Frame};

/// A response: status, head (lower-cased names) and body.
struct Answer {
    status: u16,
    head: String,
    body: Vec<u8>,
}

impl Answer {
    fn header(&self, name: &str) -> Option<String> {
        self.head.lines().find_map(|l| {
            let (k, v) = l.split_once(':')?;
            k.trim()
                .eq_ignore_ascii_case(name)
                .then(|| v.trim().to_string())
        })
    }
}

/// One `GET` over HTTP/1.0 (no chunking, no keep-alive) with extra header lines.
fn get(addr: SocketAddr, path: &str, headers: &[(&str, &str)]) -> Answer {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    let mut req = format!("GET {path} HTTP/1.0\r\nHost: {addr}\r\n");
    for (k, v) in headers {
        let _ = write!(req, "{k}: {v}\r\n");
    }
    req.push_str("\r\n");
    s.write_all(req.as_bytes()).unwrap();
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).unwrap();
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .unwrap_or_else(|| panic!("no response head from {addr}{path}"));
    let head = String::from_utf8_lossy(&raw[..split]).into_owned();
    let status = head.split_whitespace().nth(1).unwrap().parse().unwrap();
    Answer {
        status,
        head,
        body: raw[split + 4..].to_vec(),
    }
}

const BOOT: &str = "/v1/datasets/terrain/bootstrap";

fn fetch_bootstrap(addr: SocketAddr) -> (Answer, Bootstrap) {
    let a = get(addr, BOOT, &[]);
    assert_eq!(a.status, 200, "{}", String::from_utf8_lossy(&a.body));
    assert_eq!(
        a.header("content-type").as_deref(),
        Some("application/vnd.tessera.bootstrap")
    );
    let b = Bootstrap::decode(&a.body).unwrap();
    (a, b)
}

/// The frames of one level's Morton-range stream (`kind` `tiles` or `errors`) of
/// the whole level, without the trailer.
fn level_frames(addr: SocketAddr, name: &str, level: u8, kind: &str) -> Vec<Frame> {
    let last = (1u64 << (2 * u32::from(level))) - 1;
    let path = format!("/v1/datasets/{name}/levels/{level}/{kind}?ranges=0-{last}");
    let a = get(addr, &path, &[]);
    assert_eq!(a.status, 200, "{path}");
    let mut frames = wire::decode_all(&a.body).unwrap();
    assert!(matches!(frames.pop(), Some(Frame::Trailer { .. })));
    frames
}

/// A 4097² synthetic terrain in 512-cell tiles, named `coarse`: its bootstrap
/// carries records of the coarsest levels and error tables of the next ones.
fn coarse_pyramid(dir: &std::path::Path) -> PathBuf {
    let out = dir.join("coarse.tess");
    let opts = tessera_server::builder::BuildOptions {
        tile_size: 512,
        ..tessera_server::builder::BuildOptions::default()
    };
    tessera_server::builder::build("synthetic:4097:11", &out, &opts).unwrap();
    out
}

/// The levels the budgets choose for the pyramid `file`
/// ([`tessera_shared::bootstrap::plan`], as the server plans it).
fn planned_levels(file: &std::path::Path) -> (u8, u8) {
    tessera_shared::bootstrap::plan(&tessera_shared::Pyramid::open_file(file).unwrap())
}

/// The bootstrap's document is the dataset route's, its records are byte for byte
/// the Morton-range stream's of the same levels, and its error tables the error
/// route's: for the test terrain and for a pyramid of larger tiles, whose levels the
/// byte budgets split into records and error tables (the levels asked for are the
/// ones `plan_levels` gives for each file).
#[test]
fn the_bootstrap_is_what_the_individual_routes_send() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (terrain, _a) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let coarse_file = coarse_pyramid(dir.path());
    let (coarse, _b) = start_server_for(&rt, "127.0.0.1:0".parse().unwrap(), &coarse_file);
    for (addr, name, file) in [
        (
            terrain,
            "terrain",
            streaming_support::pyramid().to_path_buf(),
        ),
        (coarse, "coarse", coarse_file.clone()),
    ] {
        let levels = planned_levels(&file);
        let a = get(addr, &format!("/v1/datasets/{name}/bootstrap"), &[]);
        assert_eq!(a.status, 200, "{name}");
        let b = Bootstrap::decode(&a.body).unwrap();
        let doc = get(addr, &format!("/v1/datasets/{name}"), &[]);
        let info: DatasetInfo = serde_json::from_slice(&doc.body).unwrap();
        assert_eq!(b.info, info, "{name}");
        assert_eq!(
            (b.record_levels, b.table_levels),
            levels,
            "{name}: the budgets' levels"
        );
        if name == "coarse" {
            assert!(
                b.record_levels >= 2 && b.table_levels > b.record_levels,
                "the coarse pyramid should have records beyond the root and table levels: {levels:?}"
            );
        }
        let mut expected = Vec::new();
        for level in 0..b.record_levels {
            let frames = level_frames(addr, name, level, "tiles");
            assert!(!frames.is_empty());
            expected.extend(frames);
        }
        for level in b.record_levels..b.table_levels {
            expected.extend(level_frames(addr, name, level, "errors"));
        }
        assert_eq!(b.frames.len(), expected.len(), "{name}");
        // Frame equality compares every record and table byte, checksum and min/max.
        assert!(
            b.frames == expected,
            "{name}: the bootstrap's frames differ from the routes'"
        );
        assert!(
            b.absent().is_empty(),
            "a synthetic terrain has no no-data tile"
        );
    }
}

/// Strong ETag from the content hash, a 304 for it, immutable caching under
/// `?v=<content hash>`, revalidated caching without.
#[test]
fn the_bootstrap_is_cacheable_and_pinned_by_the_content_hash() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (addr, _server) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let (a, b) = fetch_bootstrap(addr);
    let etag = a.header("etag").expect("an ETag");
    assert!(
        etag.starts_with(&format!("\"{}", b.info.content_hash)) && !etag.starts_with("W/"),
        "{etag}"
    );
    let cc = a.header("cache-control").unwrap();
    assert!(
        cc.starts_with("public, max-age=") && !cc.contains("immutable"),
        "{cc}"
    );
    let again = get(addr, BOOT, &[("If-None-Match", &etag)]);
    assert_eq!(again.status, 304);
    assert!(again.body.is_empty());
    assert_eq!(again.header("etag").as_deref(), Some(etag.as_str()));
    let other = get(addr, BOOT, &[("If-None-Match", "\"0000000000000000\"")]);
    assert_eq!(other.status, 200);
    assert_eq!(other.body, a.body, "the same dataset, the same bytes");
    let pinned = get(addr, &format!("{BOOT}?v={}", b.info.content_hash), &[]);
    assert_eq!(pinned.status, 200);
    assert_eq!(
        pinned.header("cache-control").as_deref(),
        Some("public, max-age=31536000, immutable")
    );
    assert_eq!(pinned.body, a.body);
    let unknown = get(addr, "/v1/datasets/nosuch/bootstrap", &[]);
    assert_eq!(unknown.status, 404);
    assert!(String::from_utf8_lossy(&unknown.body).contains("nosuch"));
}

/// A body cut short anywhere, or with any frame or the document damaged, is an
/// error that says what is wrong; never a panic, never a partial bootstrap.
#[test]
fn a_truncated_or_damaged_bootstrap_is_an_error_naming_the_problem() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (addr, _server) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let (a, _) = fetch_bootstrap(addr);
    let body = a.body;
    let n = body.len();
    for cut in [0, 5, 23, 24, 100, n / 3, n / 2, n - 33, n - 1] {
        let e = Bootstrap::decode(&body[..cut]).unwrap_err();
        assert!(e.to_string().contains("truncated"), "cut at {cut}: {e}");
    }
    let damaged = |at: usize| {
        let mut b = body.clone();
        b[at] ^= 0x40;
        Bootstrap::decode(&b).unwrap_err()
    };
    assert_eq!(damaged(0), BootstrapError::Magic);
    assert_eq!(damaged(40), BootstrapError::DocumentChecksum);
    // A byte inside a record: the frame's checksum names the tile.
    let e = damaged(n / 2).to_string();
    assert!(
        e.contains("fails its checksum") || e.contains("malformed") || e.contains("frame"),
        "{e}"
    );
    // Every 997th byte flipped: never a panic, and an error unless the byte is one of
    // a frame's min/max heights — the only bytes no checksum covers (the wire
    // format's frame header; noted for the format's next version). Which bytes land
    // there moves with the document's length.
    let original = Bootstrap::decode(&body).unwrap();
    let without_bounds = |frames: &[Frame]| -> Vec<Frame> {
        frames
            .iter()
            .cloned()
            .map(|f| match f {
                Frame::Tile {
                    level,
                    morton,
                    checksum,
                    record,
                    ..
                } => Frame::Tile {
                    level,
                    morton,
                    checksum,
                    min: 0,
                    max: 0,
                    record,
                },
                Frame::ErrorTable {
                    level,
                    morton,
                    table,
                    ..
                } => Frame::ErrorTable {
                    level,
                    morton,
                    min: 0,
                    max: 0,
                    table,
                },
                other => other,
            })
            .collect()
    };
    for at in (0..n).step_by(997) {
        let mut b = body.clone();
        b[at] ^= 0x40;
        if let Ok(decoded) = Bootstrap::decode(&b) {
            assert_eq!(decoded.info, original.info, "byte {at}");
            assert_eq!(
                without_bounds(&decoded.frames),
                without_bounds(&original.frames),
                "byte {at} changed more than a frame's min/max and was not an error"
            );
        }
    }
}

/// A proxy adding 150 ms before every response, logging every request line.
fn slow_logged(rt: &tokio::runtime::Runtime, server: SocketAddr) -> (Proxy, RequestLog) {
    let log = RequestLog::default();
    let config = Config {
        responses: Responses::Delay(Delay::new(Duration::from_millis(150))),
        requests: Some(log.clone()),
        ..Config::new(server)
    };
    (rt.block_on(Proxy::start(config)).unwrap(), log)
}

/// At +150 ms, a flight opened with the bootstrap draws the root level in frame 0,
/// and the server saw one request before it (every later one a tile stream asked for
/// by a frame). Without it (`--no-bootstrap`), frame 0 is empty and the open was the
/// dataset's document; the flight still works.
#[test]
fn frame_zero_is_drawn_after_one_request_and_no_bootstrap_still_flies() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (server, _task) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let dir = tempfile::tempdir().unwrap();

    let (proxy, log) = slow_logged(&rt, server);
    let opts = options(proxy.addr(), glide(dir.path()), 60);
    let (frames, summary) = run_flight(&opts);
    let first = &frames[0];
    assert!(
        first.select.tiles > 0 && first.select.missing == 0,
        "frame 0 drew {:?}",
        first.select
    );
    assert_eq!(summary.frames_drawn, summary.frames, "every frame draws");
    let targets = log.targets();
    assert_eq!(targets[0], BOOT, "{targets:?}");
    assert_eq!(
        targets.len() as u64,
        1 + summary.stream.requests,
        "the open made one request, the frames the rest: {targets:?}"
    );
    assert!(
        targets[1..].iter().all(|t| t.contains("/levels/")),
        "{targets:?}"
    );

    let (proxy, log) = slow_logged(&rt, server);
    let mut old = options(proxy.addr(), glide(dir.path()), 60);
    old.stream.bootstrap = false;
    let (frames, summary) = run_flight(&old);
    assert_eq!(
        frames[0].select.tiles, 0,
        "without the bootstrap frame 0 has nothing yet"
    );
    assert!(
        summary.frames_drawn > 0,
        "the flight without the bootstrap drew nothing"
    );
    let targets = log.targets();
    assert_eq!(targets[0], "/v1/datasets/terrain", "{targets:?}");
    assert!(
        !targets.iter().any(|t| t.contains("bootstrap")),
        "{targets:?}"
    );
}

/// `?focus=U,V`: beside what every client gets, the records of the tiles the focus
/// names ([`Focus::tiles`]) on every finer level, byte for byte the tile route's, in
/// place of their error tables on the table levels; its own ETag and 304; a focus
/// that is not a point of the dataset is a 400 that names it.
#[test]
fn a_focused_bootstrap_adds_the_records_around_the_point() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let file = coarse_pyramid(dir.path());
    let (addr, _server) = start_server_for(&rt, "127.0.0.1:0".parse().unwrap(), &file);
    let plain = get(addr, "/v1/datasets/coarse/bootstrap", &[]);
    let plain_boot = Bootstrap::decode(&plain.body).unwrap();
    let focus = Focus::new(0.3, 0.8).unwrap();
    let path = format!("/v1/datasets/coarse/bootstrap?focus={}", focus.to_query());
    let a = get(addr, &path, &[]);
    assert_eq!(a.status, 200, "{}", String::from_utf8_lossy(&a.body));
    let b = Bootstrap::decode(&a.body).unwrap();
    assert_eq!(b.info, plain_boot.info);
    let (r, e) = (b.record_levels, b.table_levels);
    assert_eq!((r, e), (plain_boot.record_levels, plain_boot.table_levels));
    let g =
        tessera_shared::TileGeometry::new(b.info.width, b.info.height, b.info.tile_size).unwrap();
    assert!(
        g.level_count() > r,
        "the pyramid must have levels to focus on"
    );
    let mut expected = Vec::new();
    for level in g.levels() {
        let l = level.get();
        let near = focus.tiles(&g, level);
        let all = if l < e {
            level_frames(addr, "coarse", l, "tiles")
        } else {
            let ranges = tessera_shared::range_query::format(&tessera_shared::morton::coalesce(
                near.iter().map(|t| t.morton()),
            ));
            let a = get(
                addr,
                &format!("/v1/datasets/coarse/levels/{l}/tiles?ranges={ranges}"),
                &[],
            );
            let mut frames = wire::decode_all(&a.body).unwrap();
            frames.pop();
            frames
        };
        let tables = if (r..e).contains(&l) {
            level_frames(addr, "coarse", l, "errors")
        } else {
            Vec::new()
        };
        for (k, f) in all.into_iter().enumerate() {
            let Frame::Tile { morton, .. } = &f else {
                panic!("{f:?}")
            };
            let tile = tessera_shared::TileId::from_morton(level, *morton).unwrap();
            if l < r || near.contains(&tile) {
                expected.push(f);
            } else if l < e {
                expected.push(tables[k].clone());
            }
        }
        if l >= r {
            assert!(!near.is_empty() && near.len() <= 16, "level {l}: {near:?}");
        }
    }
    assert!(
        b.frames == expected,
        "the focused bootstrap's frames differ from the routes' ({} against {})",
        b.frames.len(),
        expected.len()
    );
    // Finer records than the plain bootstrap's: it carries none below R.
    let finest = |b: &Bootstrap| {
        b.frames
            .iter()
            .filter_map(|f| match f {
                Frame::Tile { level, .. } => Some(level.get()),
                _ => None,
            })
            .max()
    };
    assert_eq!(finest(&plain_boot), Some(r - 1));
    assert_eq!(finest(&b), Some(g.finest().get()));
    // Caching: its own strong ETag, revalidated; the plain one does not match it.
    let etag = a.header("etag").unwrap();
    assert_ne!(Some(&etag), plain.header("etag").as_ref());
    assert_eq!(get(addr, &path, &[("If-None-Match", &etag)]).status, 304);
    let plain_etag = plain.header("etag").unwrap();
    assert_eq!(
        get(addr, &path, &[("If-None-Match", &plain_etag)]).status,
        200
    );
    // Four decimals: a point a hundred-thousandth away is the same body.
    let near_path = "/v1/datasets/coarse/bootstrap?focus=0.30001,0.79999";
    assert_eq!(get(addr, near_path, &[]).body, a.body);
    for bad in ["2,0", "0.5", "x,1", "0.1,0.2,0.3"] {
        let a = get(
            addr,
            &format!("/v1/datasets/coarse/bootstrap?focus={bad}"),
            &[],
        );
        assert_eq!(a.status, 400, "{bad}");
        let reason: serde_json::Value = serde_json::from_slice(&a.body).unwrap();
        assert!(reason.to_string().contains("focus"), "{bad}: {reason}");
    }
}

/// At +150 ms, a low flight opened with a bootstrap focused on its start meets 2τ
/// from frame 0 through the first round trip (nothing else can have arrived by
/// then); opened with the bootstrap every client shares, frame 0 is drawn but too
/// coarse for its view (the test can fail), and only tile requests made during
/// the flight bring the detail. The pyramid has 512-cell tiles (15 km at the
/// flight's 30 m spacing): the focus's 4 × 4 tiles per level then hold the view
/// (with 128-cell tiles they hold its near part only; DECISIONS.md "The first view
/// in one round trip").
#[test]
fn a_bootstrap_focused_on_the_start_meets_two_tau_from_frame_zero() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let file = coarse_pyramid(dir.path());
    let (server, _task) = start_server_for(&rt, "127.0.0.1:0".parse().unwrap(), &file);
    let coarse = |addr: SocketAddr, path: String| {
        let mut o = options(addr, path, 30);
        o.source = tessera_client::stream::TileSource::server(format!("http://{addr}"), "coarse");
        o
    };
    let path = glide(dir.path());
    // 150 ms is 9 frames at 60 fps: no tile request made in a frame is answered
    // before frame 9.
    let first_trip = 9;
    let (proxy, log) = slow_logged(&rt, server);
    let mut opts = coarse(proxy.addr(), path.clone());
    opts.stream.focus = FlyPath::start_focus(&path, 0.0);
    assert!(opts.stream.focus.is_some());
    let (frames, _) = run_flight(&opts);
    let targets = log.targets();
    assert!(targets[0].contains("bootstrap?focus="), "{targets:?}");
    for f in &frames[..first_trip] {
        assert!(
            f.select.within(2.0),
            "frame {}: {:?} (focused on {:?})",
            f.frame,
            f.select,
            opts.stream.focus
        );
    }

    let (proxy, _log) = slow_logged(&rt, server);
    let opts = coarse(proxy.addr(), path);
    assert!(opts.stream.focus.is_none());
    let (frames, _) = run_flight(&opts);
    assert!(frames[0].select.tiles > 0, "frame 0 is drawn");
    assert!(
        !frames[0].select.within(2.0),
        "the shared bootstrap met 2τ at frame 0 too ({:?}): this flight cannot tell them apart",
        frames[0].select
    );
}

/// `--http2`: the flight speaks h2c with prior knowledge to the server (which speaks
/// it beside HTTP/1.1 on one port). Through a proxy that records HTTP/1.1 request
/// lines, none is seen, and every tile request shares one connection (the open's
/// own connection aside) instead of one per request in flight.
#[test]
fn http2_flights_share_one_connection() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (server, _task) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let dir = tempfile::tempdir().unwrap();
    let (proxy, log) = rt.block_on(tessera_proxy::logging(server)).unwrap();
    let mut opts = options(proxy.addr(), glide(dir.path()), 90);
    opts.stream.http2 = true;
    let (frames, summary) = run_flight(&opts);
    assert!(frames[0].select.tiles > 0, "frame 0 draws over HTTP/2 too");
    assert!(
        summary.stream.requests > 1 && summary.stream.failures == 0,
        "{:?}",
        summary.stream
    );
    assert!(
        log.targets().is_empty(),
        "HTTP/1.1 request lines over --http2: {:?}",
        log.targets()
    );
    assert_eq!(
        proxy.stats().connections,
        2,
        "the open's connection and one for every tile request"
    );
    // The same flight over HTTP/1.1 opens a connection per request in flight.
    let (proxy, log) = rt.block_on(tessera_proxy::logging(server)).unwrap();
    let (_, summary) = run_flight(&options(proxy.addr(), glide(dir.path()), 90));
    assert_eq!(log.targets().len() as u64, 1 + summary.stream.requests);
    assert!(proxy.stats().connections > 2, "{:?}", proxy.stats());
}
