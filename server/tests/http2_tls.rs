//! `tessera-server serve` end to end over HTTP/2 and TLS (API.md "HTTP
//! conventions"): h2c with prior knowledge serves what HTTP/1.1 does, idle h2c
//! connections close at the header timeout, TLS negotiates h2 by ALPN and serves
//! HTTP/1.1 too, a stalled handshake is closed, and bad TLS files stop the server
//! with an error naming the file. CORS, compression and validators over HTTP/1.1
//! are in `http_conventions.rs`.
//!
//! Every test starts its own server (real process, real sockets) on the shared
//! fixtures (`serve_support`).

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{CACHEABLE, Resp, Server, fixtures, gunzip, serve_must_refuse};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

// ---------------------------------------------------------------------------
// HTTP/2

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
}

/// `GET url` with `client`: the HTTP version and the response.
fn fetch(
    rt: &tokio::runtime::Runtime,
    client: &reqwest::Client,
    url: &str,
    headers: &[(&str, &str)],
) -> (reqwest::Version, Resp) {
    rt.block_on(async {
        let mut req = client.get(url);
        for (k, v) in headers {
            req = req.header(*k, *v);
        }
        let r = req
            .send()
            .await
            .unwrap_or_else(|e| panic!("GET {url}: {e:?}"));
        let version = r.version();
        let status = r.status().as_u16();
        let headers = r.headers().clone();
        let body = r.bytes().await.unwrap().to_vec();
        (
            version,
            Resp {
                path: url.to_string(),
                status,
                headers,
                body,
            },
        )
    })
}

#[test]
fn h2c_with_prior_knowledge_serves_the_same_responses_as_http1() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth], &[]);
    let rt = runtime();
    serve_support::install_tls_provider();
    let h2 = reqwest::Client::builder()
        .no_proxy()
        .http2_prior_knowledge()
        .timeout(Duration::from_secs(60))
        .build()
        .unwrap();
    for path in CACHEABLE {
        let h1 = srv.get(path).expect(200);
        let (version, r) = fetch(&rt, &h2, &srv.url(path), &[]);
        assert_eq!(version, reqwest::Version::HTTP_2, "{path}");
        assert_eq!(r.status, 200, "{path}");
        assert_eq!(r.must("etag"), h1.must("etag"), "{path}");
        assert_eq!(r.must("last-modified"), h1.must("last-modified"), "{path}");
        assert_eq!(r.body, h1.body, "{path}");
        let (_, r) = fetch(
            &rt,
            &h2,
            &srv.url(path),
            &[("if-none-match", h1.must("etag"))],
        );
        assert_eq!(r.status, 304, "{path} over h2");
    }
    // Many streams on the one connection at once.
    let results = rt.block_on(async {
        let mut set = tokio::task::JoinSet::new();
        for i in 0..64u32 {
            let h2 = h2.clone();
            let url = srv.url(&format!("/v1/datasets/synth/tiles/3/{}/{}", i % 8, i / 8));
            set.spawn(async move { h2.get(url).send().await.map(|r| r.status().as_u16()) });
        }
        set.join_all().await
    });
    assert!(results.iter().all(|r| matches!(r, Ok(200))), "{results:?}");
}

/// What an HTTP/2 client sends first (RFC 9113 §3.4).
const PREFACE: &[u8] = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n";

/// An HTTP/2 frame header: length, type, flags, stream.
fn h2_frame(kind: u8, flags: u8, stream: u32, payload: &[u8]) -> Vec<u8> {
    let len = payload.len() as u32;
    let mut f = vec![(len >> 16) as u8, (len >> 8) as u8, len as u8, kind, flags];
    f.extend_from_slice(&stream.to_be_bytes());
    f.extend_from_slice(payload);
    f
}

