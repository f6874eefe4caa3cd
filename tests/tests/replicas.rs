//! Stateless replicas (DECISIONS.md "Stateless replicas";
//! docs/ARCHITECTURE.md#scale-out): two `tessera-server serve s3://…` processes over the
//! same object in a real S3 server on loopback (moto, `tessera_shared::s3_server`),
//! behind nginx as a round-robin load balancer (`tessera_e2e::nginx::Nginx::balance`:
//! `proxy_next_upstream error timeout http_502 http_503`, passive health with
//! `max_fails`/`fail_timeout`), its access log recording which replica answered each
//! request.
//!
//! - both replicas and the front answer every record of every level with the same
//!   bytes; `tessera load` through the front is served by both without an error, and a
//!   flight through the front settles on the selection it settles on against one
//!   replica alone;
//! - one replica killed with SIGKILL mid-load: the load finishes with at most as many
//!   errors as requests can be in flight at once (the measured figure is printed),
//!   flights through the front recover and converge, and every request that starts
//!   after nginx noticed goes to the survivor alone;
//! - `/healthz/live` stays 200 while the store is down and `/healthz/ready` says 503
//!   naming the object; the same bytes put back, ready is 200 again.
//!
//! A replica is this test binary again, filtered to [`replica_process`], which runs
//! `tessera_server::serve::run` as `tessera-server serve` does (the server's binary is
//! not built for this crate's tests), so it is a process of its own to SIGKILL.
//! Without moto or nginx a test prints `SKIPPED`, or fails when `CI` is set.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared fixtures
mod streaming_support;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::PathBuf;
use std::process::{Child, ChildStdout, Command, ExitStatus, Stdio};
use std::time::{Duration, SystemTime};
use streaming_support::{assert_no_holes, glide, options, pyramid, run_flight, small_load};
use tessera_client::app::fly::{FlyOptions, FlySummary, FrameRecord};
use tessera_client::app::load_test::LoadReport;
use tessera_client::stream::{RequestMode, StreamConfig, TileSource};
use tessera_e2e::nginx::{Logged, Nginx, nginx_or_skip};
use tessera_shared::s3_server::S3Server;
use tessera_shared::{FileSource, Pyramid};

const BUCKET: &str = "tessera";
const KEY: &str = "terrain.tess";
/// What every replica serves (dataset `terrain`, after the object's stem).
const URL: &str = "s3://tessera/terrain.tess";

/// Passive health of each replica in the front's upstream: one failure leaves it out
/// for longer than any of these tests runs, so "after nginx noticed" is a clean cut.
const HEALTH: &str = "max_fails=1 fail_timeout=120s";

/// Set in a copy of this test binary that only serves: the object's URL.
const CHILD_URL: &str = "TESSERA_TEST_REPLICA_URL";

