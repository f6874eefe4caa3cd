//! Damage in transit and on disk (docs/ARCHITECTURE.md#corrupt-records-are-detected,
//! docs/ARCHITECTURE.md#the-client-never-goes-blind): tile frames that a proxy damages on
//! the way (`tessera-proxy`: flipped bytes, streams cut short mid-frame) are rejected
//! without crashing, never become resident and are retried with backoff, and a flight
//! over tiles that always arrive damaged draws their ancestors. Records corrupt in the
//! server's file (the root, or all of them) are retried, then written off; the flight
//! draws what it can and says why, and fails when it drew nothing.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared fixtures
mod streaming_support;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use streaming_support::{
    assert_no_holes, glide, options, pyramid, run_flight, start_server, start_server_for,
};
use tessera_client::app::fly::FrameRecord;
use tessera_client::stream::StreamConfig;
use tessera_proxy::{Damage, Faults, Recurrence, RequestLog};
use tessera_shared::{Level, TileId};

/// Corrupt records are detected (docs/ARCHITECTURE.md#corrupt-records-are-detected) in
/// transit: damaged frames are rejected with an error that says why, counted, retried (a
/// transient fault is not the server's corrupt record), and the flight goes on drawing
/// what is resident, then recovers.
fn assert_survived_transient(
    frames: &[FrameRecord],
    summary: &tessera_client::app::fly::FlySummary,
    faults: &Faults,
    why: &str,
) {
    assert!(
        !faults.first_damaged().is_empty(),
        "the proxy damaged nothing"
    );
    assert!(
        summary.stream.failures > 0,
        "damaged responses were not counted as failures: {:?}",
        summary.stream
    );
    let error = summary.last_error.as_deref().unwrap_or_default();
    assert!(
        error.contains(why),
        "the last error {error:?} does not say {why:?}"
    );
    assert_eq!(
        summary.stream.corrupt, 0,
        "damage in transit must not mark tiles corrupt for good"
    );
    assert_no_holes(frames);
    let last = frames.last().unwrap();
    assert!(
        last.select.deficit.is_some_and(|d| d <= 1.0),
        "no recovery from transient damage: deficit {:?}",
        last.select.deficit
    );
    assert_eq!(last.wanted, 0, "every tile arrived whole in the end");
}

/// A glide behind a proxy that damages every tile's first copy with `damage`: the
/// client must reject each damaged copy (saying `why`) and recover.
fn survives_transient(damage: Damage, why: &str) {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (server, _task) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let faults = Faults::new(damage, Recurrence::Once, |_, _| true);
    let proxy = rt
        .block_on(tessera_proxy::corrupting(server, faults.clone()))
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (frames, summary) = run_flight(&options(proxy.addr(), glide(dir.path()), 180));
    assert_survived_transient(&frames, &summary, &faults, why);
}

#[test]
fn flipped_bytes_in_tile_frames_are_rejected_and_retried() {
    // Every tile's first copy arrives with a flipped byte.
    survives_transient(Damage::FlipByte, "checksum");
}

#[test]
fn streams_cut_short_mid_frame_are_rejected_and_retried() {
    // The first response carrying each tile ends in the middle of that tile's record.
    survives_transient(Damage::CutShort, "truncated");
}

/// Tiles that always arrive damaged: a few of levels 2 and 3, by Morton code.
fn always_damaged(level: u8, morton: u64) -> bool {
    (level == 2 && morton % 5 == 1) || (level == 3 && morton % 7 == 3)
}

/// A flight over tiles that always arrive damaged still draws every frame (their
/// ancestors stand in, and the deficit says so) and retries them with backoff.
#[test]
fn flight_draws_ancestors_of_tiles_that_always_arrive_damaged() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (server, _task) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let faults = Faults::new(Damage::FlipByte, Recurrence::Always, always_damaged);
    let proxy = rt
        .block_on(tessera_proxy::corrupting(server, faults.clone()))
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    // Opened the old way: the bootstrap would bring levels 0–3 whole, undamaged
    // (the proxy damages tile streams only), before any frame asks for them.
    let mut opts = options(proxy.addr(), glide(dir.path()), 150);
    opts.stream.bootstrap = false;
    let started = Instant::now();
    let (frames, summary) = run_flight(&opts);
    let elapsed = started.elapsed();
    assert_no_holes(&frames);
    let damaged = faults.first_damaged();
    assert!(!damaged.is_empty(), "the view never needed a damaged tile");
    assert!(summary.stream.failures > 0);
    assert_eq!(summary.stream.corrupt, 0);
    let error = summary.last_error.as_deref().unwrap_or_default();
    assert!(error.contains("checksum"), "last error {error:?}");
    assert_backed_off(&damaged, elapsed, &opts.stream, 2);
}

