//! Entry points of the coverage-guided fuzz targets for the parsers of this crate
//! (`fuzz/fuzz_targets/`), kept here so that the fuzz targets and the corpus replay
//! test (`server/tests/fuzz_corpus.rs`) run exactly the same code.
//!
//! Each entry takes arbitrary bytes, drives its parser to the end (every record,
//! every frame) and returns the parser's verdict. None of them allocates in
//! proportion to what the bytes claim: whatever they allocate, the parser allocated.
//! They must never panic; for the valid seeds of `fuzz/corpus/` they return `Ok`.

use crate::codec;
use crate::format::{self, FileHeader, HEADER_LEN};
use crate::morton::{Morton, MortonRange};
use crate::reader::{ByteSource, Pyramid, ReadError};
use crate::tile::TileId;
use crate::wire::{self, FRAME_HEADER_LEN, Frame, FrameDecoder, WireError};

/// Opens `data` as a pyramid file (a `Vec<u8>` [`ByteSource`]) and reads and decodes
/// every present record, plus a Morton byte range per level.
///
/// The header checksum (XXH3-64) is a wall no mutation gets through, so the bytes are
/// also tried with that checksum recomputed, which lets the fuzzer reach the metadata,
/// level table, index and record decoding. Records whose checksum fails are decoded
/// anyway (straight through the codec) for the same reason. The verdict returned is
/// that of the bytes as given.
pub fn pyramid(data: &[u8]) -> Result<usize, ReadError> {
    if let Some(fixed) = with_header_checksum(data)
        && fixed != data
    {
        let _ = read_pyramid(fixed);
    }
    read_pyramid(data.to_vec())
}

/// `data` with its header checksum recomputed, when the header parses and points
/// inside the data.
fn with_header_checksum(data: &[u8]) -> Option<Vec<u8>> {
    let header = FileHeader::parse(data).ok()?;
    let end = usize::try_from(header.records_offset).ok()?;
    let region = data.get(HEADER_LEN..end)?;
    let sum = header.compute_checksum(region);
    let mut fixed = data.to_vec();
    fixed[56..64].copy_from_slice(&sum.to_le_bytes());
    Some(fixed)
}

/// Tiles decoded, or the first error.
fn read_pyramid(data: Vec<u8>) -> Result<usize, ReadError> {
    let p = Pyramid::open(data)?;
    let tile_log2 = p.geometry().tile_log2();
    let size = p.source().len() as u64;
    let mut first_error = None;
    let mut decoded = 0;
    for level in p.geometry().levels() {
        let Some(index) = p.index(level) else {
            continue;
        };
        // A byte range across the whole level, and one of its first half.
        let slots = level.tile_slots();
        for end in [slots - 1, (slots - 1) / 2] {
            if let Ok(r) = MortonRange::new(Morton::from_raw(0), Morton::from_raw(end)) {
                let _ = p.byte_range(level, r);
            }
        }
        for (m, e) in index.iter().enumerate() {
            if !e.is_present() {
                continue;
            }
            let Some(tile) = TileId::from_morton(level, Morton::from_raw(m as u64)) else {
                continue;
            };
            let _ = p.read_error_table(tile);
            match p.read_tile(tile) {
                Ok(_) => decoded += 1,
                Err(err) => {
                    // Reach the codec even when the checksum stops the reader.
                    let inside = e
                        .offset
                        .checked_add(u64::from(e.length))
                        .is_some_and(|end| end <= size);
                    if inside && let Ok(bytes) = p.source().read_vec(e.offset, e.length as usize) {
                        let _ = codec::decode_error_table(&bytes, tile_log2);
                        let _ = codec::decode_record(&bytes, p.record_layout());
                    }
                    first_error.get_or_insert(err);
                }
            }
        }
    }
    first_error.map_or(Ok(decoded), Err)
}

