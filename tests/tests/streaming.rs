//! Streaming against a real server over real sockets
//! (docs/ARCHITECTURE.md#no-holes-no-stalls): a flight never draws a hole once the root
//! has arrived and converges to τ, settled quality frames reuse cached references, a
//! flight keeps drawing through a proxy that delays every response (`tessera-proxy`), the
//! load generator batches only in range mode, and the deficit is missing, not huge, while
//! tiles are missing.
//!
//! The server's outages are in `streaming_outage.rs`, damage in transit and on disk
//! in `streaming_damage.rs`; the fixtures they share in `streaming_support/`.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared fixtures
mod streaming_support;

use std::time::Duration;
use streaming_support::{assert_no_holes, glide, options, run_flight, small_load, start_server};
use tessera_client::app::fly::{FrameRecord, fly};
use tessera_proxy::Delay;

#[test]
fn flight_converges_and_never_draws_a_hole() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (addr, _server) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let dir = tempfile::tempdir().unwrap();
    let (frames, summary) = run_flight(&options(addr, glide(dir.path()), 150));
    assert_no_holes(&frames);
    let last = frames.last().unwrap();
    assert!(
        last.select.deficit.is_some_and(|d| d <= 1.0),
        "the still view never reached τ: deficit {:?}",
        last.select.deficit
    );
    assert_eq!(last.wanted, 0, "everything the view needs is resident");
    assert!(summary.stream.requests > 0 && summary.stream.bytes > 0);
    assert_eq!(summary.stream.failures, 0);
}

/// `fly --quality --settle --reference-cache` (what the benchmarks use): every
/// measured frame waits until it draws what the policy asks for, two runs see the same
/// cameras and selections, and the second run takes its references from the cache.
#[test]
fn settled_quality_frames_converge_and_reuse_cached_references() {
    use tessera_client::app::headless::{Draws, RenderSetup};
    use tessera_client::render::RenderOptions;
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (addr, _server) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let flight = |out: &str| {
        let mut opts = options(addr, glide(dir.path()), 9);
        opts.width = 320;
        opts.height = 180;
        // The reference needs every finest tile in view resident and uploaded.
        opts.pool_tiles = 2048;
        opts.render = Some(RenderSetup {
            opts: RenderOptions {
                width: 320,
                height: 180,
                slots: 1100,
                ..RenderOptions::default()
            },
            out_dir: dir.path().join(out),
            draws: Draws::Quality,
            quality_every: 4,
            write_frames: false,
            // One upload per frame at most: without settling, measured frames would
            // still be waiting for tiles.
            upload_budget: Duration::ZERO,
            settle: true,
            reference_cache: Some(cache.clone()),
        });
        run_flight(&opts).0
    };
    let measured = |frames: &[FrameRecord]| -> Vec<(u32, u64, f64)> {
        frames
            .iter()
            .filter_map(|f| {
                let r = f.render.as_ref()?;
                Some((f.frame, f.select.triangles, r.mse?))
            })
            .collect()
    };
    let first = flight("a");
    let m1 = measured(&first);
    assert_eq!(
        m1.iter().map(|m| m.0).collect::<Vec<_>>(),
        [0, 4, 8],
        "every 4th frame is measured"
    );
    for f in first.iter().filter(|f| f.frame % 4 == 0) {
        let r = f.render.unwrap();
        assert!(
            r.converged && f.wanted == 0,
            "frame {} did not settle",
            f.frame
        );
        assert!(
            f.select.deficit.is_some_and(|d| d <= 1.0),
            "frame {}: deficit {:?}",
            f.frame,
            f.select.deficit
        );
    }
    let cached: Vec<_> = std::fs::read_dir(&cache)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    assert_eq!(cached.len(), 3, "one cached reference per measured frame");

    // Same cameras and selections: the same triangles. The error is close, not
    // equal: a tile's normal map takes its border from the same-level neighbours
    // resident when it is uploaded, and that depends on timing.
    let close = |a: &[(u32, u64, f64)], b: &[(u32, u64, f64)]| {
        a.len() == b.len()
            && a.iter()
                .zip(b)
                .all(|(x, y)| x.0 == y.0 && x.1 == y.1 && (x.2 - y.2).abs() <= 0.1 * y.2.max(1.0))
    };
    let second = measured(&flight("b"));
    assert!(close(&second, &m1), "{second:?} against {m1:?}");
    // The cache is what the runs compare against: spoil one reference (black) and
    // that frame's error explodes while the others stay.
    let spoiled = cached[0].clone();
    let (rgba, w, h) = tessera_client::render::png_out::read_png(&spoiled).unwrap();
    tessera_client::render::png_out::write_png(&spoiled, &vec![0u8; rgba.len()], w, h).unwrap();
    let third = measured(&flight("c"));
    let exploded: Vec<_> = third
        .iter()
        .zip(&m1)
        .filter(|(a, b)| a.2 > 20.0 * b.2.max(1.0))
        .map(|(a, _)| a.0)
        .collect();
    assert_eq!(exploded.len(), 1, "{third:?} against {m1:?}");
    let rest: (Vec<_>, Vec<_>) = third
        .iter()
        .zip(&m1)
        .filter(|(a, _)| a.0 != exploded[0])
        .map(|(a, b)| (*a, *b))
        .unzip();
    assert!(close(&rest.0, &rest.1), "{third:?} against {m1:?}");
}

