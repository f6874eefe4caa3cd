//! Verifying a frame stream as it arrives, without keeping its records (API.md "Frame
//! stream"): what a load generator needs of an answer (`tessera load --replay`;
//! DECISIONS.md "Load testing: replay"), which must check every frame but has no use for
//! the bytes.
//!
//! [`FrameScanner`] refuses exactly the streams [`FrameDecoder`] refuses, with the
//! same [`WireError`]s, at the same points: it reads the same headers
//! ([`crate::wire`]'s header parser) and decodes small frames (error messages,
//! trailers, frames of unknown kind) through the decoder's own code. Only the payload
//! of a tile or error-table frame is treated otherwise: hashed as it streams past
//! (XXH3, as [`crate::format::checksum`]) and compared with the header's checksum at
//! its end, so that it is never copied (the decoder copies every byte twice: into
//! its buffer, then out as the record).
//!
//! ```
//! use tessera_shared::frame_scan::{FrameScanner, Scanned};
//! use tessera_shared::wire::{tile_header, trailer_frame};
//! use tessera_shared::{Level, Morton, format};
//!
//! let level = Level::new(2).unwrap();
//! let record = b"a stored tile record";
//! let mut stream = tile_header(level, Morton::from_raw(5), format::checksum(record), 0, 9, 20).to_vec();
//! stream.extend_from_slice(record);
//! stream.extend(trailer_frame(level, 1, 0, &[]));
//!
//! let mut scanner = FrameScanner::new();
//! let mut tiles = Vec::new();
//! for chunk in stream.chunks(7) {
//!     scanner.push(chunk, |f| if let Scanned::Tile { morton, .. } = f { tiles.push(morton.get()) })?;
//! }
//! scanner.finish()?;
//! assert_eq!(tiles, [5]);
//! # Ok::<(), tessera_shared::wire::WireError>(())
//! ```
//!
//! [`FrameDecoder`]: crate::wire::FrameDecoder

use crate::wire::{FRAME_HEADER_LEN, Frame, Header, KIND_ERROR_TABLE, KIND_TILE, WireError};
use crate::{Level, Morton};
use xxhash_rust::xxh3::Xxh3;

/// A verified frame, as the scanner reports it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Scanned {
    /// A tile frame whose record matched its checksum (the record itself is gone).
    Tile {
        level: Level,
        morton: Morton,
        checksum: u64,
        /// The record's length in bytes.
        len: usize,
    },
    /// An error-table frame whose table matched its checksum.
    ErrorTable { level: Level, morton: Morton },
    /// An error frame or the trailer, as [`FrameDecoder`](crate::wire::FrameDecoder)
    /// decodes them.
    Frame(Frame),
}

/// What the scanner is in the middle of.
#[derive(Default)]
enum State {
    /// Reading a header: `have` of its bytes so far.
    #[default]
    Header,
    /// Hashing a tile's or error table's payload: `left` bytes still to come.
    Hashing {
        header: Header,
        hasher: Box<Xxh3>,
        left: usize,
    },
    /// Collecting another frame's payload, decoded whole at its end.
    Keeping {
        header: Header,
        payload: Vec<u8>,
        left: usize,
    },
}

/// Incremental verifier: [`push`](Self::push) bytes as they arrive, then
/// [`finish`](Self::finish).
#[derive(Default)]
pub struct FrameScanner {
    header: [u8; FRAME_HEADER_LEN],
    have: usize,
    state: State,
    frames: usize,
    done: bool,
}

impl std::fmt::Debug for FrameScanner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FrameScanner")
            .field("frames", &self.frames)
            .field("done", &self.done)
            .finish_non_exhaustive()
    }
}

impl FrameScanner {
    pub fn new() -> Self {
        Self::default()
    }

    /// Whether the trailer has been read.
    pub fn is_done(&self) -> bool {
        self.done
    }