/// Reads frames until EOF: `(type, stream)` of each, and how long the EOF took.
fn read_frames(s: &mut TcpStream) -> (Vec<(u8, u32)>, Duration) {
    let started = Instant::now();
    let mut all = Vec::new();
    let mut buf = [0u8; 16384];
    loop {
        match s.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => all.extend_from_slice(&buf[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => break,
            Err(e) => panic!("the server never closed the connection: {e}"),
        }
    }
    let elapsed = started.elapsed();
    let mut frames = Vec::new();
    let mut at = 0;
    while at + 9 <= all.len() {
        let len = (usize::from(all[at]) << 16)
            | (usize::from(all[at + 1]) << 8)
            | usize::from(all[at + 2]);
        let stream = u32::from_be_bytes(all[at + 5..at + 9].try_into().unwrap()) & 0x7fff_ffff;
        frames.push((all[at + 3], stream));
        at += 9 + len;
    }
    (frames, elapsed)
}

#[test]
fn idle_h2c_connections_are_closed_after_the_header_timeout() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth], &["--header-timeout-secs", "1"]);
    let settings = h2_frame(4, 0, 0, &[]);

    // A connection that says it speaks HTTP/2, then sends no request.
    let mut s = TcpStream::connect(srv.addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    s.write_all(PREFACE).unwrap();
    s.write_all(&settings).unwrap();
    let (_, took) = read_frames(&mut s);
    assert!(took < Duration::from_secs(5), "closed after {took:?}");

    // One request (GET /healthz, HPACK: :method GET, :scheme http, :path literal),
    // then silence: the response, then a GOAWAY about a second later, then EOF.
    let mut s = TcpStream::connect(srv.addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let mut block = vec![0x82, 0x86, 0x44, 8];
    block.extend_from_slice(b"/healthz");
    s.write_all(PREFACE).unwrap();
    s.write_all(&settings).unwrap();
    s.write_all(&h2_frame(1, 0x5, 1, &block)).unwrap();
    let (frames, took) = read_frames(&mut s);
    assert!(frames.contains(&(1, 1)), "no response HEADERS: {frames:?}");
    assert!(frames.contains(&(0, 1)), "no response DATA: {frames:?}");
    assert!(
        frames.iter().any(|&(t, _)| t == 7),
        "closed without a GOAWAY: {frames:?}"
    );
    assert!(
        took >= Duration::from_millis(800) && took < Duration::from_secs(5),
        "an idle HTTP/2 connection was closed after {took:?}, want ~1 s"
    );
}

// ---------------------------------------------------------------------------
// TLS

/// A self-signed certificate for 127.0.0.1 and localhost: (cert PEM, key PEM).
fn self_signed() -> (String, String) {
    let c =
        rcgen::generate_simple_self_signed(vec!["127.0.0.1".into(), "localhost".into()]).unwrap();
    (c.cert.pem(), c.signing_key.serialize_pem())
}

/// `GET path` over TLS to `addr`, trusting only `cert_pem` and offering `alpn`,
/// with hyper's client: the protocol ALPN chose and the response.
fn tls_get(
    rt: &tokio::runtime::Runtime,
    addr: std::net::SocketAddr,
    cert_pem: &str,
    alpn: &[&[u8]],
    path: &str,
    headers: &[(&str, &str)],
) -> (Option<Vec<u8>>, hyper::Version, Resp) {
    use hyper_util::rt::{TokioExecutor, TokioIo};
    use rustls::pki_types::pem::PemObject;
    use rustls::pki_types::{CertificateDer, ServerName};
    let mut roots = rustls::RootCertStore::empty();
    roots
        .add(CertificateDer::from_pem_slice(cert_pem.as_bytes()).unwrap())
        .unwrap();
    let mut config = rustls::ClientConfig::builder_with_provider(Arc::new(
        rustls::crypto::ring::default_provider(),
    ))
    .with_safe_default_protocol_versions()
    .unwrap()
    .with_root_certificates(roots)
    .with_no_client_auth();
    config.alpn_protocols = alpn.iter().map(|p| p.to_vec()).collect();
    let connector = tokio_rustls::TlsConnector::from(Arc::new(config));
    rt.block_on(async {
        let tcp = tokio::net::TcpStream::connect(addr).await.unwrap();
        let name = ServerName::IpAddress(addr.ip().into());
        let tls = connector.connect(name, tcp).await.unwrap();
        let chosen = tls.get_ref().1.alpn_protocol().map(<[u8]>::to_vec);
        let io = TokioIo::new(tls);
        let mut req = hyper::Request::get(format!("https://{addr}{path}"));
        for (k, v) in headers {
            req = req.header(*k, *v);
        }
        let response = if chosen.as_deref() == Some(b"h2") {
            let (mut send, conn) = hyper::client::conn::http2::handshake(TokioExecutor::new(), io)
                .await
                .unwrap();
            tokio::spawn(conn);
            send.send_request(req.body(axum::body::Body::empty()).unwrap())
                .await
                .unwrap()
        } else {
            let (mut send, conn) = hyper::client::conn::http1::handshake(io).await.unwrap();
            tokio::spawn(conn);
            let req = req
                .uri(path)
                .header("host", addr.to_string())
                .body(axum::body::Body::empty())
                .unwrap();
            send.send_request(req).await.unwrap()
        };
        let version = response.version();
        let status = response.status().as_u16();
        let headers = response.headers().clone();
        let body = axum::body::to_bytes(axum::body::Body::new(response.into_body()), 1 << 30)
            .await
            .unwrap()
            .to_vec();
        (
            chosen,
            version,
            Resp {
                path: path.to_string(),
                status,
                headers,
                body,
            },
        )
    })
}

fn write_pems(dir: &Path) -> (String, std::path::PathBuf, std::path::PathBuf) {
    let (cert, key) = self_signed();
    let (c, k) = (dir.join("cert.pem"), dir.join("key.pem"));
    std::fs::write(&c, &cert).unwrap();
    std::fs::write(&k, &key).unwrap();
    (cert, c, k)
}

#[test]
fn https_negotiates_h2_by_alpn_and_serves_http1_too() {
    let f = fixtures();
    let dir = tempfile::tempdir().unwrap();
    let (cert, c, k) = write_pems(dir.path());
    // One public URL for both, so the TileJSON (whose URLs are otherwise the
    // request's own scheme and Host) is the same document on each.
    let public = ["--public-url", "https://tiles.example.org"];
    let plain = Server::start(&[&f.synth], &public);
    let srv = Server::start(
        &[&f.synth],
        &[
            "--tls-cert",
            c.to_str().unwrap(),
            "--tls-key",
            k.to_str().unwrap(),
            public[0],
            public[1],
        ],
    );
    assert_eq!(srv.scheme, "https", "the listening line must say https://");
    let rt = runtime();
    let addr = srv.addr;
    for path in CACHEABLE {
        let want = plain.get(path).expect(200);
        let (alpn, v, r) = tls_get(&rt, addr, &cert, &[b"h2", b"http/1.1"], path, &[]);
        assert_eq!(
            alpn.as_deref(),
            Some(&b"h2"[..]),
            "{path}: ALPN did not pick h2"
        );
        assert_eq!(v, hyper::Version::HTTP_2, "{path}");
        assert_eq!(r.status, 200, "{path}");
        assert_eq!(r.must("etag"), want.must("etag"), "{path}");
        assert_eq!(r.body, want.body, "{path}");
        let (alpn, v, r) = tls_get(&rt, addr, &cert, &[b"http/1.1"], path, &[]);
        assert_eq!(alpn.as_deref(), Some(&b"http/1.1"[..]), "{path}");
        assert_eq!(v, hyper::Version::HTTP_11, "{path}");
        assert_eq!(r.status, 200, "{path}");
        assert_eq!(r.must("etag"), want.must("etag"), "{path}");
        assert_eq!(r.body, want.body, "{path}");
    }
    // Compression and CORS work the same over TLS.
    let (_, _, r) = tls_get(
        &rt,
        addr,
        &cert,
        &[b"h2"],
        "/v1/datasets/synth",
        &[("accept-encoding", "gzip"), ("origin", "https://a.example")],
    );
    assert_eq!(r.header("content-encoding"), Some("gzip"));
    assert_eq!(r.must("access-control-allow-origin"), "*");
    assert_eq!(gunzip(&r.body), plain.get("/v1/datasets/synth").body);
    // Plain HTTP on the TLS port is not served.
    let mut s = TcpStream::connect(srv.addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    s.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        .unwrap();
    let mut got = Vec::new();
    let _ = s.read_to_end(&mut got);
    assert!(
        !got.starts_with(b"HTTP/1.1 200"),
        "plain HTTP served on the TLS port"
    );
}

#[test]
fn a_stalled_tls_handshake_is_closed_at_the_header_timeout() {
    let f = fixtures();
    let dir = tempfile::tempdir().unwrap();
    let (_, c, k) = write_pems(dir.path());
    let srv = Server::start(
        &[&f.synth],
        &[
            "--tls-cert",
            c.to_str().unwrap(),
            "--tls-key",
            k.to_str().unwrap(),
            "--header-timeout-secs",
            "1",
        ],
    );
    // The first byte of a TLS record (handshake), then nothing.
    let mut s = TcpStream::connect(srv.addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    s.write_all(&[0x16, 0x03, 0x01]).unwrap();
    let started = Instant::now();
    let mut buf = [0u8; 64];
    let closed = loop {
        match s.read(&mut buf) {
            Ok(0) => break true,
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => break true,
            Err(_) => break false,
        }
    };
    let took = started.elapsed();
    assert!(closed, "the stalled handshake was never closed");
    assert!(
        took >= Duration::from_millis(800) && took < Duration::from_secs(5),
        "closed after {took:?}, want ~1 s"
    );
}

#[test]
fn bad_tls_files_stop_the_server_with_an_error_naming_the_file() {
    let f = fixtures();
    let dir = tempfile::tempdir().unwrap();
    let (_, c, k) = write_pems(dir.path());
    let synth = f.synth.to_str().unwrap();
    let (c, k) = (c.to_str().unwrap(), k.to_str().unwrap());
    let missing = dir.path().join("nope.pem");
    let missing = missing.to_str().unwrap();
    let garbage = dir.path().join("garbage.pem");
    std::fs::write(&garbage, "not a PEM file\n").unwrap();
    let garbage = garbage.to_str().unwrap();
    let (_, other_key) = self_signed();
    let other = dir.path().join("other-key.pem");
    std::fs::write(&other, other_key).unwrap();
    let other = other.to_str().unwrap();
    for (cert, key, flag, file) in [
        (c, missing, "--tls-key", missing),
        (missing, k, "--tls-cert", missing),
        (c, garbage, "--tls-key", garbage),
        (garbage, k, "--tls-cert", garbage),
        // The certificate as the key: a PEM file, but no key in it.
        (c, c, "--tls-key", c),
        // A key, but not the certificate's.
        (c, other, "--tls-key", other),
    ] {
        let err = serve_must_refuse(&[synth, "--tls-cert", cert, "--tls-key", key]);
        assert!(err.contains(flag), "{flag} {file}: {err}");
        assert!(err.contains(file), "{flag} {file}: {err}");
    }
    let err = serve_must_refuse(&[synth, "--tls-cert", c]);
    assert!(err.contains("--tls-key"), "{err}");
}
