//! The tile stream (`application/vnd.tessera.tiles`): what the range endpoint
//! sends and what clients decode (docs/ARCHITECTURE.md#contracts).
//!
//! A stream is a sequence of frames, the last of which is the one trailer frame;
//! every frame is a fixed 32-byte little-endian header and a payload. The byte
//! layout is specified once, in API.md ("Frame stream", under the Morton-range
//! tiles endpoint); this module is its implementation, and its tests pin the layout.

use crate::format;
use crate::morton::{Morton, MortonRange};
use crate::tile::Level;

/// The media type of a tile stream.
pub const CONTENT_TYPE: &str = "application/vnd.tessera.tiles";
pub const FRAME_HEADER_LEN: usize = 32;
/// Largest payload a decoder accepts (a 4096-cell tile is ~33 MiB raw).
pub const MAX_PAYLOAD: usize = 64 << 20;

pub(crate) const KIND_TILE: u8 = 0;
pub(crate) const KIND_ERROR: u8 = 1;
pub(crate) const KIND_TRAILER: u8 = 2;
pub(crate) const KIND_ERROR_TABLE: u8 = 3;

/// One decoded frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Frame {
    /// A tile's stored record, checksum already verified by the decoder.
    Tile {
        level: Level,
        morton: Morton,
        checksum: u64,
        min: u16,
        max: u16,
        record: Vec<u8>,
    },
    /// A tile's error table and min/max only (FORMAT.md "Tile record", first part).
    ErrorTable {
        level: Level,
        morton: Morton,
        min: u16,
        max: u16,
        table: Vec<u8>,
    },
    /// The server found this tile's record corrupt and did not send it.
    Error {
        level: Level,
        morton: Morton,
        message: String,
    },
    /// End of stream: counts and the requested sub-ranges that lie outside the DEM.
    Trailer {
        tiles: u64,
        errors: u64,
        outside: Vec<MortonRange>,
    },
}

/// The 32-byte header of a tile frame; the payload is the record itself, which the
/// server sends straight from storage.
pub fn tile_header(
    level: Level,
    morton: Morton,
    checksum: u64,
    min: u16,
    max: u16,
    len: u32,
) -> [u8; FRAME_HEADER_LEN] {
    header(
        len,
        KIND_TILE,
        level.get(),
        morton.get(),
        checksum,
        min,
        max,
    )
}

/// A complete error-table frame.
pub fn error_table_frame(
    level: Level,
    morton: Morton,
    min: u16,
    max: u16,
    table: &[u8],
) -> Vec<u8> {
    let mut v = header(
        table.len() as u32,
        KIND_ERROR_TABLE,
        level.get(),
        morton.get(),
        format::checksum(table),
        min,
        max,
    )
    .to_vec();
    v.extend_from_slice(table);
    v
}

/// A complete error frame.
pub fn error_frame(level: Level, morton: Morton, checksum: u64, message: &str) -> Vec<u8> {
    let mut v = header(
        message.len() as u32,
        KIND_ERROR,
        level.get(),
        morton.get(),
        checksum,
        0,
        0,
    )
    .to_vec();
    v.extend_from_slice(message.as_bytes());
    v
}

/// A complete trailer frame.
pub fn trailer_frame(level: Level, tiles: u64, errors: u64, outside: &[MortonRange]) -> Vec<u8> {
    let len = (outside.len() * 16) as u32;
    let mut v = header(len, KIND_TRAILER, level.get(), tiles, errors, 0, 0).to_vec();
    for r in outside {
        v.extend_from_slice(&r.start().get().to_le_bytes());
        v.extend_from_slice(&r.end().get().to_le_bytes());
    }
    v
}

fn header(
    len: u32,
    kind: u8,
    level: u8,
    a: u64,
    b: u64,
    min: u16,
    max: u16,
) -> [u8; FRAME_HEADER_LEN] {
    let mut h = [0u8; FRAME_HEADER_LEN];
    h[0..4].copy_from_slice(&len.to_le_bytes());
    h[4] = kind;
    h[5] = level;
    h[8..16].copy_from_slice(&a.to_le_bytes());
    h[16..24].copy_from_slice(&b.to_le_bytes());
    h[24..26].copy_from_slice(&min.to_le_bytes());
    h[26..28].copy_from_slice(&max.to_le_bytes());
    h
}

