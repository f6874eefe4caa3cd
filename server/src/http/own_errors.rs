//! The HTTP layer's own answers made like ours: hyper answers a request head it
//! cannot parse itself, before any of our code runs (414 for a request target over
//! [`MAX_TARGET_BYTES`], 431 for a head over its read buffer, 400 for a malformed
//! one), with an empty body; `OwnErrors` puts the same status with a JSON reason
//! and the CORS headers ([`OwnCors`]) in its place. The connection cap's 503
//! (`http/conn.rs`) is written with the same `own_response`.

use crate::http::conventions::CorsOrigins;
use std::io;
use std::pin::Pin;
use std::task::{Context, Poll};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// The CORS headers of the answers the connection layer writes itself (the 503 of a
/// full server, `OwnErrors`), as `conventions::cors` would give them. Those answers
/// are written before (or without) a parsed request, so with a list of origins, which
/// needs the request's `Origin`, they say only `Vary: Origin`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OwnCors {
    Any,
    List,
    Disabled,
}

impl OwnCors {
    pub(super) fn of(origins: &CorsOrigins) -> Self {
        match origins {
            CorsOrigins::Any => Self::Any,
            CorsOrigins::List(_) => Self::List,
            CorsOrigins::Disabled => Self::Disabled,
        }
    }

    /// Header lines, each ending in CRLF.
    pub(super) fn header_lines(self) -> String {
        match self {
            Self::Any => format!(
                "access-control-allow-origin: *\r\naccess-control-expose-headers: {}\r\n",
                super::conventions::EXPOSE_HEADERS.join(",")
            ),
            Self::List => "vary: origin\r\n".to_string(),
            Self::Disabled => String::new(),
        }
    }
}

/// A whole `connection: close` response with a JSON reason, as the connection layer
/// writes it itself; `extra` are header lines ending in CRLF.
pub(super) fn own_response(status: &str, reason: &str, extra: &str) -> Vec<u8> {
    let body = serde_json::json!({ "error": reason }).to_string();
    format!(
        "HTTP/1.1 {status}\r\ncontent-type: application/json\r\ncontent-length: {}\r\n{extra}connection: close\r\n\r\n{body}",
        body.len()
    )
    .into_bytes()
}

/// The longest request target hyper (and the `http` crate's `Uri`) accepts.
pub const MAX_TARGET_BYTES: usize = 65_534;

/// If `head` is hyper's own answer to a request head it could not parse (a status
/// line of 400, 414 or 431 and an empty body, with no `Content-Type`: every answer
/// of ours has one), the status and reason of ours in its place.
fn own_error(head: &[u8]) -> Option<(&'static str, String)> {
    let end = head.windows(4).position(|w| w == b"\r\n\r\n")?;
    let head = std::str::from_utf8(&head[..end]).ok()?.to_ascii_lowercase();
    let status = head
        .strip_prefix("http/1.1 ")
        .or_else(|| head.strip_prefix("http/1.0 "))?
        .get(..3)?;
    if !head.contains("\r\ncontent-length: 0") || head.contains("\r\ncontent-type:") {
        return None;
    }
    Some(match status {
        "414" => (
            "414 URI Too Long",
            format!(
                "request target longer than {MAX_TARGET_BYTES} bytes, the HTTP layer's limit \
                 (query strings have their own, --max-query-bytes; API.md \"Errors\")"
            ),
        ),
        "431" => (
            "431 Request Header Fields Too Large",
            "request head larger than the HTTP layer's read buffer (about 400 KiB)".to_string(),
        ),
        "400" => (
            "400 Bad Request",
            "malformed HTTP request: the request line or a header does not parse".to_string(),
        ),
        _ => return None,
    })
}

/// The connection as hyper sees it (after TLS): every byte passes through, except
/// hyper's own answer to a request head it cannot parse ([`own_error`]), which is
/// replaced by the same status with a JSON reason and the CORS headers. hyper writes
/// that answer as one buffer and then closes the connection; it is told its bytes
/// were written once ours are, and anything it writes after is dropped.
pub(super) struct OwnErrors<I> {
    inner: I,
    cors: OwnCors,
    state: Rewrite,
}

enum Rewrite {
    /// Passing writes through.
    Watching,
    /// Writing our answer in place of hyper's `claimed` bytes.
    Sending {
        bytes: Vec<u8>,
        sent: usize,
        claimed: usize,
    },
    /// Our answer is out; the connection is closing.
    Done,
}

impl<I> OwnErrors<I> {
    /// `inner`, watched for hyper's own error answers.
    pub(super) fn new(inner: I, cors: OwnCors) -> Self {
        Self {
            inner,
            cors,
            state: Rewrite::Watching,
        }
    }
}

