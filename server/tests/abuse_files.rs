//! Serving under abuse (DECISIONS.md "Reliability", RELIABILITY.md): what a careless
//! operator does to the files under a real `tessera-server serve` — files truncated or
//! replaced while served (then SIGHUP), bad content hashes at start-up — and what must
//! survive.
//!
//! No test measures time: deadlines are generous bounds on "eventually", many times
//! the configured timeout.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{Server, fixtures, serve_must_refuse};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::time::{Duration, Instant};
use tessera_shared::format::{FileHeader, HEADER_LEN};
use tessera_shared::{Pyramid, format};

fn copy_to(src: &Path, dst: &Path) {
    std::fs::copy(src, dst).unwrap();
}

// ---------------------------------------------------------------------------
// 6. Bad content hashes are refused at start-up

/// A copy of `src` whose metadata says `content_hash` is `hash` (16 bytes, so the
/// metadata keeps its length), with the header checksum recomputed so that only the
/// hash is wrong.
fn with_content_hash(src: &Path, dst: &Path, hash: &[u8; 16]) {
    let mut bytes = std::fs::read(src).unwrap();
    let header = FileHeader::parse(&bytes[..HEADER_LEN]).unwrap();
    let meta_at = header.meta_offset as usize;
    let meta_end = meta_at + header.meta_len as usize;
    let old = Pyramid::open(bytes.clone())
        .unwrap()
        .metadata()
        .content_hash
        .clone();
    // bincode stores a string as its length then its bytes: the hash's 16 bytes
    // appear once in the metadata, right after a length byte of 16.
    let mut needle = vec![16u8];
    needle.extend_from_slice(old.as_bytes());
    let region = &bytes[meta_at..meta_end];
    let at = region
        .windows(needle.len())
        .position(|w| w == needle.as_slice())
        .expect("the content hash inside the metadata")
        + meta_at
        + 1;
    bytes[at..at + 16].copy_from_slice(hash);
    let mut header = header;
    header.checksum = header.compute_checksum(&bytes[HEADER_LEN..header.records_offset as usize]);
    bytes[..HEADER_LEN].copy_from_slice(&header.to_bytes());
    std::fs::write(dst, &bytes).unwrap();
    // The edit is what we meant: the metadata still decodes, with the new hash.
    let m = format::decode_metadata(&bytes[meta_at..meta_end]).unwrap();
    assert_eq!(m.content_hash.as_bytes(), hash);
}

#[test]
fn bad_content_hash_is_refused_at_startup() {
    let f = fixtures();
    let dir = tempfile::Builder::new()
        .prefix("abuse-hash-")
        .tempdir()
        .unwrap();
    let cases: [(&str, &[u8; 16]); 4] = [
        ("crlf", b"0123456789ab\r\nXY"),
        ("control", b"0123456789abcd\x07e"),
        ("quote", b"0123456789abcd\"e"),
        ("upper", b"0123456789ABCDEF"),
    ];
    for (name, hash) in cases {
        let bad = dir.path().join(format!("{name}.tess"));
        with_content_hash(&f.synth, &bad, hash);
        // Served alone or beside a good file: the server refuses, naming the file.
        for args in [
            vec![bad.to_str().unwrap()],
            vec![f.synth.to_str().unwrap(), bad.to_str().unwrap()],
        ] {
            let err = serve_must_refuse(&args);
            assert!(err.contains(bad.to_str().unwrap()), "{name}: {err}");
            assert!(err.contains("content_hash"), "{name}: {err}");
            // The raw control bytes are never echoed into the log.
            assert!(
                !err.contains('\x07') && !err.contains("\r\n"),
                "{name}: {err:?}"
            );
        }
    }
}

// ---------------------------------------------------------------------------
// 7. Files truncated or replaced under the server

/// `GET path` on a fresh connection; `None` if the server did not answer at all.
fn try_status(srv: &Server, path: &str) -> Option<(u16, String, String)> {
    let mut s = TcpStream::connect(srv.addr).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(30))).ok()?;
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut all = Vec::new();
    s.read_to_end(&mut all).ok()?;
    let end = serve_support::find(&all, b"\r\n\r\n")?;
    let (status, headers) = serve_support::parse_head(std::str::from_utf8(&all[..end]).ok()?);
    let ct = headers.get("content-type").cloned().unwrap_or_default();
    Some((
        status,
        ct,
        String::from_utf8_lossy(&all[end + 4..]).to_string(),
    ))
}

