//! Streaming against a real server over real sockets (DESIGN §6 invariant 5): a
//! flight never draws a hole once the root has arrived, recovers after the server is
//! killed and restarted, and keeps drawing through a proxy that delays every response.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Duration;
use tessera_client::fly::{FlyOptions, FrameRecord, fly};
use tessera_client::stream::StreamConfig;
use tessera_server::build::{BuildOptions, build};
use tessera_server::serve::config::Settings;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

fn pyramid() -> &'static Path {
    static P: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &P.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("terrain.tess");
        let opts = BuildOptions {
            tile_size: 128,
            ..BuildOptions::default()
        };
        build("synthetic:4097:11", &out, &opts).unwrap();
        (dir, out)
    })
    .1
}

/// A server on `addr` (port 0 for any) in the background of `rt`; returns its address
/// and a handle that kills it (abruptly: connections drop) when aborted.
fn start_server(
    rt: &tokio::runtime::Runtime,
    addr: SocketAddr,
) -> (SocketAddr, tokio::task::JoinHandle<()>) {
    let settings = Settings {
        listen: addr,
        datasets: vec![pyramid().to_path_buf()],
        ..Settings::default()
    };
    let state = tessera_server::serve::state(&settings).unwrap();
    let listener = rt.block_on(tokio::net::TcpListener::bind(addr)).unwrap();
    let bound = listener.local_addr().unwrap();
    let task = rt.spawn(async move {
        let _ =
            tessera_server::serve::serve_until(listener, state, &settings, std::future::pending())
                .await;
    });
    (bound, task)
}

/// A path JSON file: a short, slow glide that ends still, so the view can settle.
fn glide(dir: &Path) -> String {
    let p = dir.join("glide.json");
    std::fs::write(
        &p,
        r#"{"waypoints": [[0.3, 0.3], [0.45, 0.4]], "speed_mps": 2000, "altitude_agl_m": 400, "pitch_deg": -20}"#,
    )
    .unwrap();
    p.to_string_lossy().into_owned()
}

fn options(server: SocketAddr, path: String, frames: u32) -> FlyOptions {
    FlyOptions {
        server: format!("http://{server}"),
        dataset: "terrain".into(),
        path,
        frames,
        fps: 60.0,
        tau: 2.0,
        width: 960,
        height: 540,
        spacing: Some(30.0),
        prefetch: true,
        pool_tiles: 512,
        stream: StreamConfig {
            retry_base: Duration::from_millis(50),
            retry_max: Duration::from_millis(400),
            request_timeout: Duration::from_secs(5),
            ..StreamConfig::default()
        },
        t_offset: 0.0,
        runtime: None,
        progress: None,
    }
}

fn run_flight(opts: &FlyOptions) -> (Vec<FrameRecord>, tessera_client::fly::FlySummary) {
    let mut buf = Vec::new();
    let summary = fly(opts, Some(&mut buf)).unwrap();
    let frames = String::from_utf8(buf)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<FrameRecord>(l).unwrap())
        .collect();
    (frames, summary)
}

/// Invariant 5: once the root is resident, every frame draws something for the view
/// (an ancestor at least), never a hole.
fn assert_no_holes(frames: &[FrameRecord]) -> usize {
    let first = frames
        .iter()
        .position(|f| f.select.tiles > 0)
        .expect("the root never arrived");
    for f in &frames[first..] {
        assert!(
            f.select.tiles > 0 && f.select.patches > 0,
            "frame {} draws nothing",
            f.frame
        );
    }
    first
}

#[test]
fn flight_converges_and_never_draws_a_hole() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (addr, _server) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let dir = tempfile::tempdir().unwrap();
    let (frames, summary) = run_flight(&options(addr, glide(dir.path()), 150));
    assert_no_holes(&frames);
    let last = frames.last().unwrap();
    assert!(
        last.select.deficit <= 1.0,
        "the still view never reached τ: deficit {}",
        last.select.deficit
    );
    assert_eq!(last.wanted, 0, "everything the view needs is resident");
    assert!(summary.stream.requests > 0 && summary.stream.bytes > 0);
    assert_eq!(summary.stream.failures, 0);
}

