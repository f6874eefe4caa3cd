//! `tessera fly` exits non-zero when a whole flight drew nothing
//! (docs/ARCHITECTURE.md#the-client-never-goes-blind, DECISIONS.md "Reliability"), run as
//! the real binary. The server here is a stand-in that knows one dataset and answers
//! every tile request with a 503, as a server whose storage has gone away would: the
//! client cannot depend on the real server (which needs axum), and the end-to-end tests
//! in `tests/` check the same verdict against it.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

use std::io::{BufRead, BufReader, Write};
use std::net::TcpListener;
use std::process::Command;

/// The contract's description of a 1025² dataset of 512-cell tiles, as the real
/// server would send it.
fn terrain_document() -> String {
    let meta = tessera_shared::Metadata {
        min_height: 0.0,
        max_height: 1000.0,
        quantization: tessera_shared::Quantization {
            offset: 0.0,
            scale: 1.0,
            max_error: 0.0,
        },
        ..tessera_shared::fixtures::metadata(1025, 1025, 512)
    };
    serde_json::to_string(&tessera_shared::api::DatasetInfo::new(
        "terrain",
        &meta,
        tessera_shared::format::VERSION,
        0,
    ))
    .unwrap()
}

/// Serves `/v1/datasets/terrain` (a 1025² dataset of 512-cell tiles) and a 503 with
/// a JSON reason for everything else, one connection at a time, until the process
/// ends. Returns the base URL and a counter of tile requests.
fn failing_server() -> (String, std::sync::Arc<std::sync::atomic::AtomicU32>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    let tiles = std::sync::Arc::new(std::sync::atomic::AtomicU32::new(0));
    let count = tiles.clone();
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(mut stream) = stream else { return };
            let count = count.clone();
            std::thread::spawn(move || {
                let mut reader = BufReader::new(stream.try_clone().unwrap());
                loop {
                    let mut request = String::new();
                    if reader.read_line(&mut request).unwrap_or(0) == 0 {
                        return;
                    }
                    // Headers up to the blank line (GET requests have no body).
                    let mut line = String::new();
                    while reader.read_line(&mut line).unwrap_or(0) > 2 {
                        line.clear();
                    }
                    let target = request.split(' ').nth(1).unwrap_or_default();
                    let (status, body) = if target == "/v1/datasets/terrain" {
                        ("200 OK", terrain_document())
                    } else {
                        count.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        (
                            "503 Service Unavailable",
                            r#"{"error":"storage unavailable"}"#.to_string(),
                        )
                    };
                    let head = format!(
                        "HTTP/1.1 {status}\r\ncontent-type: application/json\r\ncontent-length: {}\r\n\r\n",
                        body.len()
                    );
                    if stream.write_all(head.as_bytes()).is_err()
                        || stream.write_all(body.as_bytes()).is_err()
                    {
                        return;
                    }
                }
            });
        }
    });
    (url, tiles)
}

#[test]
fn fly_exits_non_zero_when_the_whole_flight_drew_nothing() {
    let (url, tiles) = failing_server();
    let dir = tempfile::tempdir().unwrap();
    let stats = dir.path().join("stats.jsonl");
    let out = Command::new(env!("CARGO_BIN_EXE_tessera"))
        .args(["fly", "--server", &url, "--dataset", "terrain"])
        .args(["--path", "orbit", "--no-render", "--frames", "60"])
        .arg("--stats")
        .arg(&stats)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        !out.status.success(),
        "a flight that drew nothing exited {:?}\n{stdout}",
        out.status
    );
    assert!(
        stderr.contains("drew nothing") && stderr.contains("503"),
        "the error does not say what happened: {stderr}"
    );
    // The summary is still printed, with the error that explains it.
    let summary: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(summary["frames_drawn"], 0, "{summary}");
    assert!(
        summary["last_error"]
            .as_str()
            .is_some_and(|e| e.contains("503")),
        "{summary}"
    );
    // Retried with backoff rather than given up after one request.
    assert!(tiles.load(std::sync::atomic::Ordering::Relaxed) > 1);
    // Every frame's statistics say so too.
    let text = std::fs::read_to_string(&stats).unwrap();
    for line in text.lines() {
        let f: serde_json::Value = serde_json::from_str(line).unwrap();
        assert_eq!(f["tiles"], 0, "{f}");
        assert!(
            f["max_rho"].is_null() && f["missing"].as_u64() > Some(0),
            "{f}"
        );
    }
    assert!(text.lines().last().is_some_and(|l| l.contains("503")));
}

/// `tessera fly` run directly, headless, without `./run` (which exports
/// `NODEVICE_SELECT=1`): Mesa's device-select layer must not print "XDG_RUNTIME_DIR
/// is invalid" (DECISIONS.md "Rendering", backend choice). The flight draws through
/// lavapipe (or any GPU).
#[test]
fn fly_run_directly_headless_prints_no_display_noise() {
    let (url, _) = failing_server();
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_tessera"))
        .args(["fly", "--server", &url, "--dataset", "terrain"])
        .args([
            "--path", "orbit", "--frames", "2", "--width", "64", "--height", "64",
        ])
        .arg("--out")
        .arg(dir.path())
        .env_remove("NODEVICE_SELECT")
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    // It drew nothing (every tile is a 503), but it did open a GPU to render with.
    assert!(stderr.contains("drew nothing"), "{stderr}");
    assert!(
        !stderr.contains("XDG_RUNTIME_DIR"),
        "display noise on a headless run: {stderr}"
    );
}