impl<I: AsyncWrite + Unpin> OwnErrors<I> {
    /// Starts replacing `head` (`claimed` bytes from hyper) if it is hyper's own error.
    fn watch(&mut self, head: &[u8], claimed: usize) {
        if let Some((status, reason)) = own_error(head) {
            tracing::info!(status, "answered a request head hyper could not parse");
            self.state = Rewrite::Sending {
                bytes: own_response(status, &reason, &self.cors.header_lines()),
                sent: 0,
                claimed,
            };
        }
    }

    /// Drives our answer out, then says hyper's `claimed` bytes were written; after
    /// it, says any `len` bytes were (they are dropped: the connection is closing).
    fn poll_replacement(&mut self, cx: &mut Context<'_>, len: usize) -> Poll<io::Result<usize>> {
        loop {
            match &mut self.state {
                // (Not called while watching.)
                Rewrite::Watching | Rewrite::Done => return Poll::Ready(Ok(len)),
                Rewrite::Sending {
                    bytes,
                    sent,
                    claimed,
                } => {
                    if *sent == bytes.len() {
                        let claimed = *claimed;
                        self.state = Rewrite::Done;
                        return Poll::Ready(Ok(claimed));
                    }
                    match Pin::new(&mut self.inner).poll_write(cx, &bytes[*sent..]) {
                        Poll::Ready(Ok(0)) => {
                            return Poll::Ready(Err(io::ErrorKind::WriteZero.into()));
                        }
                        Poll::Ready(Ok(n)) => *sent += n,
                        other => return other,
                    }
                }
            }
        }
    }
}

impl<I: AsyncRead + Unpin> AsyncRead for OwnErrors<I> {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_read(cx, buf)
    }
}

impl<I: AsyncWrite + Unpin> AsyncWrite for OwnErrors<I> {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        if matches!(this.state, Rewrite::Watching) {
            this.watch(buf, buf.len());
            if matches!(this.state, Rewrite::Watching) {
                return Pin::new(&mut this.inner).poll_write(cx, buf);
            }
        }
        this.poll_replacement(cx, buf.len())
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let len = bufs.iter().map(|b| b.len()).sum();
        if matches!(this.state, Rewrite::Watching) {
            if let Some(first) = bufs.iter().find(|b| !b.is_empty()) {
                this.watch(first, len);
            }
            if matches!(this.state, Rewrite::Watching) {
                return Pin::new(&mut this.inner).poll_write_vectored(cx, bufs);
            }
        }
        this.poll_replacement(cx, len)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::AsyncWriteExt;

    const HYPER_414: &[u8] =
        b"HTTP/1.1 414 URI Too Long\r\nconnection: close\r\ncontent-length: 0\r\ndate: Sun, 06 Dec 2026 17:38:04 GMT\r\n\r\n";

    async fn written(cors: OwnCors, writes: &[&[u8]]) -> String {
        let mut w = OwnErrors {
            inner: Vec::new(),
            cors,
            state: Rewrite::Watching,
        };
        for b in writes {
            w.write_all(b).await.unwrap();
        }
        String::from_utf8(w.inner).unwrap()
    }

    #[tokio::test]
    async fn hypers_bare_errors_become_json_with_cors() {
        let out = written(OwnCors::Any, &[HYPER_414, b"anything after"]).await;
        let (head, body) = out.split_once("\r\n\r\n").unwrap();
        assert!(head.starts_with("HTTP/1.1 414 URI Too Long\r\n"), "{out}");
        assert!(head.contains("content-type: application/json"), "{out}");
        assert!(head.contains("access-control-allow-origin: *"), "{out}");
        assert!(
            head.contains("access-control-expose-headers: etag,"),
            "{out}"
        );
        assert!(
            head.contains(&format!("content-length: {}", body.len())),
            "{out}"
        );
        let j: serde_json::Value = serde_json::from_str(body).unwrap();
        assert!(
            j["error"].as_str().unwrap().contains("65534 bytes"),
            "{body}"
        );
        let out = written(
            OwnCors::List,
            &[b"HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n\r\n"],
        )
        .await;
        assert!(
            out.contains("vary: origin\r\n") && out.contains("malformed HTTP request"),
            "{out}"
        );
        assert!(!out.contains("access-control-allow-origin"), "{out}");
    }

    #[tokio::test]
    async fn our_own_responses_pass_through_untouched() {
        let ours: [&[u8]; 3] = [
            b"HTTP/1.1 414 URI Too Long\r\ncontent-type: application/json\r\ncontent-length: 12\r\n\r\n{\"error\":\"\"}",
            b"HTTP/1.1 200 OK\r\ncontent-length: 0\r\n\r\n",
            b"\0\0\x12\x04\0\0\0\0\0",
        ];
        for bytes in ours {
            let out = written(OwnCors::Any, &[bytes, b"more"]).await;
            assert_eq!(out.as_bytes(), [bytes, b"more"].concat(), "{out}");
        }
    }
}