/// Why a stream was rejected.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    #[error("frame {index}: unknown frame kind {kind}")]
    Kind { index: usize, kind: u8 },
    #[error("frame {index}: payload of {len} bytes exceeds the {MAX_PAYLOAD}-byte limit")]
    TooLong { index: usize, len: usize },
    #[error("frame {index}: level {level} is not a valid level")]
    Level { index: usize, level: u8 },
    #[error("frame {index}: tile {morton} of level {level} fails its checksum")]
    Checksum {
        index: usize,
        level: u8,
        morton: u64,
    },
    #[error("frame {index}: malformed {what}")]
    Malformed { index: usize, what: &'static str },
    #[error("stream continues after its trailer")]
    AfterTrailer,
    #[error("stream is truncated: {0}")]
    Truncated(String),
}

/// The fields of a frame header (API.md "Frame stream"), its length checked against
/// [`MAX_PAYLOAD`]; shared by [`FrameDecoder`] and [`crate::frame_scan`], so that
/// both refuse exactly the same streams.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Header {
    pub(crate) len: usize,
    pub(crate) kind: u8,
    pub(crate) level_raw: u8,
    pub(crate) a: u64,
    pub(crate) b: u64,
    min: u16,
    max: u16,
}

impl Header {
    /// Parses the 32 header bytes of frame `index`.
    pub(crate) fn parse(index: usize, h: &[u8]) -> Result<Self, WireError> {
        let len = u32::from_le_bytes([h[0], h[1], h[2], h[3]]) as usize;
        if len > MAX_PAYLOAD {
            return Err(WireError::TooLong { index, len });
        }
        Ok(Self {
            len,
            kind: h[4],
            level_raw: h[5],
            a: u64_at(h, 8),
            b: u64_at(h, 16),
            min: u16::from_le_bytes([h[24], h[25]]),
            max: u16::from_le_bytes([h[26], h[27]]),
        })
    }

    /// The frame this header and its whole `payload` make, checked: the level, the
    /// kind, a tile's (or error table's) checksum, an error message's UTF-8, a
    /// trailer's ranges.
    pub(crate) fn frame(&self, index: usize, payload: Vec<u8>) -> Result<Frame, WireError> {
        let Self {
            kind,
            level_raw,
            a,
            b,
            min,
            max,
            ..
        } = *self;
        let level = Level::new(level_raw).ok_or(WireError::Level {
            index,
            level: level_raw,
        })?;
        let len = payload.len();
        Ok(match kind {
            KIND_TILE => {
                if format::checksum(&payload) != b {
                    return Err(WireError::Checksum {
                        index,
                        level: level_raw,
                        morton: a,
                    });
                }
                Frame::Tile {
                    level,
                    morton: Morton::from_raw(a),
                    checksum: b,
                    min,
                    max,
                    record: payload,
                }
            }
            KIND_ERROR_TABLE => {
                if format::checksum(&payload) != b {
                    return Err(WireError::Checksum {
                        index,
                        level: level_raw,
                        morton: a,
                    });
                }
                Frame::ErrorTable {
                    level,
                    morton: Morton::from_raw(a),
                    min,
                    max,
                    table: payload,
                }
            }
            KIND_ERROR => Frame::Error {
                level,
                morton: Morton::from_raw(a),
                message: String::from_utf8(payload).map_err(|_| WireError::Malformed {
                    index,
                    what: "error message",
                })?,
            },
            KIND_TRAILER => {
                if !len.is_multiple_of(16) {
                    return Err(WireError::Malformed {
                        index,
                        what: "trailer",
                    });
                }
                let outside = payload
                    .chunks_exact(16)
                    .map(|c| {
                        MortonRange::new(
                            Morton::from_raw(u64_at(c, 0)),
                            Morton::from_raw(u64_at(c, 8)),
                        )
                    })
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(|_| WireError::Malformed {
                        index,
                        what: "trailer range",
                    })?;
                Frame::Trailer {
                    tiles: a,
                    errors: b,
                    outside,
                }
            }
            kind => return Err(WireError::Kind { index, kind }),
        })
    }
}

/// Incremental decoder: feed bytes as they arrive, take frames as they complete.
#[derive(Debug, Default)]
pub struct FrameDecoder {
    buf: Vec<u8>,
    frames: usize,
    done: bool,
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}

