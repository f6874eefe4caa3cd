//! Checking one replayed answer against what was recorded
//! (DECISIONS.md "Load testing: replay"), as the body arrives, without decoding a tile:
//! frame streams go through the shared [`FrameScanner`] (which verifies every frame's
//! checksum as the bytes stream past, refusing exactly what the shared `FrameDecoder`
//! refuses, without copying a record) and a [`StreamDigest`]; other bodies through an
//! incremental XXH3 equal to [`body_digest`](super::trace::body_digest).

use super::trace::{Expect, StreamDigest};
use serde::{Deserialize, Serialize};
use tessera_shared::frame_scan::{FrameScanner, Scanned};
use tessera_shared::wire::{Frame, WireError};

/// What went wrong with a request, as the report's `errors` keys name it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorKind {
    /// A socket failure: no connection (refused, DNS, TLS), or the connection broke
    /// before an answer's head arrived (reset, closed). Never an HTTP status: an
    /// answer with one is `HttpStatus` (or as recorded).
    Connect,
    /// No complete answer within `--timeout` (or still in flight when the run ended).
    Timeout,
    /// The status differs from the recorded one (or, unrecorded, is not a 2xx).
    HttpStatus,
    /// A frame fails its checksum or is malformed, or the server sent an error frame.
    Corrupt,
    /// The stream ended before its trailer (or the connection broke mid-body).
    Truncated,
    /// Well formed, but not the recorded tiles (count or digest) or body.
    Mismatch,
    /// The HTTP client could not make the request at all (not a valid HTTP request),
    /// so nothing was sent: not the server's doing, and not a socket failure.
    Request,
}

impl ErrorKind {
    pub const ALL: [Self; 7] = [
        Self::Connect,
        Self::Timeout,
        Self::HttpStatus,
        Self::Corrupt,
        Self::Truncated,
        Self::Mismatch,
        Self::Request,
    ];

    /// Whether a request that failed this way was answered (had a status and
    /// perhaps a body, whatever was wrong with them): not for a socket failure, a
    /// timeout or a request never made.
    pub fn answered(self) -> bool {
        !matches!(self, Self::Connect | Self::Timeout | Self::Request)
    }

    /// The JSON key.
    pub fn name(self) -> &'static str {
        match self {
            Self::Connect => "connect",
            Self::Timeout => "timeout",
            Self::HttpStatus => "http_status",
            Self::Corrupt => "corrupt",
            Self::Truncated => "truncated",
            Self::Mismatch => "mismatch",
            Self::Request => "request",
        }
    }
}

impl std::fmt::Display for ErrorKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The checked answer: tile frames and body bytes received, and the first error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Outcome {
    pub tiles: u32,
    pub bytes: u64,
    pub error: Option<ErrorKind>,
}

/// Checks one answer, chunk by chunk: [`Check::new`] with the status, [`Check::push`]
/// each body chunk, then [`Check::finish`] (or [`Check::broken`] when the body
/// could not be read to its end).
#[derive(Debug)]
pub struct Check<'a> {
    expect: Option<&'a Expect>,
    body: Body,
    bytes: u64,
    error: Option<ErrorKind>,
}

enum Body {
    /// A frame stream being verified.
    Frames {
        scanner: FrameScanner,
        digest: StreamDigest,
    },
    /// Any other body, hashed as a whole.
    Other(Box<xxhash_rust::xxh3::Xxh3>),
    /// Not looked at (the status was wrong, or a recorded non-2xx answer).
    Ignored,
}

impl std::fmt::Debug for Body {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Frames { scanner, digest } => f
                .debug_struct("Frames")
                .field("scanner", scanner)
                .field("digest", digest)
                .finish(),
            // The hasher's state is not worth printing.
            Self::Other(_) => f.write_str("Other"),
            Self::Ignored => f.write_str("Ignored"),
        }
    }
}

impl<'a> Check<'a> {
    /// `frame_stream`: whether the request's answer is a frame stream
    /// ([`RequestKind::is_frame_stream`](super::trace::RequestKind::is_frame_stream)).
    pub fn new(expect: Option<&'a Expect>, frame_stream: bool, status: u16) -> Self {
        let status_ok = match expect {
            Some(e) => e.status == status,
            None => (200..300).contains(&status),
        };
        let body = if !status_ok || !(200..300).contains(&status) {
            // A recorded error status that came back again is as recorded; its body
            // (a JSON message) is not compared.
            Body::Ignored
        } else if frame_stream {
            Body::Frames {
                scanner: FrameScanner::new(),
                digest: StreamDigest::new(),
            }
        } else {
            Body::Other(Box::default())
        };
        Self {
            expect,
            body,
            bytes: 0,
            error: (!status_ok).then_some(ErrorKind::HttpStatus),
        }
    }

    /// Whether the body still matters (else the caller may stop reading it).
    pub fn wants_body(&self) -> bool {
        self.error.is_none() && !matches!(self.body, Body::Ignored)
    }

