//! Which cells of a tile are terrain (format v2;
//! docs/ARCHITECTURE.md#heights-and-no-data).
//!
//! No-data samples are filled so the mesh never cracks, but a filled area, and the
//! padding beyond the DEM's width and height, is not terrain: it must never be drawn
//! or served as such. A [`CellMask`] records, for each of a tile's `T × T` cells,
//! whether it is terrain.
//!
//! - At the finest level a cell is valid iff its four corner samples are inside the
//!   DEM and were not no-data.
//! - A coarse cell covers 2×2 cells of the level below; it is valid iff all four are
//!   ([`CellMask::pooled`]). So the valid area only shrinks going up the pyramid: a
//!   masked cell stays masked at every level, and a coarse tile never draws terrain
//!   where a finer one has none.
//!
//! ```
//! use tessera_shared::mask::CellMask;
//!
//! let mut m = CellMask::all_valid(4);
//! m.set(3, 0, false);
//! assert!(!m.is_valid(3, 0) && m.is_valid(2, 0));
//! assert_eq!(m.valid_cells(), 15);
//! let back = CellMask::decode(&m.encode(), 4).unwrap();
//! assert_eq!(back, m);
//! ```

/// A tile's cell validity, `side × side` bits, row-major, north row first.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CellMask {
    side: u32,
    /// One bit per cell, 1 = valid, least significant bit first.
    bits: Vec<u64>,
}

/// Why a stored mask could not be read.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum MaskError {
    #[error("validity mask does not decompress: {0}")]
    Lz4(String),
    #[error("validity mask decompresses to {got} bytes, expected {want}")]
    WrongSize { got: usize, want: usize },
}

impl CellMask {
    /// Every cell valid.
    pub fn all_valid(side: u32) -> Self {
        let n = (side as usize) * (side as usize);
        let mut bits = vec![u64::MAX; n.div_ceil(64)];
        if !n.is_multiple_of(64)
            && let Some(last) = bits.last_mut()
        {
            *last = (1u64 << (n % 64)) - 1;
        }
        Self { side, bits }
    }

    /// No cell valid.
    pub fn none_valid(side: u32) -> Self {
        let n = (side as usize) * (side as usize);
        Self {
            side,
            bits: vec![0; n.div_ceil(64)],
        }
    }

    /// Cells per side (the tile size `T`).
    pub const fn side(&self) -> u32 {
        self.side
    }

    fn at(&self, x: u32, y: u32) -> usize {
        debug_assert!(x < self.side && y < self.side);
        (y as usize) * (self.side as usize) + x as usize
    }

    pub fn is_valid(&self, x: u32, y: u32) -> bool {
        let i = self.at(x, y);
        self.bits[i / 64] >> (i % 64) & 1 == 1
    }

    pub fn set(&mut self, x: u32, y: u32, valid: bool) {
        let i = self.at(x, y);
        if valid {
            self.bits[i / 64] |= 1 << (i % 64);
        } else {
            self.bits[i / 64] &= !(1 << (i % 64));
        }
    }

    pub fn valid_cells(&self) -> u64 {
        self.bits.iter().map(|w| u64::from(w.count_ones())).sum()
    }

    pub fn is_all_valid(&self) -> bool {
        self.valid_cells() == u64::from(self.side) * u64::from(self.side)
    }

    pub fn is_none_valid(&self) -> bool {
        self.bits.iter().all(|w| *w == 0)
    }

    /// The finest-level mask from sample validity: `valid(x, y)` for the tile's
    /// `(side + 1)²` samples (false beyond the DEM). A cell is valid iff its four
    /// corners are.
    pub fn from_samples(side: u32, valid: impl Fn(u32, u32) -> bool) -> Self {
        let mut m = Self::none_valid(side);
        let s = side as usize + 1;
        // One row of corner validity at a time: each sample is asked once.
        let mut above: Vec<bool> = (0..=side).map(|x| valid(x, 0)).collect();
        let mut below = vec![false; s];
        for y in 0..side {
            for (x, b) in below.iter_mut().enumerate() {
                *b = valid(x as u32, y + 1);
            }
            for x in 0..side as usize {
                if above[x] && above[x + 1] && below[x] && below[x + 1] {
                    m.set(x as u32, y, true);
                }
            }
            std::mem::swap(&mut above, &mut below);
        }
        m
    }

    /// A parent's mask from its four children (NW, NE, SW, SE: Morton quadrant
    /// order; `None` = absent child). Parent cell `(x, y)` covers cells
    /// `(2x − off, 2y − off) + {0,1}²` of the child in its quadrant and is valid iff
    /// all four are.
    pub fn pooled(side: u32, children: [Option<&CellMask>; 4]) -> Self {
        let mut m = Self::none_valid(side);
        let half = side / 2;
        for (q, child) in children.iter().enumerate() {
            let Some(c) = child else { continue };
            debug_assert_eq!(c.side, side);
            let (qx, qy) = ((q as u32 & 1) * half, (q as u32 >> 1) * half);
            for y in 0..half {
                for x in 0..half {
                    let (cx, cy) = (2 * x, 2 * y);
                    let ok = c.is_valid(cx, cy)
                        && c.is_valid(cx + 1, cy)
                        && c.is_valid(cx, cy + 1)
                        && c.is_valid(cx + 1, cy + 1);
                    if ok {
                        m.set(qx + x, qy + y, true);
                    }
                }
            }
        }
        m
    }

