//! Damage in transit: tile frames with a flipped byte, tile streams cut short.

use std::collections::{HashMap, HashSet};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};

/// The media type of a Tessera tile stream (API.md, "Frame stream"); only responses
/// of this type are damaged. Equal to `tessera_shared::wire::CONTENT_TYPE` (a test
/// checks), written out so that this crate does not link the contract it tests.
pub const TILE_STREAM_CONTENT_TYPE: &str = "application/vnd.tessera.tiles";

/// The frame layout of API.md, "Frame stream": a 32-byte little-endian header (payload
/// length at 0, kind at 4, level at 5, Morton code at 8), then the payload.
const FRAME_HEADER_LEN: usize = 32;
/// The kind of a tile frame (its payload is the tile's stored record).
const KIND_TILE: u8 = 0;

/// What the proxy does to a tile frame it picks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Damage {
    /// Flip one byte (XOR `0x5a`) in the middle of the record: the frame fails its
    /// checksum.
    FlipByte,
    /// End the body in the middle of the record, with a Content-Length that says so:
    /// the HTTP response is complete and well formed, the tile stream is truncated.
    CutShort,
}

/// Whether a picked tile is damaged every time it passes or only the first time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Recurrence {
    /// Only the first time it passes (or is cut off): a transient fault, which a
    /// retry gets past.
    Once,
    /// Every time: a tile that always arrives damaged.
    Always,
}

/// A fault plan for the corrupting proxy, and what it did.
///
/// Tiles are named `(level, Morton code)` as the frame headers give them. Only
/// payload bytes change, or a body ends early; status lines, headers and HTTP framing
/// stay intact (damage there would test the HTTP library, not the client), and
/// error and trailer frames are never touched.
#[derive(Debug)]
pub struct Faults {
    damage: Damage,
    recurrence: Recurrence,
    /// Which tiles to damage.
    picks: fn(u8, u64) -> bool,
    /// Tiles that have passed through (or been cut off) at least once.
    seen: Mutex<HashSet<(u8, u64)>>,
    /// How many times each tile was the first damaged frame of a response.
    first_damaged: Mutex<HashMap<(u8, u64), u32>>,
}

impl Faults {
    /// Damages the tiles `picks(level, morton)` chooses, `damage`-wise, as often as
    /// `recurrence` says. Shared (`Arc`) so a test keeps reading what the proxy did.
    pub fn new(damage: Damage, recurrence: Recurrence, picks: fn(u8, u64) -> bool) -> Arc<Self> {
        Arc::new(Self {
            damage,
            recurrence,
            picks,
            seen: Mutex::new(HashSet::new()),
            first_damaged: Mutex::new(HashMap::new()),
        })
    }

    /// How many times each tile `(level, Morton code)` was the first damaged frame of a
    /// response: the one a client meets, rejects and must blame, since the stream is
    /// broken after it. A client that backs off a failing tile meets it here rarely.
    pub fn first_damaged(&self) -> HashMap<(u8, u64), u32> {
        lock(&self.first_damaged).clone()
    }

    /// Damages the tile frames it picks inside a tile-stream body.
    ///
    /// # Panics
    ///
    /// If the body is not a sequence of whole frames (the server sends nothing else
    /// with a Content-Length), so that a change of the wire format fails the tests
    /// that use this proxy instead of passing undamaged.
    fn apply(&self, body: &mut Vec<u8>) {
        let mut frames = Vec::new();
        let mut at = 0;
        while at + FRAME_HEADER_LEN <= body.len() {
            let h = &body[at..at + FRAME_HEADER_LEN];
            let len = u32::from_le_bytes([h[0], h[1], h[2], h[3]]) as usize;
            let mut morton = [0u8; 8];
            morton.copy_from_slice(&h[8..16]);
            frames.push((at, len, h[4], h[5], u64::from_le_bytes(morton)));
            at += FRAME_HEADER_LEN + len;
        }
        assert_eq!(at, body.len(), "the server sent a body of whole frames");
        let mut seen = lock(&self.seen);
        let mut first_damaged = lock(&self.first_damaged);
        let mut any = false;
        for (i, &(at, len, kind, level, morton)) in frames.iter().enumerate() {
            if kind != KIND_TILE {
                continue;
            }
            let first = seen.insert((level, morton));
            let pick =
                (self.picks)(level, morton) && (first || self.recurrence == Recurrence::Always);
            if !pick {
                continue;
            }
            if !any {
                *first_damaged.entry((level, morton)).or_default() += 1;
                any = true;
            }
            let middle = at + FRAME_HEADER_LEN + len / 2;
            match self.damage {
                Damage::FlipByte => body[middle] ^= 0x5a,
                Damage::CutShort => {
                    // The tiles cut off count as sent: a transient fault spares the retry.
                    for &(_, _, kind, level, morton) in &frames[i + 1..] {
                        if kind == KIND_TILE {
                            seen.insert((level, morton));
                        }
                    }
                    body.truncate(middle);
                    return;
                }
            }
        }
    }
}