/// Not a test of its own: the body of a replica process (this binary again, with
/// [`CHILD_URL`] and the store's `AWS_*` variables set): `tessera-server serve URL
/// --listen 127.0.0.1:0`, which prints `listening on http://ADDR`. Ignored, so a
/// plain run skips it.
#[test]
#[ignore = "run only as a replica process of the other tests"]
fn replica_process() {
    let Some(url) = std::env::var_os(CHILD_URL) else {
        return;
    };
    let settings = tessera_server::serve::config::Settings {
        listen: "127.0.0.1:0".parse().unwrap(),
        datasets: vec![PathBuf::from(url)],
        ..Default::default()
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(tessera_server::serve::run(settings)).unwrap();
}

/// A replica process, killed (SIGKILL) when dropped.
struct Replica {
    child: Child,
    addr: SocketAddr,
    /// Where it says where it listens; kept open, so that it never writes to a
    /// closed pipe.
    stdout: BufReader<ChildStdout>,
}

impl Replica {
    /// Starts one against the store whose environment is `env` and waits until it
    /// says where it listens (it has opened the object by then).
    fn start(env: &[(String, String)]) -> Self {
        let mut child = Command::new(std::env::current_exe().unwrap())
            .args(["--exact", "replica_process", "--ignored", "--nocapture"])
            .env(CHILD_URL, URL)
            .envs(env.iter().map(|(k, v)| (k, v)))
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap();
        let stdout = BufReader::new(child.stdout.take().unwrap());
        // Owned at once, so that a panic below still kills and reaps it.
        let mut r = Self {
            child,
            addr: SocketAddr::from(([0, 0, 0, 0], 0)),
            stdout,
        };
        let mut said = String::new();
        loop {
            let mut line = String::new();
            let n = r.stdout.read_line(&mut line).unwrap();
            assert!(n > 0, "the replica exited before listening: {said}");
            if let Some(addr) = line.trim().strip_prefix("listening on http://") {
                r.addr = addr.parse().unwrap();
                return r;
            }
            said.push_str(&line);
        }
    }

    /// SIGKILL, as a crash or an OOM kill would end it.
    fn kill(&mut self) -> ExitStatus {
        self.child.kill().unwrap();
        self.child.wait().unwrap()
    }
}

impl Drop for Replica {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// One `GET` with HTTP/1.0 (so the body is neither chunked nor kept alive): status
/// and body.
fn get(addr: SocketAddr, path: &str) -> (u16, Vec<u8>) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    write!(s, "GET {path} HTTP/1.0\r\nHost: {addr}\r\n\r\n").unwrap();
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).unwrap();
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .unwrap_or_else(|| panic!("no response head from {addr}{path}"));
    let head = String::from_utf8_lossy(&raw[..split]);
    let status = head.split_whitespace().nth(1).unwrap().parse().unwrap();
    (status, raw[split + 4..].to_vec())
}

/// The JSON body of a `GET` that must answer `status`.
fn get_json(addr: SocketAddr, path: &str, status: u16) -> serde_json::Value {
    let (got, body) = get(addr, path);
    let text = String::from_utf8_lossy(&body);
    assert_eq!(got, status, "{addr}{path}: {text}");
    serde_json::from_slice(&body).unwrap_or_else(|e| panic!("{addr}{path}: {e}: {text}"))
}

/// The test pyramid in a fresh store: its bytes, and the store.
fn store() -> Option<(S3Server, Vec<u8>)> {
    let s3 = S3Server::start_or_skip()?;
    let bytes = std::fs::read(pyramid()).unwrap();
    s3.create_bucket(BUCKET);
    s3.put(BUCKET, KEY, &bytes);
    Some((s3, bytes))
}

/// The store, two replicas of it, and nginx in front of both.
struct Cluster {
    front: Nginx,
    replicas: [Replica; 2],
    /// Every level's records as one Morton range stream: the path, and what both
    /// replicas answered.
    levels: Vec<(String, Vec<u8>)>,
    _s3: S3Server,
    /// One cluster under load at a time: two would share these two cores.
    _turn: std::sync::MutexGuard<'static, ()>,
}

impl Cluster {
    /// `None` (after a SKIPPED line) without nginx or moto. Reads every record from
    /// each replica (the same bytes from both), so their block caches are warm and
    /// the load measures the replicas rather than moto.
    fn start() -> Option<Self> {
        static TURN: std::sync::Mutex<()> = std::sync::Mutex::new(());
        if !nginx_or_skip() {
            return None;
        }
        let turn = TURN
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let (s3, _) = store()?;
        let replicas = [Replica::start(&s3.env()), Replica::start(&s3.env())];
        let p: Pyramid<FileSource> = Pyramid::open_file(pyramid()).unwrap();
        let levels = p
            .geometry()
            .levels()
            .map(|level| {
                let last = (1u64 << (2 * level.get())) - 1;
                let path = format!("/v1/datasets/terrain/levels/{level}/tiles?ranges=0-{last}");
                let (status, body) = get(replicas[0].addr, &path);
                assert_eq!(status, 200, "{path}");
                assert!(!body.is_empty(), "{path}");
                assert!(
                    get(replicas[1].addr, &path) == (200, body.clone()),
                    "{path}: the replicas differ"
                );
                (path, body)
            })
            .collect();
        let front = Nginx::balance(&[replicas[0].addr, replicas[1].addr], HEALTH)?;
        Some(Self {
            front,
            replicas,
            levels,
            _s3: s3,
            _turn: turn,
        })
    }