    /// A chunk of the body.
    pub fn push(&mut self, chunk: &[u8]) {
        self.bytes += chunk.len() as u64;
        if self.error.is_some() {
            return;
        }
        match &mut self.body {
            Body::Frames { scanner, digest } => {
                let mut server_error = false;
                let scanned = scanner.push(chunk, |f| match f {
                    Scanned::Tile {
                        level,
                        morton,
                        checksum,
                        ..
                    } => digest.push_tile(level, morton, checksum),
                    Scanned::Frame(Frame::Error { .. }) => server_error = true,
                    Scanned::ErrorTable { .. } | Scanned::Frame(_) => {}
                });
                if let Err(e) = scanned {
                    self.error = Some(classify(&e));
                } else if server_error {
                    self.error = Some(ErrorKind::Corrupt);
                }
            }
            Body::Other(h) => h.update(chunk),
            Body::Ignored => {}
        }
    }

    /// The body could not be read to its end (`kind`: what broke it — a timeout, or
    /// the connection, which counts as a truncated answer).
    pub fn broken(self, kind: ErrorKind) -> Outcome {
        Outcome {
            tiles: self.tiles(),
            bytes: self.bytes,
            error: self.error.or(Some(kind)),
        }
    }

    fn tiles(&self) -> u32 {
        match &self.body {
            Body::Frames { digest, .. } => digest.tiles(),
            _ => 0,
        }
    }

    /// The body ended: a frame stream must have ended with its trailer; then the
    /// tiles and digest are compared with the recording.
    pub fn finish(mut self) -> Outcome {
        if self.error.is_none() {
            self.error = match (&self.body, self.expect) {
                // Bytes left over after the trailer are not a cut stream but a bad one.
                (Body::Frames { scanner, .. }, _) if scanner.finish().is_err() => {
                    Some(if scanner.is_done() {
                        ErrorKind::Corrupt
                    } else {
                        ErrorKind::Truncated
                    })
                }
                (Body::Frames { digest, .. }, Some(e)) => (digest.tiles() != e.tiles
                    || digest.hex() != e.digest)
                    .then_some(ErrorKind::Mismatch),
                (Body::Other(h), Some(e)) => {
                    (format!("{:016x}", h.digest()) != e.digest).then_some(ErrorKind::Mismatch)
                }
                _ => None,
            };
        }
        Outcome {
            tiles: self.tiles(),
            bytes: self.bytes,
            error: self.error,
        }
    }
}

/// A decoder error's kind: a stream cut short is truncated; anything else the
/// decoder refuses (checksum, unknown kind or level, malformed frame, bytes after
/// the trailer) is corrupt.
pub fn classify(e: &WireError) -> ErrorKind {
    match e {
        WireError::Truncated(_) => ErrorKind::Truncated,
        _ => ErrorKind::Corrupt,
    }
}

