//! The tile-record codec: error table, then heights through a 2-D predictor and LZ4.
//!
//! Heights (`(T+1)²` quantized `u16`, row-major) are replaced by their residual
//! against the planar predictor `left + up − up_left` (wrapping `u16`
//! arithmetic, so the inverse is exact for any input), zigzag-mapped so small
//! negative and positive residuals both become small numbers, split into a plane
//! of low bytes and a plane of high bytes (terrain residuals leave the high plane
//! almost all zero), and compressed with `lz4_flex`'s block format.
//! A record is served exactly as stored; only clients decode it.
//!
//! Format v2 puts the tile's validity mask ([`crate::mask`]) between the error
//! table and the heights: a `u32` length, then that many bytes of
//! [`CellMask::encode`]; length 0 means every cell is terrain (the common case costs
//! 4 bytes). Version 1 records have no mask section; every cell reads as valid.

use crate::error_table::ErrorTable;
use crate::mask::{CellMask, MaskError};

/// Why a record could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CodecError {
    #[error("record of {got} bytes is shorter than its {need}-byte error table")]
    Truncated { got: usize, need: usize },
    #[error("height data does not decompress: {0}")]
    Lz4(String),
    #[error("height data decompresses to {got} bytes, expected {want}")]
    WrongSize { got: usize, want: usize },
    #[error("mask section claims {claimed} bytes but only {left} follow the error table")]
    MaskTruncated { claimed: usize, left: usize },
    #[error(transparent)]
    Mask(#[from] MaskError),
}

/// How to read a record: the tile size and the file's format version.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RecordLayout {
    tile_log2: u32,
    has_mask: bool,
}

impl RecordLayout {
    /// The layout of `version` files (1 or 2; the reader refuses others first).
    pub const fn new(tile_log2: u32, version: u32) -> Self {
        Self {
            tile_log2,
            has_mask: version >= 2,
        }
    }

    /// The layout this build writes.
    pub const fn current(tile_log2: u32) -> Self {
        Self::new(tile_log2, crate::format::VERSION)
    }

    pub const fn tile_log2(&self) -> u32 {
        self.tile_log2
    }

    /// Whether records carry a mask section (format v2 and later).
    pub const fn has_mask(&self) -> bool {
        self.has_mask
    }
}

/// A decoded tile record.
#[derive(Clone, Debug, PartialEq)]
pub struct TileRecord {
    pub errors: ErrorTable,
    /// `(T+1)²` quantized heights, row-major, north row first.
    pub heights: Vec<u16>,
    /// Which cells are terrain (all of them in version 1 files).
    pub mask: CellMask,
}

const fn zigzag(v: u16) -> u16 {
    let s = v as i16;
    ((s << 1) ^ (s >> 15)) as u16
}

const fn unzigzag(v: u16) -> u16 {
    ((v >> 1) as i16 ^ -((v & 1) as i16)) as u16
}

/// Planar prediction for sample `(x, y)` from already-known neighbours.
fn predict(h: &[u16], side: usize, x: usize, y: usize) -> u16 {
    let i = y * side + x;
    match (x, y) {
        (0, 0) => 0,
        (_, 0) => h[i - 1],
        (0, _) => h[i - side],
        _ => h[i - 1]
            .wrapping_add(h[i - side])
            .wrapping_sub(h[i - side - 1]),
    }
}

/// Compresses a square grid of `side × side` heights.
pub fn encode_heights(heights: &[u16], side: usize) -> Vec<u8> {
    assert_eq!(heights.len(), side * side, "heights must be side × side");
    let n = heights.len();
    let mut planes = vec![0u8; 2 * n];
    for y in 0..side {
        for x in 0..side {
            let i = y * side + x;
            let r = zigzag(heights[i].wrapping_sub(predict(heights, side, x, y)));
            planes[i] = r as u8;
            planes[n + i] = (r >> 8) as u8;
        }
    }
    lz4_flex::block::compress(&planes)
}