/// A tile that keeps failing waits `retry_base · 2^k` (at most `retry_max`) after each
/// failure blamed on it before it is asked for again, so in `elapsed` it can be the
/// damaged frame a client meets at most `4 + elapsed / retry_max` times (`slack`
/// times that where a flight may also cancel and reissue requests); without backoff
/// it would be about once per frame. Slowness only lowers the count.
fn assert_backed_off(
    first_damaged: &HashMap<(u8, u64), u32>,
    elapsed: Duration,
    config: &StreamConfig,
    slack: u32,
) {
    let bound = slack * (4 + (elapsed.as_secs_f64() / config.retry_max.as_secs_f64()) as u32);
    for (&(level, morton), &n) in first_damaged {
        assert!(
            n <= bound,
            "tile {morton} of level {level} was met damaged {n} times in {elapsed:?}: no backoff (at most {bound} expected)"
        );
    }
}

/// Through the streamer alone (the part of `fly` that accepts tiles), so that the
/// pool can be inspected afterwards: a tile whose every copy is damaged never becomes
/// resident, every resident tile equals the pyramid's own, bit for bit, and tiles
/// sent in the same responses as a damaged one still arrive.
#[test]
fn damaged_tiles_never_become_resident() {
    use tessera_client::select::Wanted;
    use tessera_client::stream::Streamer;
    use tessera_client::stream::pool::TilePool;
    use tessera_shared::Pyramid;
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (server, _task) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let faults = Faults::new(Damage::FlipByte, Recurrence::Always, always_damaged);
    let proxy = rt
        .block_on(tessera_proxy::corrupting(server, faults.clone()))
        .unwrap();
    let file = Pyramid::open_file(pyramid()).unwrap();
    let g = *file.geometry();
    // The four coarsest levels (85 tiles), coarse first as selection would rank them.
    let wanted: Vec<Wanted> = g
        .levels()
        .take(4)
        .flat_map(|l| g.present_tiles(l))
        .map(|tile| Wanted {
            tile,
            rho: 64.0 / f64::from(1u32 << tile.level().get()),
        })
        .collect();
    assert!(
        wanted
            .iter()
            .any(|w| always_damaged(w.tile.level().get(), w.tile.morton().get()))
    );
    let config = options(proxy.addr(), String::new(), 0).stream;
    let mut streamer = Streamer::new(
        &format!("http://{}", proxy.addr()),
        "terrain",
        tessera_shared::codec::RecordLayout::current(g.tile_log2()),
        config.clone(),
    )
    .unwrap();
    let mut pool = TilePool::new(1024);
    let started = Instant::now();
    while started.elapsed() < Duration::from_millis(1500) {
        streamer.frame(&mut pool, &wanted, &[]);
        std::thread::sleep(Duration::from_millis(5));
    }
    let elapsed = started.elapsed();
    for w in &wanted {
        let t = w.tile;
        let damaged = always_damaged(t.level().get(), t.morton().get());
        match pool.get(t) {
            Some(r) => {
                assert!(!damaged, "{t} always arrives damaged, yet is resident");
                let truth = file.read_tile(t).unwrap().unwrap();
                assert!(
                    r.heights == truth.heights,
                    "{t}: resident heights differ from the pyramid's"
                );
                assert_eq!(r.errors, truth.errors, "{t}: resident error table differs");
            }
            None => assert!(damaged, "{t} arrives whole but never became resident"),
        }
    }
    let s = streamer.stats;
    assert!(s.failures > 0 && s.corrupt == 0, "{s:?}");
    let error = streamer.last_error.clone().unwrap_or_default();
    assert!(error.contains("checksum"), "last error {error:?}");
    assert_backed_off(&faults.first_damaged(), elapsed, &config, 1);
}

/// A copy of the test pyramid in `dir` (same name, so the same dataset) with one byte
/// flipped in the middle of every record `pick` chooses: the records' checksums in the
/// index no longer match, so the server answers them with error frames (API.md), as
/// it would a record damaged on disk.
fn corrupted_copy(dir: &Path, pick: impl Fn(TileId) -> bool) -> (PathBuf, Vec<TileId>) {
    use std::io::{Read, Seek, SeekFrom, Write};
    use tessera_shared::Pyramid;
    let out = dir.join("terrain.tess");
    std::fs::copy(pyramid(), &out).unwrap();
    let spots: Vec<(TileId, u64)> = {
        let p = Pyramid::open_file(&out).unwrap();
        let g = *p.geometry();
        g.levels()
            .flat_map(|l| g.present_tiles(l))
            .filter(|t| pick(*t))
            .map(|t| {
                let e = p.entry(t).unwrap();
                (t, e.offset + u64::from(e.length) / 2)
            })
            .collect()
    };
    let mut f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(&out)
        .unwrap();
    for &(_, at) in &spots {
        let mut b = [0u8];
        f.seek(SeekFrom::Start(at)).unwrap();
        f.read_exact(&mut b).unwrap();
        f.seek(SeekFrom::Start(at)).unwrap();
        f.write_all(&[b[0] ^ 0x5a]).unwrap();
    }
    f.sync_all().unwrap();
    (out, spots.into_iter().map(|(t, _)| t).collect())
}

fn root() -> TileId {
    TileId::new(Level::ROOT, 0, 0).unwrap()
}

/// Requests the client sent for tiles of `level`.
fn level_requests(log: &RequestLog, level: u8) -> usize {
    let needle = format!("/levels/{level}/tiles?");
    log.targets().iter().filter(|t| t.contains(&needle)).count()
}