    /// Scans received bytes, calling `out` with each frame they complete; the first
    /// bad frame is the error (the stream is then refused as a whole).
    pub fn push(
        &mut self,
        mut bytes: &[u8],
        mut out: impl FnMut(Scanned),
    ) -> Result<(), WireError> {
        while !bytes.is_empty() {
            if self.done {
                return Err(WireError::AfterTrailer);
            }
            match &mut self.state {
                State::Header => {
                    let n = (FRAME_HEADER_LEN - self.have).min(bytes.len());
                    self.header[self.have..self.have + n].copy_from_slice(&bytes[..n]);
                    self.have += n;
                    bytes = &bytes[n..];
                    if self.have == FRAME_HEADER_LEN {
                        self.start_payload()?;
                        if let Some(s) = self.finish_payload_if_empty()? {
                            out(s);
                        }
                    }
                }
                State::Hashing { hasher, left, .. } => {
                    let n = (*left).min(bytes.len());
                    hasher.update(&bytes[..n]);
                    *left -= n;
                    bytes = &bytes[n..];
                    if *left == 0 {
                        out(self.end_frame()?);
                    }
                }
                State::Keeping { payload, left, .. } => {
                    let n = (*left).min(bytes.len());
                    payload.extend_from_slice(&bytes[..n]);
                    *left -= n;
                    bytes = &bytes[n..];
                    if *left == 0 {
                        out(self.end_frame()?);
                    }
                }
            }
        }
        Ok(())
    }

    /// A complete header: what to do with its payload.
    fn start_payload(&mut self) -> Result<(), WireError> {
        let header = Header::parse(self.frames, &self.header)?;
        self.have = 0;
        let left = header.len;
        let streamed = matches!(header.kind, KIND_TILE | KIND_ERROR_TABLE)
            && Level::new(header.level_raw).is_some();
        self.state = if streamed {
            State::Hashing {
                header,
                hasher: Box::default(),
                left,
            }
        } else {
            State::Keeping {
                header,
                payload: Vec::with_capacity(left),
                left,
            }
        };
        Ok(())
    }

    /// A frame whose payload is empty ends at its header.
    fn finish_payload_if_empty(&mut self) -> Result<Option<Scanned>, WireError> {
        let empty = match &self.state {
            State::Hashing { left, .. } | State::Keeping { left, .. } => *left == 0,
            State::Header => false,
        };
        if empty {
            self.end_frame().map(Some)
        } else {
            Ok(None)
        }
    }

    /// The current frame's payload is complete: check it.
    fn end_frame(&mut self) -> Result<Scanned, WireError> {
        let index = self.frames;
        self.frames += 1;
        match std::mem::take(&mut self.state) {
            State::Hashing { header, hasher, .. } => {
                let (level, morton) = (
                    Level::new(header.level_raw).expect("checked when the header was read"),
                    Morton::from_raw(header.a),
                );
                if hasher.digest() != header.b {
                    return Err(WireError::Checksum {
                        index,
                        level: header.level_raw,
                        morton: header.a,
                    });
                }
                Ok(if header.kind == KIND_TILE {
                    Scanned::Tile {
                        level,
                        morton,
                        checksum: header.b,
                        len: header.len,
                    }
                } else {
                    Scanned::ErrorTable { level, morton }
                })
            }
            State::Keeping {
                header, payload, ..
            } => {
                let frame = header.frame(index, payload)?;
                if matches!(frame, Frame::Trailer { .. }) {
                    self.done = true;
                }
                Ok(Scanned::Frame(frame))
            }
            State::Header => unreachable!("a payload was being read"),
        }
    }