/// Inverse of [`encode_heights`].
pub fn decode_heights(bytes: &[u8], side: usize) -> Result<Vec<u16>, CodecError> {
    let n = side * side;
    let planes =
        lz4_flex::block::decompress(bytes, 2 * n).map_err(|e| CodecError::Lz4(e.to_string()))?;
    if planes.len() != 2 * n {
        return Err(CodecError::WrongSize {
            got: planes.len(),
            want: 2 * n,
        });
    }
    let mut h = vec![0u16; n];
    for y in 0..side {
        for x in 0..side {
            let i = y * side + x;
            let r = unzigzag(u16::from(planes[i]) | (u16::from(planes[n + i]) << 8));
            h[i] = r.wrapping_add(predict(&h, side, x, y));
        }
    }
    Ok(h)
}

/// A current-format record: error table, mask section, then heights.
pub fn encode_record(errors: &ErrorTable, mask: &CellMask, heights: &[u16]) -> Vec<u8> {
    let side = (1usize << errors.tile_log2()) + 1;
    debug_assert_eq!(mask.side() as usize, side - 1);
    let mut out = Vec::with_capacity(ErrorTable::byte_len(errors.tile_log2()) + heights.len());
    errors.write_to(&mut out);
    let m = if mask.is_all_valid() {
        Vec::new()
    } else {
        mask.encode()
    };
    out.extend_from_slice(&(m.len() as u32).to_le_bytes());
    out.extend_from_slice(&m);
    out.extend_from_slice(&encode_heights(heights, side));
    out
}

/// Only the error table (the first part of every record version).
pub fn decode_error_table(record: &[u8], tile_log2: u32) -> Result<ErrorTable, CodecError> {
    ErrorTable::read_from(record, tile_log2).ok_or(CodecError::Truncated {
        got: record.len(),
        need: ErrorTable::byte_len(tile_log2),
    })
}