/// The client never goes blind (docs/ARCHITECTURE.md#the-client-never-goes-blind;
/// DECISIONS.md "Reliability"): the root's record is corrupt on disk, so the server
/// answers it with an error frame every time. The client retries it with backoff before
/// writing it off, meanwhile draws the root's children (level 1) instead of nothing, says
/// why in `last_error`, and the flight succeeds because it drew.
#[test]
fn flight_draws_level_one_when_the_root_record_is_corrupt() {
    let dir = tempfile::tempdir().unwrap();
    let (file, corrupted) = corrupted_copy(dir.path(), |t| t == root());
    assert_eq!(corrupted, [root()]);
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (server, _task) = start_server_for(&rt, "127.0.0.1:0".parse().unwrap(), &file);
    let (proxy, log) = rt.block_on(tessera_proxy::logging(server)).unwrap();
    // Opened the old way: with the bootstrap, levels 1–3 are resident from frame 0
    // and the root's error frame comes in the bootstrap (tests/bootstrap.rs).
    let mut opts = options(proxy.addr(), glide(dir.path()), 150);
    opts.stream.bootstrap = false;
    let (frames, summary) = run_flight(&opts);

    // Drawn: from the first frame with tiles on, every frame draws, never the root.
    let first = assert_no_holes(&frames);
    for f in &frames {
        assert_ne!(
            f.select.coarsest_level,
            Some(0),
            "frame {} drew the corrupt root",
            f.frame
        );
    }
    assert!(
        frames[first..]
            .iter()
            .all(|f| f.select.coarsest_level >= Some(1) && f.select.triangles > 0)
    );
    assert_eq!(summary.frames_drawn as usize, frames.len() - first);
    // Before level 1 arrives nothing is drawn: the deficit is missing, not 0.
    for f in &frames[..first] {
        assert!(
            f.select.max_rho.is_none() && f.select.deficit.is_none() && f.select.missing > 0,
            "frame {} draws nothing, yet reports {:?}",
            f.frame,
            f.select
        );
    }

    // Retried with backoff, then written off: asked for more than twice, and never
    // after the last report the client allows.
    let asked = level_requests(&log, 0);
    assert!(
        asked >= 3,
        "the corrupt root was asked for {asked} times: not retried"
    );
    assert!(
        asked <= opts.stream.corrupt_attempts as usize,
        "the root was asked for {asked} times, beyond the {} reports that write it off",
        opts.stream.corrupt_attempts
    );
    assert!(level_requests(&log, 1) > 0, "level 1 was never asked for");
    assert!(summary.stream.corrupt >= 3, "{:?}", summary.stream);
    assert_eq!(
        summary.stream.written_off, 1,
        "only the root is corrupt: {:?}",
        summary.stream
    );

    // Reported, in the summary and in the per-frame statistics.
    let error = summary.last_error.as_deref().unwrap_or_default();
    assert!(
        error.contains("corrupt") && error.contains(&root().to_string()),
        "the last error {error:?} does not name the corrupt root"
    );
    let last = frames.last().unwrap();
    assert!(
        last.last_error
            .as_deref()
            .is_some_and(|e| e.contains("corrupt")),
        "per-frame last_error: {:?}",
        last.last_error
    );
    summary.verdict().unwrap();
}

/// Every record corrupt (DECISIONS.md "Reliability"). The client retries, falls back
/// level by level, and still has nothing to draw: the flight fails (`tessera fly` exits
/// non-zero with this error), saying why, and every frame reports its deficit as missing.
#[test]
fn a_flight_that_draws_nothing_fails_and_says_why() {
    let dir = tempfile::tempdir().unwrap();
    let (file, corrupted) = corrupted_copy(dir.path(), |_| true);
    assert!(corrupted.len() > 5);
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (server, _task) = start_server_for(&rt, "127.0.0.1:0".parse().unwrap(), &file);
    let (proxy, log) = rt.block_on(tessera_proxy::logging(server)).unwrap();
    let (frames, summary) = run_flight(&options(proxy.addr(), glide(dir.path()), 90));
    assert_eq!(summary.frames_drawn, 0);
    assert_eq!(summary.frames_missing, summary.frames);
    for f in &frames {
        assert_eq!(f.select.tiles, 0, "frame {} drew a corrupt tile", f.frame);
        assert!(
            f.select.max_rho.is_none() && f.select.missing > 0,
            "frame {}: {:?}",
            f.frame,
            f.select
        );
    }
    assert!(
        level_requests(&log, 0) > 1,
        "the root was not retried: {:?}",
        log.targets()
    );
    assert!(
        level_requests(&log, 1) > 0,
        "no fallback to level 1 was tried"
    );
    let error = summary.last_error.as_deref().unwrap_or_default();
    assert!(error.contains("corrupt"), "last error {error:?}");
    let verdict = format!("{:#}", summary.verdict().unwrap_err());
    assert!(
        verdict.contains("drew nothing") && verdict.contains(error),
        "{verdict}"
    );
}
