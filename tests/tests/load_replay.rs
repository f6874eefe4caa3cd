//! Load testing (DECISIONS.md "Load testing: the proof"), the replay half: `tessera load
//! --replay` against a real server over the moon 4096², with a trace recorded by the real
//! full clients (`tessera load --record`), and proxies (`tessera-proxy`) that log, stall
//! or damage what they relay, independently of the client's code:
//!
//! - replayed as recorded, exactly the recorded requests reach the server;
//! - a server that stops answering for a while makes the latency measured from the
//!   scheduled start (coordinated omission corrected) rise by about the stall, while
//!   the latency from the actual send does not;
//! - every response damaged on the way is counted as a `corrupt` error, and nothing
//!   else is;
//! - the reports of two shards merge into the totals of one process.
//!
//! The tests share one recording and run one at a time (a lock), so that the stall
//! test's latencies are not another test's load.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared fixtures
mod streaming_support;

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Mutex, MutexGuard, OnceLock, PoisonError};
use std::time::Duration;
use streaming_support::start_server_for;
use tessera_client::app::load_test::{LoadOptions, load};
use tessera_client::loadtest::check::ErrorKind;
use tessera_client::loadtest::merge::merge;
use tessera_client::loadtest::pacing::{Pacing, Rate};
use tessera_client::loadtest::replay::{ReplayOptions, replay};
use tessera_client::loadtest::replay_report::ReplayReport;
use tessera_client::loadtest::trace::{Shard, Trace};
use tessera_client::stream::TileSource;
use tessera_proxy::{Damage, Faults, Recurrence, Stall};
use tessera_server::builder::{BuildOptions, build};

/// The moon 4096² pyramid and a trace of 8 full clients flying over it for 4 s,
/// recorded once per test binary; `None` when the DEM is not there
/// (`testdata::dem_or_skip` says so).
struct Recording {
    dir: tempfile::TempDir,
    pyramid: PathBuf,
    trace: Trace,
}

fn recording() -> Option<&'static Recording> {
    static R: OnceLock<Option<Recording>> = OnceLock::new();
    R.get_or_init(|| {
        let dem = tessera_shared::testdata::dem_or_skip("moon_crisium_gld100_4096.png")?;
        let dir = tempfile::tempdir().unwrap();
        let pyramid = dir.path().join("moon.tess");
        // 128-cell tiles (as load_record.rs): many light requests, so that one
        // connection keeps up with 100 requests/s on a busy debug build.
        let opts = BuildOptions {
            tile_size: 128,
            progress: false,
            ..BuildOptions::default()
        };
        build(dem.to_str().unwrap(), &pyramid, &opts).unwrap();
        let rt = tokio::runtime::Runtime::new().unwrap();
        let (server, task) = start_server_for(&rt, "127.0.0.1:0".parse().unwrap(), &pyramid);
        let path = dir.path().join("moon.trace.jsonl");
        load(&LoadOptions {
            record: Some(path.clone()),
            ..LoadOptions::new(
                TileSource::server(format!("http://{server}"), "moon"),
                8,
                Duration::from_secs(4),
            )
        })
        .unwrap();
        task.abort();
        let trace = Trace::read(&path).unwrap();
        // A recording a replay can say something about: tile streams, answered.
        let answered = trace
            .requests
            .iter()
            .filter(|r| r.kind.is_frame_stream() && r.expect.as_ref().is_some_and(|e| e.tiles > 0))
            .count();
        assert!(
            answered >= 20,
            "the recording has only {answered} answered tile streams of {} requests",
            trace.requests.len()
        );
        Some(Recording {
            dir,
            pyramid,
            trace,
        })
    })
    .as_ref()
}

/// One test at a time: the replays time their requests.
fn one_at_a_time() -> MutexGuard<'static, ()> {
    static L: Mutex<()> = Mutex::new(());
    L.lock().unwrap_or_else(PoisonError::into_inner)
}

/// A fresh server over the recording's pyramid on `rt`.
fn server(rt: &tokio::runtime::Runtime, rec: &Recording) -> std::net::SocketAddr {
    start_server_for(rt, "127.0.0.1:0".parse().unwrap(), &rec.pyramid).0
}

fn replay_at(
    rec: &Recording,
    front: std::net::SocketAddr,
    f: impl FnOnce(&mut ReplayOptions),
) -> ReplayReport {
    let mut opts = ReplayOptions::new(rec.trace.clone());
    opts.server = Some(format!("http://{front}"));
    f(&mut opts);
    replay(&opts).unwrap()
}