/// Decodes `data` as a tile stream twice: whole ([`wire::decode_all`]) and
/// incrementally, fed in pieces whose size the first byte chooses (as a client
/// receives it), and verifies it with the streaming scanner, which must agree with
/// the decoder. The incremental pass also runs on a copy whose tile and error-table
/// checksums are recomputed, so that mutated payloads get past the checksum.
/// Returns the number of frames of the whole-stream decode.
pub fn wire(data: &[u8]) -> Result<usize, WireError> {
    let piece = data.first().map_or(1, |&b| usize::from(b) + 1);
    let incremental = decode_in_pieces(data, piece);
    scan_agrees(data, piece, &incremental);
    let fixed = with_frame_checksums(data);
    if fixed != data {
        let decoded = decode_in_pieces(&fixed, piece);
        scan_agrees(&fixed, piece, &decoded);
    }
    let whole = wire::decode_all(data);
    // Both ways of decoding must agree on every stream.
    match (&whole, &incremental) {
        (Ok(a), Ok(b)) => assert_eq!(a, b, "incremental and whole decoding differ"),
        (Ok(_), Err(e)) => panic!("whole decoding succeeded, incremental failed: {e}"),
        (Err(e), Ok(_)) => panic!("incremental decoding succeeded, whole failed: {e}"),
        (Err(_), Err(_)) => {}
    }
    whole.map(|frames| frames.len())
}

/// The streaming verifier ([`crate::frame_scan::FrameScanner`]) must refuse exactly
/// what the decoder refuses, with the same error, and pass the same frames.
fn scan_agrees(data: &[u8], piece: usize, decoded: &Result<Vec<Frame>, WireError>) {
    let mut scanner = crate::frame_scan::FrameScanner::new();
    let mut frames = 0usize;
    let scanned = data
        .chunks(piece)
        .try_for_each(|c| scanner.push(c, |_| frames += 1))
        .and_then(|()| scanner.finish());
    match (decoded, scanned) {
        (Ok(f), Ok(())) => assert_eq!(f.len(), frames, "scanner and decoder count differ"),
        (Err(a), Err(b)) => assert_eq!(*a, b, "scanner and decoder refuse differently"),
        (Ok(_), Err(e)) => panic!("the decoder accepts what the scanner refuses: {e}"),
        (Err(e), Ok(())) => panic!("the scanner accepts what the decoder refuses: {e}"),
    }
}

fn decode_in_pieces(data: &[u8], piece: usize) -> Result<Vec<Frame>, WireError> {
    let mut d = FrameDecoder::new();
    let mut frames = Vec::new();
    for chunk in data.chunks(piece) {
        d.push(chunk);
        while let Some(f) = d.next_frame()? {
            frames.push(f);
        }
    }
    d.finish()?;
    Ok(frames)
}

/// `data` with the checksum of every complete tile or error-table frame recomputed.
fn with_frame_checksums(data: &[u8]) -> Vec<u8> {
    let mut out = data.to_vec();
    let mut at = 0;
    while let Some(h) = out.get(at..at + FRAME_HEADER_LEN) {
        let len = u32::from_le_bytes([h[0], h[1], h[2], h[3]]) as usize;
        let kind = h[4];
        let Some(payload) = out.get(at + FRAME_HEADER_LEN..at + FRAME_HEADER_LEN + len) else {
            break;
        };
        if kind == 0 || kind == 3 {
            let sum = format::checksum(payload);
            out[at + 16..at + 24].copy_from_slice(&sum.to_le_bytes());
        }
        at += FRAME_HEADER_LEN + len;
    }
    out
}

/// A bootstrap ([`crate::bootstrap`]): decoded and, when accepted, its absent tiles
/// listed (what a client does with one); the frames and absent tiles counted.
pub fn bootstrap(data: &[u8]) -> Result<usize, crate::bootstrap::BootstrapError> {
    let b = crate::bootstrap::Bootstrap::decode(data)?;
    Ok(b.frames.len() + b.absent().len())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tile::Level;

    #[test]
    fn garbage_is_an_error_not_a_panic() {
        for data in [&b""[..], b"TESSPYR\0", &[0xff; 100]] {
            assert!(pyramid(data).is_err());
            assert!(wire(data).is_err());
        }
    }

    #[test]
    fn a_valid_stream_decodes() {
        let level = Level::new(2).unwrap();
        let mut s = wire::error_frame(level, Morton::from_raw(1), 5, "bad");
        s.extend(wire::trailer_frame(level, 0, 1, &[]));
        assert_eq!(wire(&s).unwrap(), 2);
    }
}
