//! Morton (Z-order) codes: `m = interleave(x, y)` with x in the even bits.
//!
//! Within a level, any quadtree subtree is one contiguous Morton range at every
//! deeper level (Yang §3.3), so a viewport is a handful of ranges and a range is
//! one contiguous byte range of the pyramid file (docs/ARCHITECTURE.md#the-file).

use std::fmt;

/// A Morton code within one pyramid level.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Morton(u64);

/// Spreads the low 32 bits of `v` so that bit i lands on bit 2i.
const fn spread(v: u32) -> u64 {
    let mut x = v as u64;
    x = (x | (x << 16)) & 0x0000_FFFF_0000_FFFF;
    x = (x | (x << 8)) & 0x00FF_00FF_00FF_00FF;
    x = (x | (x << 4)) & 0x0F0F_0F0F_0F0F_0F0F;
    x = (x | (x << 2)) & 0x3333_3333_3333_3333;
    x = (x | (x << 1)) & 0x5555_5555_5555_5555;
    x
}

/// Inverse of [`spread`]: gathers the even bits of `v`.
const fn compact(v: u64) -> u32 {
    let mut x = v & 0x5555_5555_5555_5555;
    x = (x | (x >> 1)) & 0x3333_3333_3333_3333;
    x = (x | (x >> 2)) & 0x0F0F_0F0F_0F0F_0F0F;
    x = (x | (x >> 4)) & 0x00FF_00FF_00FF_00FF;
    x = (x | (x >> 8)) & 0x0000_FFFF_0000_FFFF;
    x = (x | (x >> 16)) & 0x0000_0000_FFFF_FFFF;
    x as u32
}

impl Morton {
    /// Interleaves `x` (even bits) and `y` (odd bits).
    ///
    /// ```
    /// use tessera_shared::Morton;
    /// let m = Morton::encode(3, 5);
    /// assert_eq!(m.decode(), (3, 5));
    /// assert_eq!(Morton::encode(1, 0).get(), 1);
    /// assert_eq!(Morton::encode(0, 1).get(), 2);
    /// ```
    pub const fn encode(x: u32, y: u32) -> Self {
        Self(spread(x) | (spread(y) << 1))
    }

    /// The code as a plain integer (its rank in Z-order within the level).
    pub const fn from_raw(v: u64) -> Self {
        Self(v)
    }

    pub const fn get(self) -> u64 {
        self.0
    }

    /// `(x, y)` tile coordinates.
    pub const fn decode(self) -> (u32, u32) {
        (compact(self.0), compact(self.0 >> 1))
    }

    /// The code of the parent tile one level up (`m >> 2`).
    pub const fn parent(self) -> Self {
        Self(self.0 >> 2)
    }

    /// The four children one level down, in Morton order (`m << 2 | q`).
    pub const fn children(self) -> [Self; 4] {
        let b = self.0 << 2;
        [Self(b), Self(b | 1), Self(b | 2), Self(b | 3)]
    }

    /// Which child of its parent this is: 0 = (0,0), 1 = (1,0), 2 = (0,1), 3 = (1,1).
    pub const fn quadrant(self) -> u8 {
        (self.0 & 3) as u8
    }

    /// The inclusive range of codes `depth` levels down covered by this tile's subtree.
    pub fn descendants(self, depth: u8) -> MortonRange {
        let shift = 2 * u32::from(depth);
        let start = self.0 << shift;
        MortonRange {
            start: Morton(start),
            end: Morton(start | ((1u64 << shift) - 1)),
        }
    }
}

impl fmt::Display for Morton {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// An inclusive range of Morton codes `start..=end` within one level.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct MortonRange {
    start: Morton,
    end: Morton,
}

/// Why a Morton range was rejected.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MortonRangeError {
    #[error("range {start}-{end} is reversed (start > end)")]
    Reversed { start: u64, end: u64 },
}

impl MortonRange {
    /// A checked inclusive range.
    pub fn new(start: Morton, end: Morton) -> Result<Self, MortonRangeError> {
        if start > end {
            return Err(MortonRangeError::Reversed {
                start: start.get(),
                end: end.get(),
            });
        }
        Ok(Self { start, end })
    }

    pub const fn single(m: Morton) -> Self {
        Self { start: m, end: m }
    }

    pub const fn start(self) -> Morton {
        self.start
    }

    pub const fn end(self) -> Morton {
        self.end
    }

    /// Number of codes in the range.
    pub const fn len(self) -> u64 {
        self.end.0 - self.start.0 + 1
    }