#[test]
fn recovers_after_the_server_is_killed_and_restarted() {
    // The server runs on its own runtime, so killing it (shutting the runtime down)
    // drops every connection, as a crashed process would.
    let server_rt = tokio::runtime::Runtime::new().unwrap();
    let (addr, _task) = start_server(&server_rt, "127.0.0.1:0".parse().unwrap());
    let dir = tempfile::tempdir().unwrap();
    // A long fast leg that keeps needing new tiles, then a still view to settle on.
    let path = dir.path().join("leg.json");
    std::fs::write(
        &path,
        r#"{"waypoints": [[0.1, 0.1], [0.6, 0.6]], "speed_mps": 40000, "altitude_agl_m": 400, "pitch_deg": -20}"#,
    )
    .unwrap();
    let opts = options(addr, path.to_string_lossy().into_owned(), 300);
    let restarter = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(400));
        server_rt.shutdown_background();
        std::thread::sleep(Duration::from_secs(1));
        let rt2 = tokio::runtime::Runtime::new().unwrap();
        let (again, task) = start_server(&rt2, addr);
        assert_eq!(again, addr);
        (rt2, task)
    });
    let (frames, summary) = run_flight(&opts);
    let _keep = restarter.join().unwrap();
    assert_no_holes(&frames);
    assert!(summary.stream.failures > 0, "the outage was not noticed");
    let last = frames.last().unwrap();
    assert!(
        last.select.deficit <= 1.0,
        "no recovery after the restart: deficit {}",
        last.select.deficit
    );
    assert_eq!(last.wanted, 0);
}

/// A TCP proxy that holds every response from upstream for `delay` before passing it on.
async fn delaying_proxy(upstream: SocketAddr, delay: Duration) -> SocketAddr {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move {
        loop {
            let Ok((client, _)) = listener.accept().await else {
                return;
            };
            tokio::spawn(async move {
                let Ok(server) = tokio::net::TcpStream::connect(upstream).await else {
                    return;
                };
                let (mut cr, mut cw) = client.into_split();
                let (mut sr, mut sw) = server.into_split();
                let up = tokio::spawn(async move {
                    let _ = tokio::io::copy(&mut cr, &mut sw).await;
                });
                let mut buf = vec![0u8; 1 << 16];
                let mut fresh = true;
                loop {
                    let n = match tokio::time::timeout(Duration::from_millis(20), sr.read(&mut buf))
                        .await
                    {
                        Ok(Ok(0) | Err(_)) => break,
                        Ok(Ok(n)) => n,
                        // A pause in the stream: the next bytes start a new response.
                        Err(_) => {
                            fresh = true;
                            continue;
                        }
                    };
                    if fresh {
                        tokio::time::sleep(delay).await;
                        fresh = false;
                    }
                    if cw.write_all(&buf[..n]).await.is_err() {
                        break;
                    }
                }
                up.abort();
            });
        }
    });
    addr
}

#[test]
fn keeps_drawing_through_150_ms_of_latency() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (server, _task) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let proxy = rt.block_on(delaying_proxy(server, Duration::from_millis(150)));
    let dir = tempfile::tempdir().unwrap();
    let (frames, summary) = run_flight(&options(proxy, glide(dir.path()), 180));
    let first = assert_no_holes(&frames);
    // The root cannot arrive before one delayed round trip (9 frames at 60 fps).
    assert!(
        first >= 9,
        "root drawn at frame {first}, before the delayed response could arrive"
    );
    let last = frames.last().unwrap();
    assert!(
        last.select.deficit <= 1.0,
        "deficit {} at the end",
        last.select.deficit
    );
    assert_eq!(summary.stream.failures, 0);
}

/// The load generator drives real clients: in single mode every tile is its own
/// request, in range mode tiles come in batches, and neither sees errors.
#[test]
fn load_generator_batches_in_range_mode_only() {
    use tessera_client::load::{LoadOptions, load};
    use tessera_client::stream::RequestMode;
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (addr, _server) = start_server(&rt, "127.0.0.1:0".parse().unwrap());
    let run = |mode| {
        load(&LoadOptions {
            server: format!("http://{addr}"),
            dataset: "terrain".into(),
            clients: 3,
            duration: Duration::from_millis(1500),
            mode,
            fps: 30.0,
            tau: 2.0,
            width: 640,
            height: 360,
            spacing: Some(30.0),
            progress: false,
        })
        .unwrap()
    };
    let single = run(RequestMode::Single);
    let ranges = run(RequestMode::Ranges);
    for r in [&single, &ranges] {
        assert_eq!(r.errors, 0, "{r:?}");
        assert!(r.tiles > 20 && r.bytes > 0, "{r:?}");
        assert!(r.latency_ms_p50 > 0.0 && r.latency_ms_p50 <= r.latency_ms_max);
    }
    assert_eq!(
        single.responses, single.tiles,
        "single mode: one tile per response"
    );
    assert!(
        ranges.responses * 2 < ranges.tiles,
        "range mode batches: {ranges:?}"
    );
}
