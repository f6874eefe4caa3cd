//! Issue 11, serving: what a hostile or careless client or operator does to a real
//! `tessera-server serve` over real sockets — slowloris, idle sockets past the fd
//! limit, range amplification, files truncated or replaced under the server, bad
//! content hashes, reflected Host headers, sloppy queries — and what must survive.
//!
//! No test measures time: deadlines are generous bounds on "eventually", many times
//! the configured timeout.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

// Shared with serve.rs, which uses the helpers this file does not.
#[allow(dead_code)]
mod serve_support;

use serve_support::{Server, bin, fixtures, metric, parse_metrics, raw_get, raw_request};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};
use tessera_shared::format::{FileHeader, HEADER_LEN};
use tessera_shared::{Pyramid, format};

/// A fresh directory for one test's files (removed on drop).
struct Scratch(PathBuf);

impl Scratch {
    fn new(test: &str) -> Self {
        let d = fixtures()
            .dir
            .join(format!("abuse-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        Self(d)
    }

    fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Runs `serve ARGS` expecting it to refuse to start: returns its stderr. Fails if it
/// prints its listening line instead (the old behaviour), without waiting for a
/// timeout.
fn serve_must_refuse(args: &[&str]) -> String {
    let mut child = bin()
        .arg("serve")
        .args(args)
        .args(["--listen", "127.0.0.1:0"])
        .env("NO_COLOR", "1")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    for line in BufReader::new(stdout).lines().map_while(Result::ok) {
        if line.starts_with("listening on") {
            let _ = child.kill();
            let _ = child.wait();
            panic!("serve {args:?} started instead of refusing");
        }
    }
    let status = child.wait().unwrap();
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    assert!(!status.success(), "serve {args:?} exited 0: {err}");
    assert!(!err.contains("panicked"), "serve {args:?} panicked: {err}");
    err
}

/// Whether the server closed `s`: EOF or a reset. Reads (and drops) whatever the
/// server sent first, e.g. a 408.
fn closed_by_server(s: &mut TcpStream) -> bool {
    s.set_nonblocking(true).unwrap();
    let mut buf = [0u8; 4096];
    loop {
        match s.read(&mut buf) {
            Ok(0) => return true,
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => return false,
            Err(_) => return true,
        }
    }
}

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
    let dir = Scratch::new("hash");
    let cases: [(&str, &[u8; 16]); 4] = [
        ("crlf", b"0123456789ab\r\nXY"),
        ("control", b"0123456789abcd\x07e"),
        ("quote", b"0123456789abcd\"e"),
        ("upper", b"0123456789ABCDEF"),
    ];
    for (name, hash) in cases {
        let bad = dir.path(&format!("{name}.tess"));
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
    let dir = Scratch::new("truncate");
    let live = dir.path("live.tess");
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
    let next = dir.path("live.tess.new");
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
    let dir = Scratch::new("rename");
    let live = dir.path("live.tess");
    copy_to(&f.synth, &live);
    let srv = Server::start(&[&live], &[]);
    let old_hash = srv.get("/v1/datasets/live").expect(200).json()["content_hash"]
        .as_str()
        .unwrap()
        .to_string();
    let old_file = std::fs::read(&f.synth).unwrap();

    let next = dir.path("live.tess.new");
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

// ---------------------------------------------------------------------------
// 8. Slow and idle clients, and connection floods

#[test]
fn slowloris_sockets_are_closed_while_normal_requests_succeed() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth], &["--header-timeout-secs", "1"]);
    let mut socks: Vec<TcpStream> = (0..50)
        .map(|_| {
            let mut s = TcpStream::connect(srv.addr).unwrap();
            s.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
                .unwrap();
            s
        })
        .collect();
    let mut open = vec![true; socks.len()];
    let mut served_meanwhile = 0;
    // 30× the header timeout: only a server that never closes them fails.
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut round = 0u32;
    while open.iter().any(|o| *o) {
        assert!(
            Instant::now() < deadline,
            "{} of {} slowloris sockets still open after 30 s with a 1 s header timeout",
            open.iter().filter(|o| **o).count(),
            socks.len()
        );
        for (s, o) in socks.iter_mut().zip(open.iter_mut()) {
            if *o {
                // One more header byte each round, never the blank line.
                let dribble = s.write_all(if round.is_multiple_of(2) { b"X" } else { b"-" });
                if dribble.is_err() || closed_by_server(s) {
                    *o = false;
                }
            }
        }
        // A normal client is served throughout.
        let r = raw_get(srv.addr, "/healthz");
        assert_eq!(r.status, 200);
        served_meanwhile += 1;
        round += 1;
        std::thread::sleep(Duration::from_millis(200));
    }
    assert!(served_meanwhile > 0);
    srv.get("/healthz").expect(200);
}

#[test]
fn idle_keep_alive_connections_are_closed_after_the_idle_timeout() {
    let f = fixtures();
    // The header timeout is long, so only the idle timeout can close these.
    let srv = Server::start(
        &[&f.synth],
        &["--header-timeout-secs", "600", "--idle-timeout-secs", "1"],
    );
    let mut socks: Vec<TcpStream> = (0..10)
        .map(|_| TcpStream::connect(srv.addr).unwrap())
        .collect();
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut open: Vec<bool> = vec![true; socks.len()];
    while open.iter().any(|o| *o) {
        assert!(
            Instant::now() < deadline,
            "idle sockets still open after 30 s with a 1 s idle timeout"
        );
        for (s, o) in socks.iter_mut().zip(open.iter_mut()) {
            if *o && closed_by_server(s) {
                *o = false;
            }
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    srv.get("/healthz").expect(200);
}

#[test]
fn idle_sockets_beyond_the_fd_limit_do_not_lock_clients_out() {
    let f = fixtures();
    // Timeouts far away: only the connection cap can make room.
    let nofile = 256;
    let srv = Server::start_with_fd_limit(
        &[&f.synth],
        &["--header-timeout-secs", "600", "--idle-timeout-secs", "600"],
        nofile,
    );
    // More idle sockets than the server has descriptors.
    let mut idle: Vec<TcpStream> = (0..nofile + 100)
        .map(|_| TcpStream::connect(srv.addr).unwrap())
        .collect();
    // A new client is still served, repeatedly.
    for _ in 0..5 {
        let r = raw_get(srv.addr, "/healthz");
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    }
    // The server made room by closing idle sockets (the oldest first), and kept
    // fewer open than its descriptor limit.
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let still_open = idle
            .iter_mut()
            .map(|s| !closed_by_server(s))
            .filter(|open| *open)
            .count();
        if still_open < nofile as usize {
            assert!(
                closed_by_server(&mut idle[0]),
                "the oldest idle socket should be among the closed"
            );
            break;
        }
        assert!(
            Instant::now() < deadline,
            "{still_open} idle sockets open on a server limited to {nofile} descriptors"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    assert!(srv.log().lines().all(|l| !l.contains("panicked")));
    srv.get("/healthz").expect(200);
}

#[test]
fn sigterm_finishes_in_flight_requests_and_closes_idle_connections() {
    let f = fixtures();
    let mut srv = Server::start(
        &[&f.synth4k],
        &["--header-timeout-secs", "600", "--idle-timeout-secs", "600"],
    );
    // Idle keep-alive connections, each after one request: they must not hold the
    // shutdown up.
    let mut idle: Vec<TcpStream> = (0..5)
        .map(|_| {
            let mut s = TcpStream::connect(srv.addr).unwrap();
            s.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
                .unwrap();
            let mut buf = [0u8; 1024];
            let n = s.read(&mut buf).unwrap();
            assert!(buf[..n].starts_with(b"HTTP/1.1 200"));
            s
        })
        .collect();
    // Several large responses in flight, read slowly.
    let finest = Pyramid::open_file(&f.synth4k).unwrap().geometry().finest();
    let want = srv
        .get(&format!(
            "/v1/datasets/synth4k/levels/{finest}/tiles?ranges=0-1023"
        ))
        .expect(200)
        .body;
    let mut inflight: Vec<TcpStream> = (0..3)
        .map(|_| {
            let mut s = TcpStream::connect(srv.addr).unwrap();
            write!(
                s,
                "GET /v1/datasets/synth4k/levels/{finest}/tiles?ranges=0-1023 HTTP/1.1\r\nHost: x\r\n\r\n"
            )
            .unwrap();
            let mut first = [0u8; 1];
            s.read_exact(&mut first).unwrap();
            s
        })
        .collect();
    srv.terminate();
    for s in &mut inflight {
        s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
        let mut all = vec![b'H'];
        s.read_to_end(&mut all).unwrap();
        let end = serve_support::find(&all, b"\r\n\r\n").unwrap();
        assert!(all.starts_with(b"HTTP/1.1 200"));
        assert!(all[end + 4..] == want[..], "an in-flight response was cut");
    }
    let status = srv.wait_exit(Duration::from_secs(60));
    assert!(status.success(), "{status:?}");
    for s in &mut idle {
        assert!(closed_by_server(s));
    }
}

// ---------------------------------------------------------------------------
// 9. Range amplification

#[test]
fn overlapping_byte_ranges_never_send_more_than_the_file() {
    let f = fixtures();
    let file = std::fs::read(&f.synth).unwrap();
    let size = file.len();
    let srv = Server::start(&[&f.synth], &[]);
    let url = "/v1/datasets/synth/pyramid";

    let spec = format!("bytes={}", vec!["0-"; 64].join(","));
    let r = srv.get_with(url, &[("range", &spec)]);
    assert!(
        r.body.len() <= size,
        "{} bytes for a {size}-byte file",
        r.body.len()
    );
    assert_eq!(r.status, 206);
    assert_eq!(
        r.must("content-range"),
        format!("bytes 0-{}/{size}", size - 1)
    );
    assert!(r.body == file);

    // Overlapping and touching ranges become one.
    let r = srv.get_with(url, &[("range", "bytes=0-9,5-19,20-29")]);
    assert_eq!(r.status, 206);
    assert_eq!(r.must("content-range"), format!("bytes 0-29/{size}"));
    assert!(r.body == file[..30]);

    // Many small overlapping ranges: still at most the bytes they cover, plus parts.
    let spec: Vec<String> = (0..64)
        .map(|i| format!("{}-{}", i * 1000, i * 1000 + 1500))
        .collect();
    let r = srv.get_with(url, &[("range", &format!("bytes={}", spec.join(",")))]);
    assert_eq!(r.status, 206);
    assert_eq!(r.must("content-range"), format!("bytes 0-64500/{size}"));
    assert!(r.body == file[..=64500]);
}

// ---------------------------------------------------------------------------
// 10. Host header

fn tiles_url(srv: &Server, headers: &str) -> String {
    let r = raw_request(srv.addr, "/v1/datasets/synth/tilejson.json", headers);
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    let j: serde_json::Value = serde_json::from_slice(&r.body).unwrap();
    j["tiles"][0].as_str().unwrap().to_string()
}

#[test]
fn tilejson_urls_never_come_from_the_host_header() {
    let f = fixtures();
    let hash = Pyramid::open_file(&f.synth)
        .unwrap()
        .metadata()
        .content_hash
        .clone();
    let path = format!("/v1/datasets/synth/{{z}}/{{x}}/{{y}}.png?encoding=terrarium&v={hash}");

    // Default: relative URLs, whatever Host (or none) and forwarded headers say.
    let srv = Server::start(&[&f.synth], &[]);
    for headers in [
        "Host: evil.example\r\n",
        "",
        "Host: evil.example\r\nX-Forwarded-Host: evil2.example\r\nX-Forwarded-Proto: https\r\n",
    ] {
        let url = tiles_url(&srv, headers);
        assert_eq!(url, path, "{headers:?}");
    }
    // The relative template resolves on this server.
    let png = srv.get(
        &path
            .replace("{z}", "1")
            .replace("{x}", "0")
            .replace("{y}", "1"),
    );
    assert_eq!(png.expect(200).must("content-type"), "image/png");
    drop(srv);

    // --public-url: exactly that, whatever the request says.
    let srv = Server::start(&[&f.synth], &["--public-url", "https://tiles.example.org/"]);
    for headers in [
        "Host: evil.example\r\n",
        "",
        "X-Forwarded-Host: evil.example\r\n",
    ] {
        assert_eq!(
            tiles_url(&srv, headers),
            format!("https://tiles.example.org{path}"),
            "{headers:?}"
        );
    }
    drop(srv);

    // --trust-forwarded: the proxy's headers, checked; never Host.
    let srv = Server::start(&[&f.synth], &["--trust-forwarded"]);
    assert_eq!(
        tiles_url(
            &srv,
            "Host: evil.example\r\nX-Forwarded-Host: cdn.example\r\nX-Forwarded-Proto: https\r\n"
        ),
        format!("https://cdn.example{path}")
    );
    assert_eq!(
        tiles_url(&srv, "Host: evil.example\r\n"),
        path,
        "no forwarded host: relative"
    );
    let r = raw_request(
        srv.addr,
        "/v1/datasets/synth/tilejson.json",
        "X-Forwarded-Host: evil.example/x?\r\n",
    );
    assert_eq!(r.status, 400);
    let r = raw_request(
        srv.addr,
        "/v1/datasets/synth/tilejson.json",
        "X-Forwarded-Host: cdn.example\r\nX-Forwarded-Proto: javascript\r\n",
    );
    assert_eq!(r.status, 400);
}

// ---------------------------------------------------------------------------
// 12. The smaller ones

fn json_error(r: &serve_support::RawResp) -> String {
    assert!(
        r.headers
            .get("content-type")
            .is_some_and(|t| t.starts_with("application/json")),
        "{:?}: {}",
        r.headers,
        String::from_utf8_lossy(&r.body)
    );
    let j: serde_json::Value = serde_json::from_slice(&r.body).unwrap();
    j["error"].as_str().unwrap().to_string()
}

#[test]
fn every_error_is_json_and_sloppy_queries_are_rejected() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth], &[]);
    for target in [
        "/v1/datasets/%ff%fe",
        "/v1/datasets/%ff%fe/pyramid",
        "/v1/datasets/synth/levels/%ff/tiles?ranges=0",
        "/v1/datasets/synth/tiles/1/%c3%28/0",
    ] {
        let r = raw_get(srv.addr, target);
        assert_eq!(r.status, 400, "{target}");
        let msg = json_error(&r);
        assert!(msg.contains("UTF-8"), "{target}: {msg}");
        assert!(
            !msg.contains('\u{fffd}') && !msg.contains("\\x"),
            "{target}: {msg}"
        );
    }
    for (query, want) in [
        ("ranges=+5", "digits only"),
        ("ranges=%205", "digits only"),
        ("ranges=5%20", "digits only"),
        ("ranges=0-%2B3", "digits only"),
        ("ranges=0&ranges=1", "more than once"),
        ("ranges=0&v=a&v=b", "more than once"),
    ] {
        let r = raw_get(
            srv.addr,
            &format!("/v1/datasets/synth/levels/1/tiles?{query}"),
        );
        assert_eq!(r.status, 400, "{query}");
        let msg = json_error(&r);
        assert!(msg.contains(want), "{query}: {msg}");
    }
    // Percent-encoded bytes that are not UTF-8 in the query: a JSON 400 too.
    let r = raw_get(srv.addr, "/v1/datasets/synth/levels/1/tiles?ranges=%ff");
    assert_eq!(r.status, 400);
    assert!(json_error(&r).contains("malformed range"));
}

#[test]
fn corrupt_records_are_counted_once_and_reads_every_time() {
    let f = fixtures();
    let srv = Server::start(&[&f.corrupt], &[]);
    let c = f.corrupt_tile;
    let single = format!(
        "/v1/datasets/synth-corrupt/tiles/{}/{}/{}",
        c.level(),
        c.x(),
        c.y()
    );
    let stream = format!(
        "/v1/datasets/synth-corrupt/levels/{}/tiles?ranges={}",
        c.level(),
        c.morton()
    );
    for _ in 0..3 {
        srv.get(&single).error(500);
    }
    srv.get(&stream).expect(200);
    let m = parse_metrics(&srv.get("/metrics").expect(200).text());
    assert_eq!(metric(&m, "tessera_corrupt_records_total"), 1.0);
    assert_eq!(metric(&m, "tessera_corrupt_record_reads_total"), 4.0);
}

#[test]
fn zero_limits_are_refused_naming_the_flag() {
    let f = fixtures();
    let file = f.synth.to_str().unwrap();
    for flag in [
        "--max-ranges",
        "--max-tiles",
        "--timeout-secs",
        "--concurrency",
        "--header-timeout-secs",
        "--idle-timeout-secs",
        "--max-connections",
    ] {
        let err = serve_must_refuse(&[file, flag, "0"]);
        assert!(err.contains(flag), "{flag}: {err}");
    }
}

#[test]
fn logs_have_no_colour_codes_off_a_terminal_and_quiet_keeps_only_errors() {
    let f = fixtures();
    let file = f.synth.to_str().unwrap();
    // A warning at start-up: the cap asked for is above the fd limit.
    let run = |extra: &[&str]| -> String {
        let mut child = bin()
            .arg("serve")
            .arg(file)
            .args(["--listen", "127.0.0.1:0", "--max-connections", "100000000"])
            .args(extra)
            .env_remove("NO_COLOR")
            .env_remove("RUST_LOG")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut out = BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        out.read_line(&mut line).unwrap();
        let addr = line
            .trim()
            .strip_prefix("listening on http://")
            .unwrap()
            .to_string();
        let r = raw_get(addr.parse().unwrap(), "/v1/datasets/nope");
        assert_eq!(r.status, 404);
        let _ = child.kill();
        let _ = child.wait();
        let mut err = String::new();
        child
            .stderr
            .take()
            .unwrap()
            .read_to_string(&mut err)
            .unwrap();
        err
    };
    let loud = run(&[]);
    assert!(loud.contains("WARN"), "{loud}");
    assert!(loud.contains("request"), "{loud}");
    assert!(!loud.contains('\x1b'), "ANSI codes in a pipe: {loud:?}");
    let quiet = run(&["-q"]);
    assert!(
        !quiet.contains("WARN") && !quiet.contains("INFO"),
        "{quiet}"
    );
}

/// Reads one whole HTTP/1.1 response (head and `Content-Length` body) from a
/// keep-alive connection; returns its status.
fn read_keep_alive_response(s: &mut TcpStream) -> u16 {
    let mut head = Vec::new();
    let mut byte = [0u8; 1];
    while serve_support::find(&head, b"\r\n\r\n").is_none() {
        s.read_exact(&mut byte).unwrap();
        head.push(byte[0]);
    }
    let (status, headers) = serve_support::parse_head(std::str::from_utf8(&head).unwrap());
    let len: usize = headers["content-length"].parse().unwrap();
    let mut body = vec![0u8; len];
    s.read_exact(&mut body).unwrap();
    status
}

/// Kilobytes of the process's resident memory (`VmRSS` or `VmHWM`).
fn rss_kib(pid: u32, field: &str) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    status
        .lines()
        .find_map(|l| l.strip_prefix(field)?.trim().strip_suffix("kB"))
        .and_then(|v| v.trim().parse().ok())
        .unwrap()
}

