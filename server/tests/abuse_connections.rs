//! Serving under abuse (DECISIONS.md "Reliability", RELIABILITY.md): what hostile or
//! careless clients do to a real `tessera-server serve` over real sockets with their
//! connections — slowloris, idle keep-alive sockets, idle sockets past the fd limit, a
//! thousand keep-alive connections at once, SIGTERM with requests in flight — and what
//! must survive.
//!
//! No test measures time: deadlines are generous bounds on "eventually", many times
//! the configured timeout.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{Server, fixtures, raw_get, rss_kib};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};
use tessera_shared::Pyramid;

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
