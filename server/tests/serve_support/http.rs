//! HTTP responses: [`Resp`] (through reqwest, see [`super::Server::get`]) and raw
//! HTTP/1.1 over TCP for what a client library would normalise or hide.

use reqwest::header::HeaderMap;
use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

/// One request of every kind of cacheable response, on dataset `synth`.
pub const CACHEABLE: [&str; 6] = [
    "/v1/datasets/synth",
    "/v1/datasets/synth/tilejson.json",
    "/v1/datasets/synth/levels/2/tiles?ranges=0-15",
    "/v1/datasets/synth/tiles/2/1/1",
    "/v1/datasets/synth/2/1/1.png",
    "/v1/datasets/synth/pyramid",
];

/// A gzip body, decompressed.
pub fn gunzip(b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    flate2::read::GzDecoder::new(b)
        .read_to_end(&mut out)
        .unwrap();
    out
}

#[derive(Debug)]
pub struct Resp {
    pub path: String,
    pub status: u16,
    pub headers: HeaderMap,
    pub body: Vec<u8>,
}

impl Resp {
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers.get(name).map(|v| v.to_str().unwrap())
    }

    /// A header that must be present.
    pub fn must(&self, name: &str) -> &str {
        self.header(name)
            .unwrap_or_else(|| panic!("{}: no {name} header in {:?}", self.path, self.headers))
    }

    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).to_string()
    }

    pub fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("{}: body is not JSON ({e}): {}", self.path, self.text()))
    }

    /// Asserts the status and returns the response.
    pub fn expect(self, status: u16) -> Self {
        assert_eq!(
            self.status,
            status,
            "GET {}: body {}",
            self.path,
            &self.text().chars().take(500).collect::<String>()
        );
        self
    }

    /// Asserts an error response: `status`, a JSON content type, and a body
    /// `{"error": "<message>"}`; returns the message.
    pub fn error(&self, status: u16) -> String {
        assert_eq!(
            self.status,
            status,
            "GET {}: body {}",
            self.path,
            self.text()
        );
        self.json_error()
    }

    /// Asserts a JSON error body (whatever the status) and returns its message.
    pub fn json_error(&self) -> String {
        let ct = self.header("content-type").unwrap_or("");
        assert!(
            ct.starts_with("application/json"),
            "GET {}: error content type {ct:?}",
            self.path
        );
        let j = self.json();
        let msg = j["error"]
            .as_str()
            .unwrap_or_else(|| panic!("GET {}: no \"error\" string in {j}", self.path))
            .to_string();
        assert!(!msg.is_empty(), "GET {}: empty error message", self.path);
        msg
    }
}

// ---------------------------------------------------------------------------
// Raw HTTP/1.1 over TCP

/// A raw response: status, head (lower-cased header names), body.
#[derive(Debug)]
pub struct RawResp {
    pub status: u16,
    pub headers: BTreeMap<String, String>,
    pub body: Vec<u8>,
}

/// Position of `needle` in `hay`.
pub fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// Parses a response head (`HTTP/1.1 200 OK\r\nName: value\r\n…`); a field
/// sent twice is one, its values joined.
pub fn parse_head(head: &str) -> (u16, BTreeMap<String, String>) {
    let mut lines = head.split("\r\n");
    let status_line = lines.next().unwrap();
    let status = status_line
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("bad status line {status_line:?}"));
    // A repeated field is one list, its values joined with ", " (RFC 9110 §5.3).
    let mut headers = BTreeMap::<String, String>::new();
    for (k, v) in lines.filter_map(|l| l.split_once(':')) {
        headers
            .entry(k.trim().to_ascii_lowercase())
            .and_modify(|all| {
                all.push_str(", ");
                all.push_str(v.trim());
            })
            .or_insert_with(|| v.trim().to_string());
    }
    (status, headers)
}

/// Sends `GET target` exactly as written (no normalisation) with `Connection: close`
/// and reads the whole response.
pub fn raw_get(addr: SocketAddr, target: &str) -> RawResp {
    raw_request(addr, target, &format!("Host: {addr}\r\n"))
}

/// Sends `GET target` with exactly the header lines `headers` (each ending in CRLF,
/// `Host` included or not) plus `Connection: close`, and reads the whole response.
pub fn raw_request(addr: SocketAddr, target: &str, headers: &str) -> RawResp {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    write!(
        s,
        "GET {target} HTTP/1.1\r\n{headers}Connection: close\r\n\r\n"
    )
    .unwrap();
    let mut all = Vec::new();
    s.read_to_end(&mut all).unwrap();
    let end = find(&all, b"\r\n\r\n").expect("a response head");
    let (status, headers) = parse_head(std::str::from_utf8(&all[..end]).unwrap());
    let body = all[end + 4..].to_vec();
    if let Some(len) = headers.get("content-length") {
        assert_eq!(body.len(), len.parse::<usize>().unwrap(), "GET {target}");
    }
    RawResp {
        status,
        headers,
        body,
    }
}