impl FrameDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Whether the trailer has been decoded.
    pub fn is_done(&self) -> bool {
        self.done
    }

    /// The next complete frame, `Ok(None)` if more bytes are needed.
    pub fn next_frame(&mut self) -> Result<Option<Frame>, WireError> {
        if self.buf.len() < FRAME_HEADER_LEN {
            if self.done && !self.buf.is_empty() {
                return Err(WireError::AfterTrailer);
            }
            return Ok(None);
        }
        if self.done {
            return Err(WireError::AfterTrailer);
        }
        let index = self.frames;
        let header = Header::parse(index, &self.buf[..FRAME_HEADER_LEN])?;
        let len = header.len;
        if self.buf.len() < FRAME_HEADER_LEN + len {
            return Ok(None);
        }
        let payload: Vec<u8> = self.buf[FRAME_HEADER_LEN..FRAME_HEADER_LEN + len].to_vec();
        self.buf.drain(..FRAME_HEADER_LEN + len);
        self.frames += 1;
        let frame = header.frame(index, payload)?;
        if matches!(frame, Frame::Trailer { .. }) {
            self.done = true;
        }
        Ok(Some(frame))
    }

    /// Checks that the stream ended cleanly: a trailer, and nothing left over.
    pub fn finish(&self) -> Result<(), WireError> {
        if !self.buf.is_empty() {
            return Err(WireError::Truncated(format!(
                "{} bytes of an incomplete frame",
                self.buf.len()
            )));
        }
        if !self.done {
            return Err(WireError::Truncated("no trailer frame".into()));
        }
        Ok(())
    }
}

/// Decodes a whole stream held in memory.
pub fn decode_all(bytes: &[u8]) -> Result<Vec<Frame>, WireError> {
    let mut d = FrameDecoder::new();
    d.push(bytes);
    let mut out = Vec::new();
    while let Some(f) = d.next_frame()? {
        out.push(f);
    }
    d.finish()?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stream() -> (Vec<u8>, Vec<u8>) {
        let level = Level::new(3).unwrap();
        let record = b"pretend this is a tile record".to_vec();
        let mut s = tile_header(
            level,
            Morton::from_raw(9),
            format::checksum(&record),
            10,
            20,
            record.len() as u32,
        )
        .to_vec();
        s.extend_from_slice(&record);
        s.extend(error_frame(
            level,
            Morton::from_raw(10),
            77,
            "checksum mismatch",
        ));
        s.extend(error_table_frame(
            level,
            Morton::from_raw(11),
            3,
            4,
            b"table",
        ));
        let outside = [MortonRange::new(Morton::from_raw(40), Morton::from_raw(63)).unwrap()];
        s.extend(trailer_frame(level, 1, 1, &outside));
        (s, record)
    }

    #[test]
    fn frames_round_trip_in_any_chunking() {
        let (s, record) = stream();
        for chunk in [1, 7, 32, 1000] {
            let mut d = FrameDecoder::new();
            let mut frames = Vec::new();
            for c in s.chunks(chunk) {
                d.push(c);
                while let Some(f) = d.next_frame().unwrap() {
                    frames.push(f);
                }
            }
            d.finish().unwrap();
            assert_eq!(frames.len(), 4);
            assert!(
                matches!(&frames[0], Frame::Tile { morton, record: r, min: 10, max: 20, .. } if morton.get() == 9 && *r == record)
            );
            assert!(
                matches!(&frames[1], Frame::Error { message, .. } if message == "checksum mismatch")
            );
            assert!(
                matches!(&frames[2], Frame::ErrorTable { min: 3, max: 4, table, .. } if table == b"table")
            );
            assert!(
                matches!(&frames[3], Frame::Trailer { tiles: 1, errors: 1, outside } if outside[0].to_string() == "40-63")
            );
        }
    }

    #[test]
    fn damaged_streams_are_rejected() {
        let (s, _) = stream();
        // Truncated anywhere before the end.
        for cut in [5, 31, 40, s.len() - 1] {
            let err = decode_all(&s[..cut]).unwrap_err();
            assert!(matches!(err, WireError::Truncated(_)), "cut {cut}: {err}");
        }
        // A flipped payload byte fails the tile's checksum.
        let mut bad = s.clone();
        bad[FRAME_HEADER_LEN + 3] ^= 1;
        assert!(matches!(
            decode_all(&bad),
            Err(WireError::Checksum { morton: 9, .. })
        ));
        // Unknown kinds, absurd lengths and bytes after the trailer.
        let mut bad = s.clone();
        bad[4] = 9;
        assert!(matches!(
            decode_all(&bad),
            Err(WireError::Kind { kind: 9, .. })
        ));
        let mut bad = s.clone();
        bad[0..4].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(decode_all(&bad), Err(WireError::TooLong { .. })));
        let mut bad = s.clone();
        bad.extend_from_slice(&[0u8; 40]);
        assert!(matches!(decode_all(&bad), Err(WireError::AfterTrailer)));
    }
}