/// The fault plan's records stay readable after a panic elsewhere.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Carries HTTP/1.1 responses from upstream to the client one at a time, damaging
/// tile streams as `faults` says. A body that was cut short goes out with a
/// Content-Length that matches it. A response whose body has no Content-Length
/// (chunked, or to the end of the connection) cannot be delimited: it and everything
/// after it pass unchanged.
pub(crate) async fn relay_damaging(sr: OwnedReadHalf, mut cw: OwnedWriteHalf, faults: &Faults) {
    let mut r = tokio::io::BufReader::new(sr);
    loop {
        let mut head = Vec::new();
        while !head.ends_with(b"\r\n\r\n") {
            match r.read_until(b'\n', &mut head).await {
                Ok(0) | Err(_) => return,
                Ok(_) => {}
            }
        }
        let text = String::from_utf8_lossy(&head).into_owned();
        let header = |name: &str| {
            text.lines().find_map(|l| {
                let (k, v) = l.split_once(':')?;
                k.trim()
                    .eq_ignore_ascii_case(name)
                    .then(|| v.trim().to_string())
            })
        };
        let Some(len) = header("content-length").and_then(|v| v.parse::<usize>().ok()) else {
            // A body this proxy cannot delimit: pass everything on unchanged.
            let _ = cw.write_all(&head).await;
            let _ = tokio::io::copy(&mut r, &mut cw).await;
            return;
        };
        let mut body = vec![0u8; len];
        if r.read_exact(&mut body).await.is_err() {
            return;
        }
        if header("content-type").as_deref() == Some(TILE_STREAM_CONTENT_TYPE) {
            faults.apply(&mut body);
            if body.len() != len {
                head = text
                    .split("\r\n")
                    .map(|l| match l.split_once(':') {
                        Some((k, _)) if k.trim().eq_ignore_ascii_case("content-length") => {
                            format!("content-length: {}", body.len())
                        }
                        _ => l.to_string(),
                    })
                    .collect::<Vec<_>>()
                    .join("\r\n")
                    .into_bytes();
            }
        }
        if cw.write_all(&head).await.is_err() || cw.write_all(&body).await.is_err() {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::corrupting;
    use crate::testing::{get, http_upstream, pattern, read_response, response};
    use tessera_shared::format::checksum;
    use tessera_shared::wire::{self, Frame, WireError};
    use tessera_shared::{Level, Morton};
    use tokio::io::BufReader;
    use tokio::net::TcpStream;

    fn level() -> Level {
        Level::new(2).unwrap()
    }

    fn tile_frame(morton: u64, payload: &[u8]) -> Vec<u8> {
        let h = wire::tile_header(
            level(),
            Morton::from_raw(morton),
            checksum(payload),
            0,
            1,
            payload.len() as u32,
        );
        [&h[..], payload].concat()
    }

    /// A real tile stream, as the contract's encoder writes it: tile 1, an error frame
    /// for tile 2, tile 3, the trailer. Returns the body and where each tile's payload
    /// starts and how long it is.
    fn stream() -> (Vec<u8>, [(usize, usize); 2]) {
        let a = tile_frame(1, &pattern(101));
        let e = wire::error_frame(level(), Morton::from_raw(2), 7, "record 2 is corrupt");
        let b = tile_frame(3, &pattern(64));
        let t = wire::trailer_frame(level(), 2, 1, &[]);
        let spots = [(32, 101), (a.len() + e.len() + 32, 64)];
        let body = [a, e, b, t].concat();
        assert_eq!(wire::decode_all(&body).unwrap().len(), 4);
        (body, spots)
    }

    /// Sends `n` GETs through a corrupting proxy with `faults` in front of an upstream
    /// that answers each with `answer`, one after the other on one connection; returns
    /// each response as the client got it (head, body).
    async fn through(faults: &Arc<Faults>, answer: Vec<u8>, n: usize) -> Vec<(String, Vec<u8>)> {
        let upstream = http_upstream(vec![answer]).await;
        let proxy = corrupting(upstream.addr, faults.clone()).await.unwrap();
        let (r, mut w) = TcpStream::connect(proxy.addr()).await.unwrap().into_split();
        let mut r = BufReader::new(r);
        let mut out = Vec::new();
        for i in 0..n {
            w.write_all(&get(&format!("/tiles?{i}"))).await.unwrap();
            out.push(read_response(&mut r).await);
        }
        out
    }

    fn head_for(body_len: usize) -> String {
        let r = response(TILE_STREAM_CONTENT_TYPE, &vec![0; body_len]);
        String::from_utf8(r[..r.len() - body_len].to_vec()).unwrap()
    }

    #[test]
    fn the_frame_layout_is_the_contracts() {
        assert_eq!(TILE_STREAM_CONTENT_TYPE, wire::CONTENT_TYPE);
        assert_eq!(FRAME_HEADER_LEN, wire::FRAME_HEADER_LEN);
        let f = tile_frame(9, b"abc");
        assert_eq!((f[4], f[5], f[8]), (KIND_TILE, 2, 9));
    }

    /// Always flipping tile 3: every response has exactly one byte changed, the middle
    /// of tile 3's record, so the contract's decoder rejects it for its checksum; the
    /// head, tile 1, the error frame and the trailer are untouched.
    #[tokio::test]
    async fn flip_byte_changes_exactly_the_middle_of_each_picked_record() {
        let (body, [_, (at, len)]) = stream();
        let faults = Faults::new(Damage::FlipByte, Recurrence::Always, |l, m| {
            l == 2 && m == 3
        });
        let got = through(&faults, response(TILE_STREAM_CONTENT_TYPE, &body), 3).await;
        let mut expected = body.clone();
        expected[at + len / 2] ^= 0x5a;
        for (head, b) in &got {
            assert_eq!(*head, head_for(body.len()));
            assert!(*b == expected, "not exactly the one byte flipped");
            let err = wire::decode_all(b).unwrap_err();
            assert!(
                matches!(err, WireError::Checksum { morton: 3, .. }),
                "{err}"
            );
        }
        assert_eq!(faults.first_damaged(), HashMap::from([((2, 3), 3)]));
    }

    /// A transient fault over every tile: the first response has both tiles flipped
    /// (and names tile 1, the first, as the one the client meets), the retries pass
    /// unchanged.
    #[tokio::test]
    async fn a_transient_fault_damages_each_tile_only_the_first_time() {
        let (body, spots) = stream();
        let faults = Faults::new(Damage::FlipByte, Recurrence::Once, |_, _| true);
        let got = through(&faults, response(TILE_STREAM_CONTENT_TYPE, &body), 3).await;
        let mut expected = body.clone();
        for (at, len) in spots {
            expected[at + len / 2] ^= 0x5a;
        }
        assert!(
            got[0].1 == expected,
            "the first copy is not damaged as planned"
        );
        assert!(got[1].1 == body && got[2].1 == body, "a retry was damaged");
        assert_eq!(faults.first_damaged(), HashMap::from([((2, 1), 1)]));
    }

    /// Cutting at tile 1: the body ends in the middle of its record, with a
    /// Content-Length that says so and every other header as it was; tile 3, cut off
    /// with it, counts as sent, so the retry comes through whole.
    #[tokio::test]
    async fn cut_short_ends_the_body_mid_record_with_a_matching_content_length() {
        let (body, [(at, len), _]) = stream();
        let faults = Faults::new(Damage::CutShort, Recurrence::Once, |_, _| true);
        let got = through(&faults, response(TILE_STREAM_CONTENT_TYPE, &body), 2).await;
        let cut = at + len / 2;
        assert_eq!(got[0].0, head_for(cut));
        assert!(got[0].1 == body[..cut], "not cut in the middle of tile 1");
        let err = wire::decode_all(&got[0].1).unwrap_err();
        assert!(matches!(err, WireError::Truncated(_)), "{err}");
        assert_eq!(got[1].0, head_for(body.len()));
        assert!(got[1].1 == body, "the retry was damaged");
        let frames = wire::decode_all(&got[1].1).unwrap();
        assert!(matches!(frames[2], Frame::Tile { .. }));
        assert_eq!(faults.first_damaged(), HashMap::from([((2, 1), 1)]));
    }

    /// Responses of other types pass unchanged whatever the plan, and so does a
    /// tile stream without a Content-Length (chunked), with all that follows it.
    #[tokio::test]
    async fn other_responses_pass_unchanged() {
        let (body, _) = stream();
        let faults = Faults::new(Damage::FlipByte, Recurrence::Always, |_, _| true);
        let plain = response("application/octet-stream", &body);
        let got = through(&faults, plain.clone(), 2).await;
        for (head, b) in got {
            assert_eq!([head.as_bytes(), &b].concat(), plain);
        }

        let mut chunked = format!(
            "HTTP/1.1 200 OK\r\ncontent-type: {TILE_STREAM_CONTENT_TYPE}\r\ntransfer-encoding: chunked\r\n\r\n{:x}\r\n",
            body.len()
        )
        .into_bytes();
        chunked.extend_from_slice(&body);
        chunked.extend_from_slice(b"\r\n0\r\n\r\n");
        let upstream = http_upstream(vec![chunked.clone()]).await;
        let proxy = corrupting(upstream.addr, faults.clone()).await.unwrap();
        let mut c = TcpStream::connect(proxy.addr()).await.unwrap();
        c.write_all(&get("/chunked")).await.unwrap();
        let mut got = vec![0u8; chunked.len()];
        c.read_exact(&mut got).await.unwrap();
        assert!(got == chunked, "a chunked response was changed");
        assert!(faults.first_damaged().is_empty());
    }
}