    fn addrs(&self) -> [SocketAddr; 2] {
        [self.replicas[0].addr, self.replicas[1].addr]
    }
}

/// `tessera load` with `clients` against `server` for `duration` (the options of the
/// other load tests: 30 fps, τ = 2, 640×360, 30 m spacing).
fn load_against(server: SocketAddr, clients: u32, duration: Duration) -> LoadReport {
    small_load(
        TileSource::server(format!("http://{server}"), "terrain"),
        clients,
        duration,
        RequestMode::Ranges,
    )
}

/// The front's log lines for tile streams (what the clients ask for).
fn tile_requests(log: &[Logged]) -> Vec<&Logged> {
    log.iter()
        .filter(|l| l.uri.starts_with("/v1/datasets/terrain/levels/") && l.uri.ends_with("/tiles"))
        .collect()
}

/// The replica that answered: the last upstream tried.
fn answered_by(l: &Logged) -> Option<SocketAddr> {
    l.upstreams().last().copied()
}

/// A flight's end: no holes, and at the end every wanted tile has arrived and the
/// view is drawn within τ.
fn assert_converged(who: &str, frames: &[FrameRecord]) {
    assert_no_holes(frames);
    let last = frames.last().unwrap();
    assert!(
        last.select.deficit.is_some_and(|d| d <= 1.0) && last.wanted == 0,
        "{who}: not converged at the end: deficit {:?}, {} tiles still wanted",
        last.select.deficit,
        last.wanted
    );
}

/// Both replicas, and the front, answer every record of every level with the same
/// bytes; `tessera load` through the front (8 clients) is answered by both replicas
/// without an error, as it is by one alone; a flight through the front settles on the
/// same selection, the same tiles drawn, as against one replica alone.
#[test]
fn replicas_behind_nginx_share_the_load_and_answer_alike() {
    let Some(c) = Cluster::start() else {
        return;
    };
    let [a, b] = c.addrs();
    let front = c.front.addr();

    // Every record of every level, one Morton range stream per level: the replicas
    // answered alike (Cluster::start), and so does the front, twice (round robin:
    // once from each).
    for (path, alone) in &c.levels {
        for _ in 0..2 {
            assert!(
                get(front, path) == (200, alone.clone()),
                "{path}: the front differs"
            );
        }
    }
    let log = c.front.log();
    for r in [a, b] {
        assert!(
            tile_requests(&log)
                .iter()
                .any(|l| answered_by(l) == Some(r)),
            "{r} answered none of the level streams through the front"
        );
    }
    c.front.clear_log();

    // The load: both replicas serve it, round robin, and nobody sees an error.
    let clients = 8;
    let through = load_against(front, clients, Duration::from_secs(3));
    let log = c.front.log();
    let tiles = tile_requests(&log);
    let by = |r| tiles.iter().filter(|l| answered_by(l) == Some(r)).count();
    let (by_a, by_b) = (by(a), by(b));
    let alone = load_against(a, clients, Duration::from_secs(3));
    eprintln!("through nginx: {through}\none replica:   {alone}");
    eprintln!(
        "tiles: {} through nginx in {} requests, {} from one replica in {} requests; nginx: {} \
         tile requests, {by_a} answered by replica A, {by_b} by replica B",
        through.tiles,
        through.requests,
        alone.tiles,
        alone.requests,
        tiles.len()
    );
    for r in [&through, &alone] {
        assert_eq!(r.errors, 0, "{r:?}");
        assert!(r.tiles > 20, "{r:?}");
    }
    // The same tiles for the same paths, give or take prefetch timing.
    let ratio = through.tiles as f64 / alone.tiles as f64;
    assert!(
        (0.75..=1.33).contains(&ratio),
        "tiles: {} through nginx, {} from one replica",
        through.tiles,
        alone.tiles
    );
    assert_eq!(by_a + by_b, tiles.len(), "a request nobody answered");
    assert!(
        tiles.iter().all(|l| l.status == 200 || l.status == 499),
        "{:?}",
        tiles.iter().find(|l| l.status != 200 && l.status != 499)
    );
    assert!(
        by_a * 3 >= tiles.len() && by_b * 3 >= tiles.len(),
        "not round robin: {by_a} and {by_b} of {}",
        tiles.len()
    );
    // Every request the load made reached nginx (some were cancelled on the way).
    assert!(
        tiles.len() as u64 <= through.requests,
        "{} logged, {} made",
        tiles.len(),
        through.requests
    );

    // One flight through the front and one against replica A alone settle on the
    // same selection.
    let dir = tempfile::tempdir().unwrap();
    let path = glide(dir.path());
    // Transitions over time off: one still morphing at the last frame draws raised
    // patches, and the last tiles' arrival differs by a frame or two between the two.
    let settled = |server| FlyOptions {
        morph_seconds: 0.0,
        ..options(server, path.clone(), 150)
    };
    let (front_frames, front_summary) = run_flight(&settled(front));
    let (alone_frames, alone_summary) = run_flight(&settled(a));
    for (who, frames, s) in [
        ("through nginx", &front_frames, &front_summary),
        ("one replica", &alone_frames, &alone_summary),
    ] {
        assert_converged(who, frames);
        assert_eq!(
            s.stream.failures + s.stream.corrupt,
            0,
            "{who}: {:?}",
            s.stream
        );
    }
    let (x, y) = (
        &front_frames.last().unwrap().select,
        &alone_frames.last().unwrap().select,
    );
    assert_eq!(
        (x.tiles, x.coarsest_level, x.patches, x.triangles),
        (y.tiles, y.coarsest_level, y.patches, y.triangles),
        "through nginx {x:?}, one replica {y:?}"
    );
}

