//! Per-tile error tables (Kang §4.1, Yang §4.1, docs/ARCHITECTURE.md#error-tables).
//!
//! For each within-tile level `2^n` (`n = 0..=t`: the tile drawn as a mesh of
//! `2^n × 2^n` cells), an 8×8 grid of blocks holds the maximum vertical distance
//! between that mesh (triangulated as in [`crate::triangulation`]) and the
//! *finest* samples of the pyramid over the block. Block `(bx, by)` covers the
//! closed sample range `[bx·T/8, (bx+1)·T/8] × [by·T/8, (by+1)·T/8]` of the tile,
//! so border samples count in both neighbouring blocks.
//!
//! Each block also stores the min/max (quantized) height of the finest samples it
//! covers. The mesh drawn at level `n` over a block lies within
//! `[min − ε_n, max + ε_n]`: the cuboid bound the client culls and measures
//! distance with (Yang §4.1).
//!
//! Errors are measured against the finest *stored* samples in metres; the
//! dataset's quantization error (in the metadata) comes on top.

use crate::tile::BLOCKS;

const BLOCK_COUNT: usize = (BLOCKS * BLOCKS) as usize;

/// Error table of one tile.
#[derive(Clone, Debug, PartialEq)]
pub struct ErrorTable {
    tile_log2: u32,
    /// `(t + 1) × 64` errors in metres; index `n · 64 + by · 8 + bx`.
    errors: Vec<f32>,
    /// Quantized min/max height per block; index `by · 8 + bx`.
    min: [u16; BLOCK_COUNT],
    max: [u16; BLOCK_COUNT],
}

/// Rounds up to the nearest `f32`, so a stored bound is never below the true value.
pub fn round_up_f32(v: f64) -> f32 {
    let f = v as f32;
    if f64::from(f) < v { f.next_up() } else { f }
}

impl ErrorTable {
    /// Bytes of a serialized table for tiles of `2^tile_log2` cells.
    pub const fn byte_len(tile_log2: u32) -> usize {
        (tile_log2 as usize + 1) * BLOCK_COUNT * 4 + BLOCK_COUNT * 4
    }

    /// A table of zero errors and empty (`min = u16::MAX, max = 0`) blocks.
    pub fn empty(tile_log2: u32) -> Self {
        Self {
            tile_log2,
            errors: vec![0.0; (tile_log2 as usize + 1) * BLOCK_COUNT],
            min: [u16::MAX; BLOCK_COUNT],
            max: [0; BLOCK_COUNT],
        }
    }

    pub const fn tile_log2(&self) -> u32 {
        self.tile_log2
    }

    /// Error in metres of the mesh with `2^n` cells per side over block `(bx, by)`.
    pub fn error(&self, n: u32, bx: u32, by: u32) -> f32 {
        self.errors[Self::index(n, bx, by)]
    }

    pub fn set_error(&mut self, n: u32, bx: u32, by: u32, metres: f32) {
        self.errors[Self::index(n, bx, by)] = metres;
    }

    /// All 64 errors of within-tile level `n`, row-major by block.
    pub fn level_errors(&self, n: u32) -> &[f32] {
        let s = n as usize * BLOCK_COUNT;
        &self.errors[s..s + BLOCK_COUNT]
    }

    /// Quantized `(min, max)` of the finest samples in block `(bx, by)`.
    pub fn block_range(&self, bx: u32, by: u32) -> (u16, u16) {
        let i = (by * BLOCKS + bx) as usize;
        (self.min[i], self.max[i])
    }

    pub fn set_block_range(&mut self, bx: u32, by: u32, min: u16, max: u16) {
        let i = (by * BLOCKS + bx) as usize;
        self.min[i] = min;
        self.max[i] = max;
    }

    /// The tile's error at its own full resolution (`n = t`): what decides between
    /// drawing this tile and refining into its children (docs/ARCHITECTURE.md#selection).
    pub fn full_resolution_error(&self) -> f32 {
        self.level_errors(self.tile_log2)
            .iter()
            .copied()
            .fold(0.0, f32::max)
    }

    /// Quantized `(min, max)` over the whole tile.
    pub fn tile_range(&self) -> (u16, u16) {
        let min = self.min.iter().copied().min().unwrap_or(u16::MAX);
        let max = self.max.iter().copied().max().unwrap_or(0);
        (min, max)
    }

    const fn index(n: u32, bx: u32, by: u32) -> usize {
        n as usize * BLOCK_COUNT + (by * BLOCKS + bx) as usize
    }

    /// Little-endian serialization: errors (`f32`, level-major), then `(min, max)` pairs.
    pub fn write_to(&self, out: &mut Vec<u8>) {
        out.reserve(Self::byte_len(self.tile_log2));
        for e in &self.errors {
            out.extend_from_slice(&e.to_le_bytes());
        }
        for i in 0..BLOCK_COUNT {
            out.extend_from_slice(&self.min[i].to_le_bytes());
            out.extend_from_slice(&self.max[i].to_le_bytes());
        }
    }

    /// Parses a table written by [`ErrorTable::write_to`]; `None` if `bytes` is too short.
    pub fn read_from(bytes: &[u8], tile_log2: u32) -> Option<Self> {
        let bytes = bytes.get(..Self::byte_len(tile_log2))?;
        let (errs, ranges) = bytes.split_at((tile_log2 as usize + 1) * BLOCK_COUNT * 4);
        let errors = errs
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let mut t = Self {
            tile_log2,
            errors,
            min: [0; BLOCK_COUNT],
            max: [0; BLOCK_COUNT],
        };
        for (i, c) in ranges.chunks_exact(4).enumerate() {
            t.min[i] = u16::from_le_bytes([c[0], c[1]]);
            t.max[i] = u16::from_le_bytes([c[2], c[3]]);
        }
        Some(t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_up_never_goes_below() {
        for v in [0.1f64, 1.0 / 3.0, 12_345.678_901, 1e-9, 0.0] {
            let f = round_up_f32(v);
            assert!(f64::from(f) >= v);
            assert!(f64::from(f.next_down()) < v || v == 0.0);
        }
    }

    #[test]
    fn serialization_round_trips() {
        let mut t = ErrorTable::empty(6);
        t.set_error(3, 7, 1, 2.5);
        t.set_error(6, 0, 0, 0.25);
        t.set_block_range(2, 5, 17, 900);
        let mut bytes = Vec::new();
        t.write_to(&mut bytes);
        assert_eq!(bytes.len(), ErrorTable::byte_len(6));
        let back = ErrorTable::read_from(&bytes, 6).unwrap();
        assert_eq!(back, t);
        assert_eq!(back.full_resolution_error(), 0.25);
        assert!(ErrorTable::read_from(&bytes[..bytes.len() - 1], 6).is_none());
    }
}