const CONNECTIONS: usize = 1024;

/// 1024 keep-alive connections open at once, each served twice (so each is really
/// kept alive): every request gets a 200, and the server's resident memory stays
/// bounded. RSS is reported, and checked against a generous bound (64 KiB of
/// buffers per connection over the idle server's), never timed.
///
/// The test process needs more descriptors than the usual soft limit of 1024, so
/// the body runs in a copy of this test binary started with a raised limit.
#[test]
fn a_thousand_keep_alive_connections_are_served_with_bounded_memory() {
    if std::env::var_os("TESSERA_KEEP_ALIVE_CHILD").is_none() {
        let me = std::env::current_exe().unwrap();
        let o = std::process::Command::new("sh")
            .arg("-c")
            .arg("ulimit -n 4096 && exec \"$0\" --exact \"$1\" --nocapture --test-threads 1")
            .arg(me)
            .arg("a_thousand_keep_alive_connections_are_served_with_bounded_memory")
            .env("TESSERA_KEEP_ALIVE_CHILD", "1")
            .output()
            .unwrap();
        let out = String::from_utf8_lossy(&o.stdout);
        let err = String::from_utf8_lossy(&o.stderr);
        eprintln!("{err}");
        assert!(o.status.success(), "the child run failed:\n{out}\n{err}");
        assert!(out.contains("1 passed"), "the child ran no test:\n{out}");
        return;
    }
    let f = fixtures();
    let srv = Server::start_with_fd_limit(&[&f.synth], &[], 4096);
    let idle = rss_kib(srv.pid(), "VmRSS:");
    let g = *Pyramid::open_file(&f.synth).unwrap().geometry();
    let tiles: Vec<_> = g.present_tiles(g.finest()).collect();
    let mut socks: Vec<TcpStream> = (0..CONNECTIONS)
        .map(|_| {
            let s = TcpStream::connect(srv.addr).unwrap();
            s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
            s
        })
        .collect();
    for round in 0..2 {
        // Every connection has a request in flight before any answer is read.
        for (i, s) in socks.iter_mut().enumerate() {
            let t = tiles[(i + round) % tiles.len()];
            write!(
                s,
                "GET /v1/datasets/synth/tiles/{}/{}/{} HTTP/1.1\r\nHost: t\r\n\r\n",
                t.level().get(),
                t.x(),
                t.y()
            )
            .unwrap();
        }
        for s in &mut socks {
            assert_eq!(read_keep_alive_response(s), 200, "round {round}");
        }
    }
    let busy = rss_kib(srv.pid(), "VmRSS:");
    let peak = rss_kib(srv.pid(), "VmHWM:");
    drop(socks);
    eprintln!(
        "{CONNECTIONS} keep-alive connections: server RSS {idle} KiB idle, {busy} KiB with all \
         open, peak {peak} KiB"
    );
    let bound = idle + 64 * CONNECTIONS as u64 + 32 * 1024;
    assert!(peak <= bound, "peak RSS {peak} KiB over {bound} KiB");
}