#[test]
fn keeps_drawing_through_150_ms_of_latency() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (server, _task) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let proxy = rt
        .block_on(tessera_proxy::delaying(
            server,
            Delay::new(Duration::from_millis(150)),
        ))
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    // Opened the old way (the dataset's document): the root comes with the first
    // frame's requests. (With the bootstrap it is there at frame 0: tests/bootstrap.rs.)
    let mut opts = options(proxy.addr(), glide(dir.path()), 180);
    opts.stream.bootstrap = false;
    let (frames, summary) = run_flight(&opts);
    let first = assert_no_holes(&frames);
    // The root cannot arrive before one delayed round trip (9 frames at 60 fps).
    assert!(
        first >= 9,
        "root drawn at frame {first}, before the delayed response could arrive"
    );
    let last = frames.last().unwrap();
    assert!(
        last.select.deficit.is_some_and(|d| d <= 1.0),
        "deficit {:?} at the end",
        last.select.deficit
    );
    assert_eq!(summary.stream.failures, 0);
}

/// The load generator drives real clients: in single mode every tile is its own
/// request, in range mode tiles come in batches, and neither sees errors.
#[test]
fn load_generator_batches_in_range_mode_only() {
    use tessera_client::stream::RequestMode;
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (addr, _server) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let run = |mode| {
        small_load(
            tessera_client::stream::TileSource::server(format!("http://{addr}"), "terrain"),
            3,
            Duration::from_millis(1500),
            mode,
        )
    };
    let single = run(RequestMode::Single);
    let ranges = run(RequestMode::Ranges);
    for r in [&single, &ranges] {
        assert_eq!(r.errors, 0, "{r:?}");
        assert!(r.tiles > 20 && r.bytes > 0, "{r:?}");
        assert!(r.latency_ms_p50 > 0.0 && r.latency_ms_p50 <= r.latency_ms_max);
    }
    // Single mode: one tile per request, and every response answered in full carried
    // its tile. A tile is counted when it decodes and its response when the body ends,
    // so a response cut off when the run stops may have counted its tile only: tiles
    // may exceed full responses, never requests.
    assert!(
        single.responses <= single.tiles && single.tiles <= single.requests,
        "single mode: one tile per response: {single:?}"
    );
    assert!(
        ranges.responses * 2 < ranges.tiles,
        "range mode batches: {ranges:?}"
    );
}

/// The deficit is reported as "missing", not as a huge number
/// (docs/ARCHITECTURE.md#the-client-never-goes-blind; DECISIONS.md "Reliability"): in an
/// ordinary flight the first frames have only the root, or nothing, and the eye is inside
/// the root's error box. Those frames say `null` and count what is missing; a number is
/// only ever a bounded error. The old selection clamped the distance to 1e-9 m, which
/// made `ε·λ/d` at least 1e9 px for any error over a metre: no number that large is a
/// measurement.
#[test]
fn the_deficit_is_missing_rather_than_huge_while_tiles_are_missing() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (addr, _server) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let dir = tempfile::tempdir().unwrap();
    let mut buf = Vec::new();
    // Opened the old way, so that the first frames have nothing yet (the bootstrap
    // would have the coarsest levels resident at frame 0).
    let mut opts = options(addr, glide(dir.path()), 120);
    opts.stream.bootstrap = false;
    fly(&opts, Some(&mut buf)).unwrap();
    let lines: Vec<serde_json::Value> = String::from_utf8(buf)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let mut nulls = 0;
    for l in &lines {
        let (rho, deficit) = (&l["max_rho"], &l["deficit"]);
        if rho.is_null() {
            nulls += 1;
            assert!(deficit.is_null(), "{l}");
            continue;
        }
        let rho = rho.as_f64().unwrap();
        assert!(
            rho.is_finite() && rho < 1e9,
            "frame {}: max_rho {rho} is no measurement",
            l["frame"]
        );
        assert_eq!(l["missing"].as_u64(), Some(0), "{l}");
        let deficit = deficit.as_f64().unwrap();
        assert!(
            (deficit - rho / opts.tau).abs() <= 1e-9 * rho.max(1.0),
            "{l}"
        );
    }
    assert!(
        lines[0]["missing"].as_u64().is_some_and(|m| m > 0) && lines[0]["max_rho"].is_null(),
        "frame 0 cannot have the root yet: {}",
        lines[0]
    );
    assert!(
        nulls > 0 && nulls < lines.len(),
        "{nulls} of {} frames",
        lines.len()
    );
    let last = lines.last().unwrap();
    assert!(last["deficit"].as_f64().is_some_and(|d| d <= 1.0), "{last}");
}