    /// Checks that the stream ended cleanly: a trailer, and nothing left over.
    pub fn finish(&self) -> Result<(), WireError> {
        let pending = match &self.state {
            State::Header => self.have,
            State::Hashing { header, left, .. } | State::Keeping { header, left, .. } => {
                FRAME_HEADER_LEN + header.len - left
            }
        };
        if pending > 0 {
            return Err(WireError::Truncated(format!(
                "{pending} bytes of an incomplete frame"
            )));
        }
        if !self.done {
            return Err(WireError::Truncated("no trailer frame".into()));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::MortonRange;
    use crate::format;
    use crate::wire::{FrameDecoder, error_frame, error_table_frame, tile_header, trailer_frame};
    use proptest::prelude::*;

    /// What the decoder makes of `stream` cut into `chunk`-byte pieces, as the
    /// scanner reports it: the frames, or the first error.
    fn decoded(stream: &[u8], chunk: usize) -> Result<Vec<Scanned>, WireError> {
        let mut d = FrameDecoder::new();
        let mut out = Vec::new();
        for c in stream.chunks(chunk.max(1)) {
            d.push(c);
            while let Some(f) = d.next_frame()? {
                out.push(match f {
                    Frame::Tile {
                        level,
                        morton,
                        checksum,
                        record,
                        ..
                    } => Scanned::Tile {
                        level,
                        morton,
                        checksum,
                        len: record.len(),
                    },
                    Frame::ErrorTable { level, morton, .. } => {
                        Scanned::ErrorTable { level, morton }
                    }
                    f => Scanned::Frame(f),
                });
            }
        }
        d.finish()?;
        Ok(out)
    }

    fn scanned(stream: &[u8], chunk: usize) -> Result<Vec<Scanned>, WireError> {
        let mut s = FrameScanner::new();
        let mut out = Vec::new();
        for c in stream.chunks(chunk.max(1)) {
            s.push(c, |f| out.push(f))?;
        }
        s.finish()?;
        Ok(out)
    }

    fn stream() -> Vec<u8> {
        let level = Level::new(3).unwrap();
        let mut s = Vec::new();
        for (m, record) in [
            (9u64, &b"first tile record"[..]),
            (12, b""),
            (13, &[7u8; 300][..]),
        ] {
            s.extend(tile_header(
                level,
                Morton::from_raw(m),
                format::checksum(record),
                1,
                2,
                record.len() as u32,
            ));
            s.extend_from_slice(record);
        }
        s.extend(error_frame(
            level,
            Morton::from_raw(10),
            77,
            "corrupt on disk",
        ));
        s.extend(error_table_frame(
            level,
            Morton::from_raw(11),
            3,
            4,
            b"table",
        ));
        let outside = [MortonRange::new(Morton::from_raw(40), Morton::from_raw(63)).unwrap()];
        s.extend(trailer_frame(level, 3, 1, &outside));
        s
    }

    #[test]
    fn a_good_stream_scans_as_it_decodes_in_any_chunking() {
        let s = stream();
        let want = decoded(&s, s.len()).unwrap();
        assert_eq!(want.len(), 6);
        for chunk in [1, 5, 31, 32, 33, 100, s.len()] {
            assert_eq!(scanned(&s, chunk).unwrap(), want, "chunks of {chunk}");
        }
    }

    #[test]
    fn damage_is_refused_as_the_decoder_refuses_it() {
        let s = stream();
        // A flipped byte in the first record, in a header's kind, level and length,
        // a cut, and bytes after the trailer.
        let mut cases: Vec<Vec<u8>> = Vec::new();
        for (at, xor) in [(40, 0x5a), (4, 0x40), (5, 0xf0), (3, 0x80), (2, 0x01)] {
            let mut d = s.clone();
            d[at] ^= xor;
            cases.push(d);
        }
        cases.push(s[..s.len() - 3].to_vec());
        cases.push(s[..100].to_vec());
        let mut extra = s.clone();
        extra.push(0);
        cases.push(extra);
        for (i, d) in cases.iter().enumerate() {
            for chunk in [1, 13, d.len()] {
                let want = decoded(d, chunk);
                assert!(want.is_err(), "case {i} decodes");
                assert_eq!(scanned(d, chunk), want, "case {i}, chunks of {chunk}");
            }
        }
    }

    proptest! {
        /// Any bytes at all, in any chunking: the scanner and the decoder agree.
        #[test]
        fn any_bytes_scan_as_they_decode(
            mut bytes in proptest::collection::vec(any::<u8>(), 0..600),
            flip in 0usize..600,
            chunk in 1usize..64,
        ) {
            // Mostly valid streams with one byte changed, and noise.
            let s = stream();
            if bytes.len() % 2 == 0 {
                bytes = s.clone();
                let at = flip % bytes.len();
                bytes[at] ^= 0x24;
            }
            prop_assert_eq!(scanned(&bytes, chunk), decoded(&bytes, chunk));
        }
    }
}
