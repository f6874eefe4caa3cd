//! Loopback peers for the proxy's own tests: upstreams that echo, or answer each HTTP
//! request with the next scripted response, and the client's side of HTTP/1.1.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use tokio::io::{AsyncBufRead, AsyncBufReadExt, AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpListener;

/// `n` bytes without a short period, so a shifted or reordered copy never matches.
pub(crate) fn pattern(n: usize) -> Vec<u8> {
    let mut x = 0x9E37_79B9_u32;
    (0..n)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            (x >> 24) as u8
        })
        .collect()
}

/// An upstream that sends every connection's bytes back until the connection ends.
pub(crate) async fn echo_upstream() -> SocketAddr {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move {
        while let Ok((s, _)) = listener.accept().await {
            tokio::spawn(async move {
                let (mut r, mut w) = s.into_split();
                let _ = tokio::io::copy(&mut r, &mut w).await;
            });
        }
    });
    addr
}

/// An HTTP upstream: answers the i-th request head it receives (on any connection)
/// with `responses[i]` (the last one again once they run out), and keeps every byte
/// it received.
#[derive(Debug)]
pub(crate) struct HttpUpstream {
    pub addr: SocketAddr,
    pub received: Arc<Mutex<Vec<u8>>>,
}

pub(crate) async fn http_upstream(responses: Vec<Vec<u8>>) -> HttpUpstream {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let received = Arc::new(Mutex::new(Vec::new()));
    let keep = received.clone();
    let responses = Arc::new(responses);
    let answered = Arc::new(Mutex::new(0usize));
    tokio::spawn(async move {
        while let Ok((s, _)) = listener.accept().await {
            let (keep, responses, answered) = (keep.clone(), responses.clone(), answered.clone());
            tokio::spawn(async move {
                let (mut r, mut w) = s.into_split();
                let mut pending = Vec::new();
                let mut buf = [0u8; 4096];
                loop {
                    let n = match r.read(&mut buf).await {
                        Ok(0) | Err(_) => return,
                        Ok(n) => n,
                    };
                    keep.lock().unwrap().extend_from_slice(&buf[..n]);
                    pending.extend_from_slice(&buf[..n]);
                    while let Some(end) = pending.windows(4).position(|w| w == b"\r\n\r\n") {
                        pending.drain(..end + 4);
                        let i = {
                            let mut a = answered.lock().unwrap();
                            *a += 1;
                            (*a - 1).min(responses.len() - 1)
                        };
                        if w.write_all(&responses[i]).await.is_err() {
                            return;
                        }
                    }
                }
            });
        }
    });
    HttpUpstream { addr, received }
}

/// A complete `200 OK` response with a Content-Length.
pub(crate) fn response(content_type: &str, body: &[u8]) -> Vec<u8> {
    let mut v = format!(
        "HTTP/1.1 200 OK\r\ncontent-type: {content_type}\r\ncontent-length: {}\r\nx-test: kept\r\n\r\n",
        body.len()
    )
    .into_bytes();
    v.extend_from_slice(body);
    v
}

/// A GET request head for `target`.
pub(crate) fn get(target: &str) -> Vec<u8> {
    format!("GET {target} HTTP/1.1\r\nhost: proxy.test\r\n\r\n").into_bytes()
}

/// Reads one response with a Content-Length: its head (with the blank line) and body.
pub(crate) async fn read_response(r: &mut (impl AsyncBufRead + Unpin)) -> (String, Vec<u8>) {
    let mut head = Vec::new();
    while !head.ends_with(b"\r\n\r\n") {
        let n = r.read_until(b'\n', &mut head).await.unwrap();
        assert!(n > 0, "the response ended inside its head: {head:?}");
    }
    let head = String::from_utf8(head).unwrap();
    let len: usize = head
        .lines()
        .find_map(|l| {
            let (k, v) = l.split_once(':')?;
            k.eq_ignore_ascii_case("content-length")
                .then(|| v.trim().parse().unwrap())
        })
        .expect("no content-length");
    let mut body = vec![0u8; len];
    r.read_exact(&mut body).await.unwrap();
    (head, body)
}

/// Waits (a minute at most: a bound no correct proxy comes near, and no deadline
/// that could fail one on a slow machine) until `proxy` has counted `n` holds.
pub(crate) async fn until_held(proxy: &crate::Proxy, n: u64) {
    let started = std::time::Instant::now();
    while proxy.stats().held < n {
        assert!(
            started.elapsed() < std::time::Duration::from_secs(60),
            "{:?}: never held {n} times",
            proxy.stats()
        );
        tokio::time::sleep(std::time::Duration::from_millis(2)).await;
    }
}

/// Sends `GET /a` through `proxy` on a plain socket (so that a read asks the kernel
/// what has arrived), waits until the proxy holds the response, and checks that the
/// upstream got the request and not one byte of the response reached the client.
pub(crate) async fn assert_held_back(proxy: &crate::Proxy, upstream: &HttpUpstream) {
    let mut client = std::net::TcpStream::connect(proxy.addr()).unwrap();
    std::io::Write::write_all(&mut client, &get("/a")).unwrap();
    client.set_nonblocking(true).unwrap();
    until_held(proxy, 1).await;
    assert_eq!(*upstream.received.lock().unwrap(), get("/a"));
    let mut buf = [0u8; 64];
    match std::io::Read::read(&mut client, &mut buf) {
        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
        other => panic!("the client could read a held response: {other:?}"),
    }
}