#[test]
fn truncated_file_answers_503_others_keep_serving_and_sighup_reloads() {
    let f = fixtures();
    let dir = tempfile::Builder::new()
        .prefix("abuse-truncate-")
        .tempdir()
        .unwrap();
    let live = dir.path().join("live.tess");
    copy_to(&f.synth, &live);
    let srv = Server::start(&[&live, &f.synth4k], &[]);
    let finest = Pyramid::open_file(&f.synth).unwrap().geometry().finest();
    let routes = [
        format!("/v1/datasets/live/levels/{finest}/tiles?ranges=0-63"),
        format!("/v1/datasets/live/levels/{finest}/errors?ranges=0-63"),
        format!("/v1/datasets/live/tiles/{finest}/3/3"),
        "/v1/datasets/live/pyramid".to_string(),
        "/v1/datasets/live/2/1/1.png".to_string(),
        "/v1/datasets/live".to_string(),
        "/v1/datasets/live/tilejson.json".to_string(),
    ];
    for r in &routes {
        srv.get(r).expect(200);
    }

    // Load on both datasets while the file is truncated in place (what `cp` over a
    // served file does first).
    let stop = std::sync::atomic::AtomicBool::new(false);
    std::thread::scope(|s| {
        let load = s.spawn(|| {
            let mut answered = 0u32;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                for r in [&routes[0], &routes[3]] {
                    if try_status(&srv, r).is_some() {
                        answered += 1;
                    }
                }
            }
            answered
        });
        std::thread::sleep(Duration::from_millis(300));
        std::fs::OpenOptions::new()
            .write(true)
            .open(&live)
            .unwrap()
            .set_len(100_000)
            .unwrap();
        std::thread::sleep(Duration::from_millis(500));
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        assert!(load.join().unwrap() > 0);
    });

    // Every route of the truncated dataset: 503 with a JSON reason, and the
    // process is alive.
    for r in &routes {
        let (status, ct, body) =
            try_status(&srv, r).unwrap_or_else(|| panic!("GET {r}: no answer: the server died"));
        assert_eq!(status, 503, "GET {r}: {body}");
        assert!(ct.starts_with("application/json"), "GET {r}: {ct}");
        let j: serde_json::Value = serde_json::from_str(&body).unwrap();
        let msg = j["error"].as_str().unwrap();
        assert!(
            msg.contains("live") && msg.contains("changed size"),
            "{msg}"
        );
    }
    // The other dataset and the server's own endpoints are unaffected.
    srv.get(&format!(
        "/v1/datasets/synth4k/levels/{finest}/tiles?ranges=0-15"
    ))
    .expect(200);
    srv.get("/v1/datasets/synth4k/pyramid").expect(200);
    srv.get("/healthz").expect(200);
    let list = srv.get("/v1/datasets").expect(200).json();
    let names: Vec<&str> = list["datasets"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| d["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["synth4k"], "the unavailable dataset is left out");

    // The safe deploy: a complete file renamed over the path, then SIGHUP.
    let next = dir.path().join("live.tess.new");
    copy_to(&f.synth, &next);
    std::fs::rename(&next, &live).unwrap();
    srv.signal("HUP");
    let deadline = Instant::now() + Duration::from_secs(60);
    while try_status(&srv, &routes[0]).map(|r| r.0) != Some(200) {
        assert!(
            Instant::now() < deadline,
            "SIGHUP did not reload: {}",
            srv.log()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    for r in &routes {
        srv.get(r).expect(200);
    }
}

#[test]
fn renamed_file_keeps_serving_the_old_inode_until_sighup() {
    let f = fixtures();
    let dir = tempfile::Builder::new()
        .prefix("abuse-rename-")
        .tempdir()
        .unwrap();
    let live = dir.path().join("live.tess");
    copy_to(&f.synth, &live);
    let srv = Server::start(&[&live], &[]);
    let old_hash = srv.get("/v1/datasets/live").expect(200).json()["content_hash"]
        .as_str()
        .unwrap()
        .to_string();
    let old_file = std::fs::read(&f.synth).unwrap();

    let next = dir.path().join("live.tess.new");
    copy_to(&f.synth4k, &next);
    std::fs::rename(&next, &live).unwrap();
    // Until told, the server keeps the file it opened: same hash, same bytes.
    let j = srv.get("/v1/datasets/live").expect(200).json();
    assert_eq!(j["content_hash"], old_hash.as_str());
    assert!(srv.get("/v1/datasets/live/pyramid").expect(200).body == old_file);

    srv.signal("HUP");
    let new_hash = Pyramid::open_file(&f.synth4k)
        .unwrap()
        .metadata()
        .content_hash
        .clone();
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let j = srv.get("/v1/datasets/live").expect(200).json();
        if j["content_hash"] == new_hash.as_str() {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "SIGHUP did not reload: {}",
            srv.log()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let new_file = std::fs::read(&f.synth4k).unwrap();
    assert!(srv.get("/v1/datasets/live/pyramid").expect(200).body == new_file);

    // A reload that fails (a file that does not open) keeps the datasets served.
    std::fs::write(&next, b"not a pyramid").unwrap();
    std::fs::rename(&next, &live).unwrap();
    srv.signal("HUP");
    std::thread::sleep(Duration::from_millis(500));
    let deadline = Instant::now() + Duration::from_secs(60);
    while !srv.log().contains("reload failed") {
        assert!(
            Instant::now() < deadline,
            "no reload error logged: {}",
            srv.log()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    assert_eq!(
        srv.get("/v1/datasets/live").expect(200).json()["content_hash"],
        new_hash.as_str()
    );
}