fn counts<'a>(targets: impl Iterator<Item = &'a str>) -> HashMap<&'a str, usize> {
    let mut m = HashMap::new();
    for t in targets {
        *m.entry(t).or_insert(0) += 1;
    }
    m
}

/// Replayed as recorded through a logging proxy: the server was asked exactly the
/// trace's requests (the same multiset of targets: no request lost, added or sent
/// twice), and every answer is the recorded one (no error of any kind).
#[test]
fn replay_sends_exactly_the_recorded_requests() {
    let Some(rec) = recording() else { return };
    let _one = one_at_a_time();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (proxy, log) = rt
        .block_on(tessera_proxy::logging(server(&rt, rec)))
        .unwrap();
    let report = replay_at(rec, proxy.addr(), |_| {});
    let logged = log.targets();
    let recorded = counts(rec.trace.requests.iter().map(|r| r.target.as_str()));
    let sent = counts(logged.iter().map(String::as_str));
    assert_eq!(
        logged.len(),
        rec.trace.requests.len(),
        "{} requests on the wire for {} recorded",
        logged.len(),
        rec.trace.requests.len()
    );
    assert!(
        sent == recorded,
        "the requests on the wire are not the trace's"
    );
    assert_eq!(report.sent, rec.trace.requests.len() as u64);
    assert_eq!(report.completed, report.sent);
    assert_eq!(report.errors.total(), 0, "{:?}", report.errors);
    let recorded_tiles: u64 = rec
        .trace
        .requests
        .iter()
        .filter_map(|r| r.expect.as_ref())
        .map(|e| u64::from(e.tiles))
        .sum();
    assert!(
        report.tiles >= recorded_tiles && recorded_tiles > 0,
        "{} tiles checked, {recorded_tiles} recorded",
        report.tiles
    );
}

/// 100 requests/s for 6 s over one HTTP/1.1 connection, through a proxy whose server
/// stops answering for 2 s from 1.5 s on. Every request scheduled in the first
/// `2 · duration / 100` = 120 ms of the stall (12 requests, 2 % of the 600 samples)
/// waits at least `stall − 120 ms` from its scheduled start, so the corrected p99
/// (the 594th of 600 latencies) is at least that: a bound, not a timing guess.
/// (`duration / 100` would cover exactly 1 %, 6 samples, one short of moving the
/// p99 when no request happened to be on the wire as the stall began.) Measured from
/// the actual send, only the one request on the wire during the stall waited (< 1 %
/// of the samples), so the uncorrected p99 stays below half the stall. The same run
/// without the stall has a corrected p99 below half the stall: the rise is the
/// stall's.
#[test]
fn a_stall_raises_the_corrected_p99_by_the_stall_and_not_the_uncorrected() {
    let Some(rec) = recording() else { return };
    let _one = one_at_a_time();
    let stall = Duration::from_secs(2);
    let duration = Duration::from_secs(6);
    let rt = tokio::runtime::Runtime::new().unwrap();
    let upstream = server(&rt, rec);
    let run = |front| {
        replay_at(rec, front, |o| {
            o.pacing = Pacing::Constant {
                rate: Rate::new(100.0).unwrap(),
                duration,
            };
            o.connections = 1;
        })
    };
    let ms = |d: Duration| d.as_secs_f64() * 1000.0;

    let calm = rt.block_on(tessera_proxy::relay(upstream)).unwrap();
    let before = run(calm.addr());
    drop(calm);
    let stalling = rt
        .block_on(tessera_proxy::stalling(
            upstream,
            Stall {
                after: Duration::from_millis(1500),
                for_: stall,
            },
        ))
        .unwrap();
    let stalled = run(stalling.addr());
    assert!(
        stalling.stats().held >= 1,
        "the stall never held a response: {:?}",
        stalling.stats()
    );

    let shown = format!(
        "without the stall: corrected p99 {:.1} ms, uncorrected p99 {:.1} ms; with a {} ms stall: \
         corrected p99 {:.1} ms, uncorrected p99 {:.1} ms ({} requests, errors {:?})",
        before.latency_ms.p99,
        before.uncorrected_latency_ms.p99,
        ms(stall),
        stalled.latency_ms.p99,
        stalled.uncorrected_latency_ms.p99,
        stalled.completed,
        stalled.errors
    );
    assert_eq!(stalled.errors.total(), 0, "{shown}");
    assert_eq!(stalled.completed, 600, "{shown}");
    assert!(
        stalled.latency_ms.p99 >= ms(stall) - 2.0 * ms(duration) / 100.0,
        "the corrected p99 did not rise by the stall: {shown}"
    );
    assert!(
        stalled.uncorrected_latency_ms.p99 < ms(stall) / 2.0,
        "the uncorrected p99 rose with the stall: {shown}"
    );
    assert!(
        before.latency_ms.p99 < ms(stall) / 2.0,
        "the corrected p99 is high without the stall too: {shown}"
    );
    eprintln!("{shown}");
}