/// A flight that keeps needing new tiles for a while, then holds still so it can
/// converge (the outage tests' leg); its path file lives in `dir`.
fn leg(dir: &std::path::Path) -> String {
    let p = dir.join("leg.json");
    std::fs::write(
        &p,
        r#"{"waypoints": [[0.1, 0.1], [0.6, 0.6]], "speed_mps": 40000, "altitude_agl_m": 400, "pitch_deg": -20}"#,
    )
    .unwrap();
    p.to_string_lossy().into_owned()
}

/// Seconds since the epoch, as nginx's `$msec`.
fn now() -> f64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

/// Replica B killed with SIGKILL while `tessera load` (8 clients) and two flights run
/// through the front, once it has answered some of their requests.
///
/// Bound: a request B had not begun to answer is retried on A by nginx
/// (`proxy_next_upstream error`), so a client can only see the failure of a response
/// B had begun and not finished: at most as many as the clients can have in flight
/// at once (`max_in_flight` each). Every request that starts after nginx noticed
/// (B's first failure in the log) goes to A alone (`max_fails=1`); the flights
/// converge, every wanted tile received.
#[test]
fn a_replica_killed_mid_load_costs_at_most_the_requests_in_flight() {
    let Some(mut c) = Cluster::start() else {
        return;
    };
    let [a, b] = c.addrs();
    let front = c.front.addr();
    let clients = 8;
    let loader = std::thread::spawn(move || load_against(front, clients, Duration::from_secs(6)));
    let dir = tempfile::tempdir().unwrap();
    let flight = options(front, leg(dir.path()), 360);
    let witnesses: Vec<_> = (0..2)
        .map(|_| {
            let o = flight.clone();
            std::thread::spawn(move || run_flight(&o))
        })
        .collect();

    // Kill B once it has answered some of the load's requests (a count, not a time).
    let mut polls = 0;
    while tile_requests(&c.front.log())
        .iter()
        .filter(|l| answered_by(l) == Some(b))
        .count()
        < 20
    {
        polls += 1;
        assert!(polls < 3000, "replica B answered fewer than 20 requests");
        std::thread::sleep(Duration::from_millis(10));
    }
    let killed_at = now();
    let status = c.replicas[1].kill();
    assert_eq!(
        std::os::unix::process::ExitStatusExt::signal(&status),
        Some(9),
        "replica B was not killed by SIGKILL: {status:?}"
    );

    let report = loader.join().unwrap();
    let flights: Vec<(Vec<FrameRecord>, FlySummary)> =
        witnesses.into_iter().map(|w| w.join().unwrap()).collect();
    let log = c.front.log();
    let tiles = tile_requests(&log);

    // nginx noticed at the first request B failed (refused, reset, cut off).
    let b_failed = |l: &Logged| {
        let tried = l.upstreams();
        tried.contains(&b) && (answered_by(l) != Some(b) || l.status >= 500)
    };
    let noticed = tiles
        .iter()
        .filter(|l| b_failed(l))
        .map(|l| l.ended)
        .fold(f64::INFINITY, f64::min);
    assert!(noticed.is_finite(), "no request ever failed at replica B");
    let after_kill: Vec<_> = tiles.iter().filter(|l| l.ended >= killed_at).collect();
    let retried = after_kill
        .iter()
        .filter(|l| l.upstreams().len() > 1)
        .count();
    // `$msec` and `$request_time` are to the millisecond: 2 ms of slack.
    let later: Vec<_> = tiles
        .iter()
        .filter(|l| l.started() > noticed + 0.002)
        .collect();
    let stream_errors: u64 = flights
        .iter()
        .map(|(_, s)| s.stream.failures + s.stream.corrupt)
        .sum();
    eprintln!("load through nginx, replica B killed: {report}");
    eprintln!(
        "load: {} errors of {} requests ({} answered in full); flights: {stream_errors} errors \
         of {} requests",
        report.errors,
        report.requests,
        report.responses,
        flights.iter().map(|(_, s)| s.stream.requests).sum::<u64>()
    );
    eprintln!(
        "nginx: {} tile requests, {} ended after the kill ({retried} of them tried B first and \
         were retried on A), {} started after nginx noticed, all on A",
        tiles.len(),
        after_kill.len(),
        later.len()
    );

    // The bound.
    let in_flight = StreamConfig::default().max_in_flight as u64;
    assert!(
        report.errors <= u64::from(clients) * in_flight,
        "{} errors: more than the {clients} clients can have in flight",
        report.errors
    );
    assert!(
        stream_errors <= 2 * flight.stream.max_in_flight as u64,
        "{stream_errors} errors in the flights"
    );
    // The survivor takes everything after nginx noticed; the load went on.
    assert!(
        later.len() >= 10,
        "only {} requests after the kill",
        later.len()
    );
    for l in &later {
        assert!(l.upstreams().iter().all(|u| *u == a), "{l:?}");
        assert!(l.status == 200 || l.status == 499, "{l:?}");
    }
    // Every client recovered: the flights converged, every wanted tile received.
    for (i, (frames, _)) in flights.iter().enumerate() {
        assert_converged(&format!("flight {i}"), frames);
    }
}

