//! From source band values to 8-bit colour channels.
//!
//! 8-bit bands are taken as they are (`[0, 255]`). Wider data (16-bit Landsat 8/9,
//! Sentinel-2 reflectances) spans only a small part of its type's range, so it is
//! stretched linearly from the band's 2nd to its 98th percentile — the default of
//! most GIS viewers (QGIS's "cumulative count cut 2–98 %") — clamped outside. Each
//! band gets its own range; a constant band maps to mid grey rather than dividing by 0.

use super::source::SourceImage;

/// Percentiles of a wide band mapped to 0 and 255.
pub const LOW_PERCENTILE: f64 = 2.0;
pub const HIGH_PERCENTILE: f64 = 98.0;

/// Linear maps of three bands onto 0..=255.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stretch {
    /// Per output channel, the source values mapped to 0 and 255.
    pub ranges: [[f64; 2]; 3],
}

impl Stretch {
    /// The stretch of `bands` (0-based) of `image`.
    pub fn of(image: &SourceImage, bands: [usize; 3]) -> Self {
        let ranges = bands.map(|b| {
            if image.bits == 8 {
                [0.0, 255.0]
            } else {
                percentile_range(image.band_values(b))
            }
        });
        Self { ranges }
    }

    /// Channel `c`'s 8-bit value for source value `v`.
    pub fn apply(&self, c: usize, v: f32) -> u8 {
        let [lo, hi] = self.ranges[c];
        if hi <= lo {
            return 128;
        }
        let t = (f64::from(v) - lo) / (hi - lo);
        (t * 255.0).round().clamp(0.0, 255.0) as u8
    }
}

/// The [`LOW_PERCENTILE`]–[`HIGH_PERCENTILE`] range of 16-bit values (exact: a full
/// histogram). Zero is left out: it is the fill of every scene's edge.
fn percentile_range(values: impl Iterator<Item = u16>) -> [f64; 2] {
    let mut hist = vec![0u64; 1 << 16];
    let mut n = 0u64;
    for v in values.filter(|&v| v != 0) {
        hist[usize::from(v)] += 1;
        n += 1;
    }
    if n == 0 {
        return [0.0, 0.0];
    }
    let at = |p: f64| {
        let rank = ((p / 100.0) * (n - 1) as f64).round() as u64;
        let mut seen = 0;
        for (v, &c) in hist.iter().enumerate() {
            seen += c;
            if seen > rank {
                return v as f64;
            }
        }
        65535.0
    };
    [at(LOW_PERCENTILE), at(HIGH_PERCENTILE)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_of_a_uniform_ramp() {
        // 1..=1000: the 2nd percentile is ~21, the 98th ~980; zeros are ignored.
        let values = (1..=1000u16).chain(std::iter::repeat_n(0, 5000));
        let [lo, hi] = percentile_range(values);
        assert!((lo - 21.0).abs() <= 1.0, "{lo}");
        assert!((hi - 980.0).abs() <= 1.0, "{hi}");
    }

    #[test]
    fn apply_maps_the_range_onto_8_bits_and_clamps() {
        let s = Stretch {
            ranges: [[100.0, 355.0], [0.0, 255.0], [7.0, 7.0]],
        };
        assert_eq!(s.apply(0, 100.0), 0);
        assert_eq!(s.apply(0, 355.0), 255);
        assert_eq!(s.apply(0, 227.5), 128);
        assert_eq!(s.apply(0, 10.0), 0);
        assert_eq!(s.apply(0, 9000.0), 255);
        assert_eq!(s.apply(1, 77.0), 77);
        assert_eq!(s.apply(2, 7.0), 128);
    }
}