/// Decodes a whole record laid out as `layout` says.
pub fn decode_record(record: &[u8], layout: RecordLayout) -> Result<TileRecord, CodecError> {
    let t = layout.tile_log2;
    let errors = decode_error_table(record, t)?;
    let cells = 1u32 << t;
    let side = cells as usize + 1;
    let mut rest = &record[ErrorTable::byte_len(t)..];
    let mask = if layout.has_mask {
        let Some((len, after)) = rest.split_first_chunk::<4>() else {
            return Err(CodecError::Truncated {
                got: record.len(),
                need: ErrorTable::byte_len(t) + 4,
            });
        };
        let len = u32::from_le_bytes(*len) as usize;
        if len > after.len() {
            return Err(CodecError::MaskTruncated {
                claimed: len,
                left: after.len(),
            });
        }
        let (bytes, heights) = after.split_at(len);
        rest = heights;
        if len == 0 {
            CellMask::all_valid(cells)
        } else {
            CellMask::decode(bytes, cells)?
        }
    } else {
        CellMask::all_valid(cells)
    };
    let heights = decode_heights(rest, side)?;
    Ok(TileRecord {
        errors,
        heights,
        mask,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testdata;

    #[test]
    fn zigzag_is_a_bijection() {
        for v in 0..=u16::MAX {
            assert_eq!(unzigzag(zigzag(v)), v);
        }
        assert_eq!(zigzag(0), 0);
        assert_eq!(zigzag(u16::MAX), 1); // -1
        assert_eq!(zigzag(1), 2);
    }

    #[test]
    fn extreme_values_round_trip() {
        // Alternating extremes make every residual wrap: the inverse must still be exact.
        let side = 65;
        let h: Vec<u16> = (0..side * side)
            .map(|i| if (i / side + i) % 2 == 0 { 0 } else { u16::MAX })
            .collect();
        assert_eq!(decode_heights(&encode_heights(&h, side), side).unwrap(), h);
    }

    fn read_png16(path: &std::path::Path) -> (usize, usize, Vec<u16>) {
        let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
        let mut reader = png::Decoder::new(file).read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!(info.bit_depth, png::BitDepth::Sixteen);
        let samples = buf[..info.buffer_size()]
            .chunks_exact(2)
            .map(|c| u16::from_be_bytes([c[0], c[1]]))
            .collect();
        (info.width as usize, info.height as usize, samples)
    }

    /// Cuts `side × side` windows out of a real 16-bit DEM and checks bit-exact round trips.
    fn round_trip_real_dem(name: &str, side: usize) {
        let Some(path) = testdata::dem_or_skip(name) else {
            return;
        };
        let (w, h, samples) = read_png16(&path);
        let mut checked = 0;
        let mut compressed = 0usize;
        for y0 in (0..h.saturating_sub(side - 1)).step_by(side - 1) {
            for x0 in (0..w.saturating_sub(side - 1)).step_by(side - 1) {
                let tile: Vec<u16> = (0..side * side)
                    .map(|i| samples[(y0 + i / side) * w + x0 + i % side])
                    .collect();
                let bytes = encode_heights(&tile, side);
                compressed += bytes.len();
                assert_eq!(
                    decode_heights(&bytes, side).unwrap(),
                    tile,
                    "{name} at ({x0},{y0})"
                );
                checked += 1;
            }
        }
        assert!(checked > 0, "{name} has no full {side}² window");
        // Real terrain must compress (a broken predictor leaves ~2 bytes per sample).
        let per_sample = compressed as f64 / (checked * side * side) as f64;
        assert!(per_sample < 1.6, "{name}: {per_sample:.2} bytes per sample");
    }

    #[test]
    fn real_tiles_round_trip_bit_exact() {
        round_trip_real_dem("jacksboro_fault_dem.png", 129);
        round_trip_real_dem("sthelens_10m.png", 513);
    }

    #[test]
    fn records_round_trip_and_reject_damage() {
        let mut t = ErrorTable::empty(6);
        t.set_error(6, 1, 1, 3.0);
        let heights: Vec<u16> = (0..65 * 65).map(|i| (i * 7 % 1000) as u16).collect();
        let layout = RecordLayout::current(6);
        let mut mask = CellMask::all_valid(64);
        let rec = encode_record(&t, &mask, &heights);
        let back = decode_record(&rec, layout).unwrap();
        assert_eq!(back.errors, t);
        assert_eq!(back.heights, heights);
        assert!(back.mask.is_all_valid());
        assert!(matches!(
            decode_record(&rec[..100], layout),
            Err(CodecError::Truncated { .. })
        ));
        let cut = &rec[..rec.len() - 3];
        assert!(decode_record(cut, layout).is_err());

        mask.set(10, 20, false);
        let rec = encode_record(&t, &mask, &heights);
        let back = decode_record(&rec, layout).unwrap();
        assert_eq!(back.mask, mask);
        assert_eq!(back.heights, heights);
        // A mask length running past the record is named as such.
        let mut lying = rec.clone();
        let at = ErrorTable::byte_len(6);
        lying[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(
            decode_record(&lying, layout),
            Err(CodecError::MaskTruncated { .. })
        ));
    }

    #[test]
    fn version_1_records_have_no_mask_section_and_read_as_all_valid() {
        let t = ErrorTable::empty(6);
        let heights: Vec<u16> = (0..65 * 65).map(|i| (i % 300) as u16).collect();
        let mut v1 = Vec::new();
        t.write_to(&mut v1);
        v1.extend_from_slice(&encode_heights(&heights, 65));
        let back = decode_record(&v1, RecordLayout::new(6, 1)).unwrap();
        assert_eq!(back.heights, heights);
        assert!(back.mask.is_all_valid());
        // Read as v2, the first height bytes would be taken for a mask length.
        assert!(decode_record(&v1, RecordLayout::new(6, 2)).is_err());
    }
}