/// Through a proxy that flips a byte in every tile frame whose Morton code is a
/// multiple of 3 below the root, every time: the report counts exactly the responses
/// the proxy damaged as `corrupt` (one error per request: the stream is broken after
/// its first bad frame), and no error of any other kind.
#[test]
fn damaged_responses_are_counted_as_corrupt_and_nothing_else() {
    let Some(rec) = recording() else { return };
    let _one = one_at_a_time();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let faults = Faults::new(Damage::FlipByte, Recurrence::Always, |level, morton| {
        level > 0 && morton % 3 == 0
    });
    let proxy = rt
        .block_on(tessera_proxy::corrupting(server(&rt, rec), faults.clone()))
        .unwrap();
    let report = replay_at(rec, proxy.addr(), |_| {});
    let damaged: u32 = faults.first_damaged().values().sum();
    assert!(damaged > 0, "the proxy damaged nothing: pick other tiles");
    assert_eq!(
        report.errors.get(ErrorKind::Corrupt),
        u64::from(damaged),
        "{damaged} responses damaged; errors {:?}",
        report.errors
    );
    for kind in ErrorKind::ALL {
        if kind != ErrorKind::Corrupt {
            assert_eq!(report.errors.get(kind), 0, "{kind}: {:?}", report.errors);
        }
    }
    assert_eq!(report.completed, rec.trace.requests.len() as u64);
}

/// Shards 0/2 and 1/2 replayed as recorded, and the whole trace: the merged report
/// has the whole's counts (sent, completed, tiles, bytes, errors) and as many
/// latencies in each histogram.
#[test]
fn merged_shards_equal_one_process() {
    let Some(rec) = recording() else { return };
    let _one = one_at_a_time();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let front = server(&rt, rec);
    let whole = replay_at(rec, front, |_| {});
    let shards: Vec<ReplayReport> = (0..2)
        .map(|k| replay_at(rec, front, |o| o.shard = Shard::new(k, 2).unwrap()))
        .collect();
    assert!(
        shards.iter().all(|s| s.sent > 0),
        "a shard sent nothing: {:?}",
        shards.iter().map(|s| s.sent).collect::<Vec<_>>()
    );
    let merged = merge(&shards).unwrap();
    let totals = |r: &ReplayReport| (r.sent, r.completed, r.tiles, r.bytes, r.errors);
    assert_eq!(totals(&merged), totals(&whole));
    assert_eq!(merged.shards, 2);
    let count = |r: &ReplayReport| {
        let (c, u) = r.histograms.decode().unwrap();
        (c.count(), u.count())
    };
    assert_eq!(count(&merged), count(&whole));
    assert_eq!(count(&whole).0, whole.completed);
}

/// A trace of one tile per request (`tessera load --mode single`) replays with its
/// tiles counted: one per record answered as recorded (its body is the record, not a
/// frame stream), none for a tile recorded absent (404).
#[test]
fn single_tile_requests_count_as_tiles() {
    let Some(rec) = recording() else { return };
    let _one = one_at_a_time();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let front = server(&rt, rec);
    let path = rec.dir.path().join("single.trace.jsonl");
    load(&LoadOptions {
        record: Some(path.clone()),
        mode: tessera_client::stream::RequestMode::Single,
        ..LoadOptions::new(
            TileSource::server(format!("http://{front}"), "moon"),
            2,
            Duration::from_secs(2),
        )
    })
    .unwrap();
    let trace = Trace::read(&path).unwrap();
    let records = trace
        .requests
        .iter()
        .filter(|r| {
            r.kind == tessera_client::loadtest::trace::RequestKind::Tile
                && r.expect.as_ref().is_some_and(|e| e.status == 200)
        })
        .count();
    assert!(records >= 10, "only {records} single tiles recorded");
    let mut opts = ReplayOptions::new(trace);
    opts.server = Some(format!("http://{front}"));
    let r = replay(&opts).unwrap();
    assert_eq!(r.errors.total(), 0, "{:?}", r.errors);
    assert_eq!(r.tiles, records as u64);
}
