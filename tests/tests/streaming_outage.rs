//! Streaming through the server's outages (docs/ARCHITECTURE.md#no-holes-no-stalls,
//! docs/ARCHITECTURE.md#the-client-never-goes-blind): a flight recovers after the server
//! is killed and restarted on the same port, whether its runtime is shut down under it or
//! its process is killed with SIGKILL; it keeps drawing what it has meanwhile, never a
//! hole.
//!
//! The SIGKILL test runs this test binary again as the server process, filtered to
//! [`server_process_for_the_sigkill_test`].

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared fixtures
mod streaming_support;

use std::net::SocketAddr;
use std::path::Path;
use std::time::{Duration, Instant};
use streaming_support::{
    assert_recovered, options, pyramid, run_flight, start_server, start_server_for,
};
use tessera_client::app::fly::FlyOptions;

/// A long fast leg that keeps needing new tiles, then a still view to settle on:
/// the flight of the outage tests (its path file lives in the returned directory).
fn outage_flight(addr: SocketAddr) -> (tempfile::TempDir, FlyOptions) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("leg.json");
    std::fs::write(
        &path,
        r#"{"waypoints": [[0.1, 0.1], [0.6, 0.6]], "speed_mps": 40000, "altitude_agl_m": 400, "pitch_deg": -20}"#,
    )
    .unwrap();
    let opts = options(addr, path.to_string_lossy().into_owned(), 300);
    (dir, opts)
}

#[test]
fn recovers_after_the_server_is_killed_and_restarted() {
    // The server runs on its own runtime, so killing it (shutting the runtime down)
    // drops every connection, as a crashed process would.
    let server_rt = tokio::runtime::Runtime::new().unwrap();
    let (addr, _task) = start_server(&server_rt, "127.0.0.1:0".parse().unwrap());
    let (_dir, opts) = outage_flight(addr);
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
    assert_recovered(&frames, &summary);
}

/// Set in a copy of this test binary that only serves: the address and the file.
const CHILD_ADDR: &str = "TESSERA_TEST_SERVER_ADDR";
const CHILD_FILE: &str = "TESSERA_TEST_SERVER_FILE";

/// Not a test of its own: the body of the server process that
/// [`recovers_after_the_server_process_is_killed_with_sigkill`] starts (this binary
/// again, with [`CHILD_ADDR`] set) and kills. Ignored, so a plain run skips it.
#[test]
#[ignore = "run only as the child process of the SIGKILL test"]
fn server_process_for_the_sigkill_test() {
    let (Some(addr), Some(file)) = (std::env::var_os(CHILD_ADDR), std::env::var_os(CHILD_FILE))
    else {
        return;
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    let addr = addr.to_str().unwrap().parse().unwrap();
    let (_bound, task) = start_server_for(&rt, addr, Path::new(&file));
    let _ = rt.block_on(task);
}

/// Starts the server process on `addr` and waits until it accepts connections.
fn spawn_server_process(addr: SocketAddr) -> std::process::Child {
    let child = std::process::Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "server_process_for_the_sigkill_test",
            "--ignored",
        ])
        .env(CHILD_ADDR, addr.to_string())
        .env(CHILD_FILE, pyramid())
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let started = Instant::now();
    while std::net::TcpStream::connect(addr).is_err() {
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "the server process did not start"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    child
}

/// `kill -9` of a real server process mid-flight, then a restart on the same port: the
/// flight notices, keeps drawing what it has, and recovers
/// (docs/ARCHITECTURE.md#the-client-never-goes-blind).
#[test]
fn recovers_after_the_server_process_is_killed_with_sigkill() {
    let addr = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap();
    let mut first = spawn_server_process(addr);
    let (_dir, opts) = outage_flight(addr);
    let restarter = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(400));
        first.kill().unwrap(); // SIGKILL
        let status = first.wait().unwrap();
        std::thread::sleep(Duration::from_secs(1));
        (status, spawn_server_process(addr))
    });
    let (frames, summary) = run_flight(&opts);
    let (killed, mut second) = restarter.join().unwrap();
    let _ = second.kill();
    let _ = second.wait();
    assert_eq!(
        std::os::unix::process::ExitStatusExt::signal(&killed),
        Some(9),
        "the first server was not killed by SIGKILL: {killed:?}"
    );
    assert_recovered(&frames, &summary);
}