    /// The stored form: the bitmap's bytes (little-endian words), LZ4 block format.
    pub fn encode(&self) -> Vec<u8> {
        lz4_flex::block::compress(&self.raw_bytes())
    }

    fn raw_bytes(&self) -> Vec<u8> {
        let n = self.raw_len();
        let mut raw: Vec<u8> = self.bits.iter().flat_map(|w| w.to_le_bytes()).collect();
        raw.truncate(n);
        raw
    }

    fn raw_len(&self) -> usize {
        ((self.side as usize) * (self.side as usize)).div_ceil(8)
    }

    /// Reads [`CellMask::encode`]'s output for a `side`-cell tile.
    pub fn decode(bytes: &[u8], side: u32) -> Result<Self, MaskError> {
        let mut m = Self::none_valid(side);
        let want = m.raw_len();
        let raw =
            lz4_flex::block::decompress(bytes, want).map_err(|e| MaskError::Lz4(e.to_string()))?;
        if raw.len() != want {
            return Err(MaskError::WrongSize {
                got: raw.len(),
                want,
            });
        }
        for (w, chunk) in m.bits.iter_mut().zip(raw.chunks(8)) {
            let mut b = [0u8; 8];
            b[..chunk.len()].copy_from_slice(chunk);
            *w = u64::from_le_bytes(b);
        }
        // Bits past the last cell are not cells: keep them clear so equality and
        // counts hold whatever a damaged file put there.
        let n = (side as usize) * (side as usize);
        if !n.is_multiple_of(64)
            && let Some(last) = m.bits.last_mut()
        {
            *last &= (1u64 << (n % 64)) - 1;
        }
        Ok(m)
    }

    /// One byte per cell (255 valid, 0 not), row-major: the texture the renderer
    /// samples to discard non-terrain fragments.
    pub fn to_bytes_per_cell(&self) -> Vec<u8> {
        let n = (self.side as usize) * (self.side as usize);
        (0..n)
            .map(|i| {
                if self.bits[i / 64] >> (i % 64) & 1 == 1 {
                    255
                } else {
                    0
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn all_and_none_count_exactly_the_cells() {
        for side in [1, 3, 8, 64, 100] {
            let n = u64::from(side) * u64::from(side);
            assert_eq!(CellMask::all_valid(side).valid_cells(), n);
            assert!(CellMask::all_valid(side).is_all_valid());
            assert!(CellMask::none_valid(side).is_none_valid());
        }
    }

    #[test]
    fn a_cell_is_valid_only_when_its_four_corners_are() {
        // Sample (2, 1) is missing: the four cells around it are not terrain.
        let m = CellMask::from_samples(4, |x, y| (x, y) != (2, 1));
        for y in 0..4 {
            for x in 0..4 {
                let touches = (x == 1 || x == 2) && (y == 0 || y == 1);
                assert_eq!(m.is_valid(x, y), !touches, "cell ({x}, {y})");
            }
        }
        assert_eq!(m.valid_cells(), 12);
    }

    #[test]
    fn pooling_keeps_a_masked_cell_masked_and_absent_children_empty() {
        let side = 8;
        let mut ne = CellMask::all_valid(side);
        ne.set(5, 6, false);
        let all = CellMask::all_valid(side);
        let m = CellMask::pooled(side, [Some(&all), Some(&ne), None, Some(&all)]);
        // NE quadrant starts at x = 4; child cell (5, 6) lies under parent (4 + 2, 3).
        assert!(!m.is_valid(4 + 2, 3));
        assert!(m.is_valid(4 + 3, 3) && m.is_valid(4 + 2, 2));
        // The absent SW child leaves its quadrant empty.
        for y in 4..8 {
            for x in 0..4 {
                assert!(!m.is_valid(x, y));
            }
        }
        assert_eq!(m.valid_cells(), 3 * 16 - 1);
    }

    #[test]
    fn encoding_round_trips_and_damage_is_refused() {
        let mut m = CellMask::all_valid(64);
        for i in 0..64 {
            m.set(i, (i * 7) % 64, false);
        }
        let bytes = m.encode();
        assert_eq!(CellMask::decode(&bytes, 64).unwrap(), m);
        assert!(CellMask::decode(&bytes, 128).is_err());
        assert!(CellMask::decode(&bytes[..bytes.len() / 2], 64).is_err());
    }

    #[test]
    fn bytes_per_cell_follow_the_bits() {
        let m = CellMask::from_samples(2, |x, _| x < 2);
        assert_eq!(m.to_bytes_per_cell(), vec![255, 0, 255, 0]);
    }
}