/// `/healthz/live` is the process, `/healthz/ready` the store: with the store killed a
/// replica is live (200) and not ready (503, naming the object); the same bytes put
/// back in a restarted store, it is ready again without a restart of its own.
#[test]
fn live_stays_200_while_ready_follows_the_store() {
    let Some((mut s3, bytes)) = store() else {
        return;
    };
    let replica = Replica::start(&s3.env());
    let r = replica.addr;
    assert_eq!(get_json(r, "/healthz/live", 200)["status"], "live");
    assert_eq!(get_json(r, "/healthz/ready", 200)["status"], "ready");

    s3.kill();
    assert_eq!(get_json(r, "/healthz/live", 200)["status"], "live");
    let why = get_json(r, "/healthz/ready", 503);
    eprintln!("ready with the store down: {why}");
    assert_eq!(why["status"], "not ready");
    let reason = why["failing"]["terrain"].as_str().unwrap_or_default();
    assert!(
        reason.contains(URL),
        "the reason does not name {URL}: {why}"
    );

    s3.restart();
    s3.create_bucket(BUCKET);
    s3.put(BUCKET, KEY, &bytes);
    // The first check after the restart may meet a connection the store's death left
    // behind in the pool; a few tries.
    let mut tries = 0;
    loop {
        let (status, body) = get(r, "/healthz/ready");
        if status == 200 {
            break;
        }
        tries += 1;
        assert!(
            tries < 10,
            "not ready after the same bytes were put back: {status} {}",
            String::from_utf8_lossy(&body)
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    assert_eq!(get_json(r, "/healthz/live", 200)["status"], "live");
}