/// The checks a whole body held in memory gets (tests, and callers with a body).
pub fn check_body(
    expect: Option<&Expect>,
    frame_stream: bool,
    status: u16,
    body: &[u8],
) -> Outcome {
    let mut c = Check::new(expect, frame_stream, status);
    c.push(body);
    c.finish()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::loadtest::trace::body_digest;
    use tessera_shared::wire::{decode_all, error_frame, tile_header, trailer_frame};
    use tessera_shared::{Level, Morton};

    fn tile(level: u8, morton: u64, record: &[u8]) -> Vec<u8> {
        let mut v = tile_header(
            Level::new(level).unwrap(),
            Morton::from_raw(morton),
            tessera_shared::format::checksum(record),
            1,
            2,
            record.len() as u32,
        )
        .to_vec();
        v.extend_from_slice(record);
        v
    }

    fn stream(tiles: &[(u64, &[u8])]) -> Vec<u8> {
        let mut s = Vec::new();
        for (m, r) in tiles {
            s.extend(tile(4, *m, r));
        }
        s.extend(trailer_frame(
            Level::new(4).unwrap(),
            tiles.len() as u64,
            0,
            &[],
        ));
        s
    }

    fn expect_of(body: &[u8]) -> Expect {
        let mut d = StreamDigest::new();
        for f in decode_all(body).unwrap() {
            d.push(&f);
        }
        Expect {
            status: 200,
            tiles: d.tiles(),
            bytes: body.len() as u64,
            digest: d.hex(),
        }
    }

    const A: &[u8] = b"the first tile's record bytes";
    const B: &[u8] = b"the second tile's record, a little longer";

    #[test]
    fn the_recorded_stream_passes_in_any_chunking() {
        let body = stream(&[(1, A), (2, B)]);
        let e = expect_of(&body);
        let whole = check_body(Some(&e), true, 200, &body);
        assert_eq!(
            whole,
            Outcome {
                tiles: 2,
                bytes: body.len() as u64,
                error: None
            }
        );
        for n in [1, 7, 32, 33, 100] {
            let mut c = Check::new(Some(&e), true, 200);
            for chunk in body.chunks(n) {
                c.push(chunk);
            }
            assert_eq!(c.finish(), whole, "chunks of {n}");
        }
    }

    #[test]
    fn a_flipped_byte_is_corrupt() {
        let body = stream(&[(1, A), (2, B)]);
        let e = expect_of(&body);
        // In the second tile's record.
        let mut bad = body.clone();
        let at = 2 * 32 + A.len() + 5;
        bad[at] ^= 0x10;
        assert_eq!(
            check_body(Some(&e), true, 200, &bad).error,
            Some(ErrorKind::Corrupt)
        );
        // In a frame header's kind byte.
        let mut bad = body.clone();
        bad[4] = 9;
        assert_eq!(
            check_body(Some(&e), true, 200, &bad).error,
            Some(ErrorKind::Corrupt)
        );
    }

    #[test]
    fn bytes_after_the_trailer_and_oversized_frames_are_corrupt() {
        let body = stream(&[(1, A)]);
        let e = expect_of(&body);
        for extra in [
            &b"x"[..],
            &[0u8; 31][..],
            &[0u8; 32][..],
            &tile(4, 9, B)[..],
        ] {
            let mut bad = body.clone();
            bad.extend_from_slice(extra);
            let out = check_body(Some(&e), true, 200, &bad);
            assert_eq!(
                out.error,
                Some(ErrorKind::Corrupt),
                "{} bytes after",
                extra.len()
            );
        }
        // A header announcing more than the decoder accepts is refused at once, not
        // waited for.
        let mut huge = tile_header(
            Level::new(4).unwrap(),
            Morton::from_raw(1),
            0,
            0,
            0,
            u32::MAX,
        )
        .to_vec();
        huge.extend_from_slice(b"a little");
        let mut c = Check::new(None, true, 200);
        c.push(&huge);
        assert!(!c.wants_body());
        assert_eq!(c.finish().error, Some(ErrorKind::Corrupt));
    }

    #[test]
    fn an_error_frame_is_corrupt() {
        let mut body = tile(4, 1, A);
        body.extend(error_frame(
            Level::new(4).unwrap(),
            Morton::from_raw(2),
            7,
            "record fails its checksum",
        ));
        body.extend(trailer_frame(Level::new(4).unwrap(), 1, 1, &[]));
        assert_eq!(
            check_body(None, true, 200, &body).error,
            Some(ErrorKind::Corrupt)
        );
    }

    #[test]
    fn a_cut_body_is_truncated() {
        let body = stream(&[(1, A), (2, B)]);
        let e = expect_of(&body);
        for cut in [10, 32, 40, body.len() - 32, body.len() - 1] {
            let out = check_body(Some(&e), true, 200, &body[..cut]);
            assert_eq!(out.error, Some(ErrorKind::Truncated), "cut at {cut}");
            assert_eq!(out.bytes, cut as u64);
        }
        // A connection broken mid-body: truncated, unless already corrupt.
        let mut c = Check::new(Some(&e), true, 200);
        c.push(&body[..40]);
        assert_eq!(
            c.broken(ErrorKind::Truncated).error,
            Some(ErrorKind::Truncated)
        );
    }

    #[test]
    fn other_tiles_are_a_mismatch() {
        let body = stream(&[(1, A), (2, B)]);
        let e = expect_of(&body);
        for other in [
            stream(&[(1, A), (3, B)]),
            stream(&[(1, A)]),
            stream(&[(2, B), (1, A)]),
            stream(&[(1, A), (2, A)]),
        ] {
            assert_eq!(
                check_body(Some(&e), true, 200, &other).error,
                Some(ErrorKind::Mismatch)
            );
            // Without a recording, a well-formed stream is fine.
            assert_eq!(check_body(None, true, 200, &other).error, None);
        }
    }

    #[test]
    fn statuses_are_compared_with_the_recording() {
        let body = stream(&[(1, A)]);
        let e = expect_of(&body);
        let out = check_body(Some(&e), true, 503, b"{\"error\":\"busy\"}");
        assert_eq!(out.error, Some(ErrorKind::HttpStatus));
        assert_eq!(
            check_body(None, true, 404, b"").error,
            Some(ErrorKind::HttpStatus)
        );
        // A recorded 404 that comes back as a 404 is as recorded; its body is not read.
        let gone = Expect {
            status: 404,
            tiles: 0,
            bytes: 3,
            digest: "0".repeat(16),
        };
        let c = Check::new(Some(&gone), true, 404);
        assert!(!c.wants_body());
        assert_eq!(c.finish().error, None);
    }

    #[test]
    fn other_bodies_are_compared_by_digest() {
        let doc = br#"{"name":"moon","levels":6}"#;
        let e = Expect {
            status: 200,
            tiles: 0,
            bytes: doc.len() as u64,
            digest: body_digest(doc),
        };
        let mut c = Check::new(Some(&e), false, 200);
        c.push(&doc[..5]);
        c.push(&doc[5..]);
        assert_eq!(c.finish().error, None);
        assert_eq!(
            check_body(Some(&e), false, 200, br#"{"name":"moon","levels":7}"#).error,
            Some(ErrorKind::Mismatch)
        );
    }
}