    /// Never true: a range holds at least one code. Present for API symmetry with `len`.
    pub const fn is_empty(self) -> bool {
        false
    }

    pub const fn contains(self, m: Morton) -> bool {
        self.start.0 <= m.0 && m.0 <= self.end.0
    }

    pub fn iter(self) -> impl Iterator<Item = Morton> {
        (self.start.0..=self.end.0).map(Morton)
    }
}

impl fmt::Display for MortonRange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}-{}", self.start, self.end)
    }
}

/// Coalesces a set of codes into sorted, disjoint, non-adjacent inclusive ranges.
///
/// ```
/// use tessera_shared::{Morton, morton::coalesce};
/// let codes = [5, 3, 4, 9, 10, 4].map(Morton::from_raw);
/// let ranges: Vec<String> = coalesce(codes).iter().map(|r| r.to_string()).collect();
/// assert_eq!(ranges, ["3-5", "9-10"]);
/// ```
pub fn coalesce(codes: impl IntoIterator<Item = Morton>) -> Vec<MortonRange> {
    let mut v: Vec<u64> = codes.into_iter().map(Morton::get).collect();
    v.sort_unstable();
    v.dedup();
    let mut out: Vec<MortonRange> = Vec::new();
    for c in v {
        match out.last_mut() {
            Some(r) if r.end.0 + 1 == c => r.end = Morton(c),
            _ => out.push(MortonRange::single(Morton(c))),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::collections::BTreeSet;

    /// Bit-by-bit interleave, the definition the fast version must match.
    fn interleave_slow(x: u32, y: u32) -> u64 {
        (0..32).fold(0u64, |m, i| {
            m | (u64::from((x >> i) & 1) << (2 * i)) | (u64::from((y >> i) & 1) << (2 * i + 1))
        })
    }

    proptest! {
        #[test]
        fn encode_decode_round_trip(x: u32, y: u32) {
            let m = Morton::encode(x, y);
            prop_assert_eq!(m.get(), interleave_slow(x, y));
            prop_assert_eq!(m.decode(), (x, y));
        }

        #[test]
        fn parent_and_children_agree(x in 0u32..1 << 30, y in 0u32..1 << 30) {
            let m = Morton::encode(x, y);
            prop_assert_eq!(m.parent().decode(), (x / 2, y / 2));
            for (q, c) in m.children().into_iter().enumerate() {
                prop_assert_eq!(c.parent(), m);
                prop_assert_eq!(usize::from(c.quadrant()), q);
                let (cx, cy) = c.decode();
                prop_assert_eq!((cx, cy), (2 * x + (q as u32 & 1), 2 * y + (q as u32 >> 1)));
            }
        }

        #[test]
        fn subtree_is_one_range(x in 0u32..64, y in 0u32..64, depth in 0u8..5) {
            let m = Morton::encode(x, y);
            let r = m.descendants(depth);
            let scale = 1u32 << depth;
            let mut inside = 0u64;
            for cy in 0..64 * scale / 8 {
                for cx in 0..64 * scale / 8 {
                    let c = Morton::encode(cx, cy);
                    let in_subtree = cx / scale == x && cy / scale == y;
                    prop_assert_eq!(r.contains(c), in_subtree);
                    inside += u64::from(in_subtree);
                }
            }
            if x < 8 && y < 8 {
                prop_assert_eq!(inside, r.len());
            }
        }

        #[test]
        fn coalesce_is_exact_sorted_and_disjoint(codes in proptest::collection::vec(0u64..300, 0..120)) {
            let ranges = coalesce(codes.iter().copied().map(Morton::from_raw));
            let want: BTreeSet<u64> = codes.iter().copied().collect();
            let got: BTreeSet<u64> = ranges.iter().flat_map(|r| r.iter().map(Morton::get)).collect();
            prop_assert_eq!(&got, &want);
            let total: u64 = ranges.iter().map(|r| r.len()).sum();
            prop_assert_eq!(total as usize, want.len());
            for w in ranges.windows(2) {
                // Sorted, disjoint and not even adjacent (adjacent ranges must merge).
                prop_assert!(w[0].end().get() + 1 < w[1].start().get());
            }
        }
    }

    #[test]
    fn reversed_range_is_rejected() {
        let err = MortonRange::new(Morton::from_raw(9), Morton::from_raw(3)).unwrap_err();
        assert_eq!(err.to_string(), "range 9-3 is reversed (start > end)");
    }
}
