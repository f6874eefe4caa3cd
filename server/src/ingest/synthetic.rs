//! `synthetic:SIZE[:SEED]`: deterministic mountains and valleys of any size, for
//! demos and scale tests.
//!
//! Every height is a closed-form function of its position and the seed, built from
//! gradient noise (a pseudo-random unit gradient at every lattice point, blended
//! with a quintic fade so slopes are continuous: no creases along lattice lines):
//!
//! - a *domain warp* bends the coordinates by a low-frequency noise field, so
//!   ranges and valleys meander instead of following the lattice;
//! - an *uplift* field (a few smooth octaves, higher toward the middle of the
//!   terrain) says where the ranges stand and where the lowlands ring them;
//! - *ridged* octaves (`(1 − |n|)²`, sharp where the noise crosses zero) make the
//!   crests; each octave is weighted by the one below it, so fine detail gathers
//!   on the ridges and the valley floors stay smooth, as erosion leaves them;
//! - *valleys* cut through the ranges along a level line of another noise field,
//!   the one through the terrain's centre (so a valley runs through the middle);
//! - rolling *hills* (plain fractal octaves) roughen the lowlands a little.
//!
//! Octaves halve in wavelength (and turn by 36.87° so no axis is favoured) from
//! the landform scale down to two samples, so the terrain has relief at every
//! scale. The landform scale is the terrain's size up to `MAX_WAVELENGTH`
//! samples: a small terrain is one massif, a large one many ranges.
//!
//! Since nothing is stored, any window can be generated independently, in any
//! order, on any thread, and a 262145² terrain holds no memory beyond the window
//! being read.

use super::raster::{self, Raster};
use anyhow::{Context, bail};

/// Largest synthetic terrain.
const MAX_SIZE: u32 = 262_145;
/// Wavelength in samples of the largest landforms (at 30 m a sample, ~30 km:
/// ranges a few tens of kilometres across, as in the Alps).
const MAX_WAVELENGTH: f64 = 1024.0;
/// Quantization: `h = OFFSET + SCALE · q`.
pub const OFFSET: f64 = -2000.0;
pub const SCALE: f64 = 0.125;

/// Salts that make each noise field independent of the others.
const WARP_X: u64 = 1;
const WARP_Y: u64 = 2;
const UPLIFT: u64 = 3;
const RIDGES: u64 = 4;
const HILLS: u64 = 5;
const VALLEYS: u64 = 6;

#[derive(Debug)]
pub struct Synthetic {
    size: u32,
    seed: u64,
    /// Landform wavelength in samples.
    wavelength: f64,
    /// Octaves from the landform scale down to two samples.
    octaves: u32,
    /// The valley noise at the terrain's centre (valleys follow its level lines).
    valley_level: f64,
}

/// cos and sin of 11.25° and of 33.75°.
const C1: f64 = 0.980_785_280_403_230_4;
const S1: f64 = 0.195_090_322_016_128_3;
const C3: f64 = 0.831_469_612_302_545_2;
const S3: f64 = 0.555_570_233_019_602_2;
/// Sixteen unit gradients, evenly spaced around the circle: at `(k + ½) · 22.5°`.
const GRADIENTS: [(f64, f64); 16] = [
    (C1, S1),
    (C3, S3),
    (S3, C3),
    (S1, C1),
    (-S1, C1),
    (-S3, C3),
    (-C3, S3),
    (-C1, S1),
    (-C1, -S1),
    (-C3, -S3),
    (-S3, -C3),
    (-S1, -C1),
    (S1, -C1),
    (S3, -C3),
    (C3, -S3),
    (C1, -S1),
];

/// 64 well-mixed bits from a lattice point, a salt and the seed (SplitMix64's
/// finaliser over the packed coordinates).
fn hash(ix: i64, iy: i64, salt: u64) -> u64 {
    let mut z = (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ salt.wrapping_mul(0x1656_67B1_9E37_79F9);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// `6t⁵ − 15t⁴ + 10t³`: zero first and second derivatives at 0 and 1, so the
/// blended noise has continuous slope and curvature across lattice lines.
fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

fn lerp(a: f64, b: f64, t: f64) -> f64 {
    a + (b - a) * t
}

fn smoothstep(lo: f64, hi: f64, x: f64) -> f64 {
    let t = ((x - lo) / (hi - lo)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// The next octave's coordinates: twice the frequency, turned by atan(3/4) so the
/// lattices of successive octaves never line up.
fn next_octave(x: f64, y: f64) -> (f64, f64) {
    (1.6 * x - 1.2 * y, 1.2 * x + 1.6 * y)
}

impl Synthetic {
    /// Parses `SIZE[:SEED]`.
    pub fn parse(spec: &str) -> anyhow::Result<Self> {
        let mut parts = spec.split(':');
        let size: u32 = parts
            .next()
            .unwrap_or("")
            .parse()
            .context("SIZE is not a whole number")?;
        let seed: u64 = match parts.next() {
            Some(s) => s.parse().context("SEED is not a whole number")?,
            None => 1,
        };
        if parts.next().is_some() {
            bail!("too many ':' fields");
        }
        Self::new(size, seed)
    }

    pub fn new(size: u32, seed: u64) -> anyhow::Result<Self> {
        if !(2..=MAX_SIZE).contains(&size) {
            bail!("SIZE {size} is outside 2..={MAX_SIZE}");
        }
        let wavelength = f64::from(size - 1).clamp(64.0, MAX_WAVELENGTH);
        // Octaves from about half the landform wavelength down to two samples.
        let octaves = ((wavelength / 4.0).log2().floor() as u32).max(1);
        let mut s = Self {
            size,
            seed,
            wavelength,
            octaves,
            valley_level: 0.0,
        };
        let centre = f64::from(size - 1) / 2.0;
        let (qx, qy) = s.warp(centre, centre);
        s.valley_level = s.valley_noise(qx, qy);
        Ok(s)
    }

    pub fn size(&self) -> u32 {
        self.size
    }

    /// Bytes the terrain holds in memory, for the build's budget: nothing is stored
    /// but the generator itself.
    pub fn memory_bytes(&self) -> u64 {
        size_of::<Self>() as u64
    }

    pub fn description(&self) -> String {
        format!(
            "synthetic mountain terrain {0}×{0}, seed {1}",
            self.size, self.seed
        )
    }

    /// Gradient noise at `(x, y)` in lattice units, roughly in `[-1, 1]`.
    fn noise(&self, x: f64, y: f64, salt: u64) -> f64 {
        let (fx, fy) = (x.floor(), y.floor());
        let (ix, iy) = (fx as i64, fy as i64);
        let (dx, dy) = (x - fx, y - fy);
        let salt = salt ^ self.seed.rotate_left(17);
        let corner = |cx: i64, cy: i64, ox: f64, oy: f64| {
            let (gx, gy) = GRADIENTS[(hash(ix + cx, iy + cy, salt) >> 60) as usize];
            gx * ox + gy * oy
        };
        let (u, v) = (fade(dx), fade(dy));
        let bottom = lerp(corner(0, 0, dx, dy), corner(1, 0, dx - 1.0, dy), u);
        let top = lerp(
            corner(0, 1, dx, dy - 1.0),
            corner(1, 1, dx - 1.0, dy - 1.0),
            u,
        );
        // A 2-D gradient noise peaks at ±√½; scale it to about ±1.
        std::f64::consts::SQRT_2 * lerp(bottom, top, v)
    }

    /// Fractal sum of `octaves` octaves, each `gain` times the one below, divided
    /// by the sum of the weights: roughly in `[-1, 1]`.
    fn fbm(&self, mut x: f64, mut y: f64, octaves: u32, gain: f64, salt: u64) -> f64 {
        let (mut sum, mut norm, mut amp) = (0.0, 0.0, 1.0);
        for k in 0..octaves {
            sum += amp * self.noise(x, y, salt.wrapping_add(u64::from(k) << 8));
            norm += amp;
            amp *= gain;
            (x, y) = next_octave(x, y);
        }
        sum / norm
    }

    /// Ridged octaves in `[0, 1]`: each is `(1 − |n|)²`, a crest where the noise
    /// crosses zero, weighted by the octave below (detail on the crests, smooth
    /// valley floors), each octave 0.55 times the one below (rougher than
    /// Brownian, as mountains are).
    fn ridged(&self, mut x: f64, mut y: f64, octaves: u32, salt: u64) -> f64 {
        let (mut sum, mut norm, mut amp, mut weight) = (0.0, 0.0, 1.0, 1.0);
        for k in 0..octaves {
            let n = self.noise(x, y, salt.wrapping_add(u64::from(k) << 8));
            let crest = (1.0 - n.abs()).powi(2);
            sum += amp * weight * crest;
            norm += amp;
            weight = (1.6 * crest).clamp(0.0, 1.0);
            amp *= 0.55;
            (x, y) = next_octave(x, y);
        }
        sum / norm
    }

    /// The noise whose level lines are the valleys, at warped coordinates.
    fn valley_noise(&self, qx: f64, qy: f64) -> f64 {
        self.noise(2.0 * qx + 7.1, 2.0 * qy - 3.7, VALLEYS)
    }

    /// Warped coordinates of sample `(x, y)`, in landform wavelengths: the plane
    /// bent by up to about a tenth of the landform scale.
    fn warp(&self, x: f64, y: f64) -> (f64, f64) {
        let (px, py) = (x / self.wavelength, y / self.wavelength);
        let wx = self.fbm(1.3 * px, 1.3 * py, 3, 0.5, WARP_X);
        let wy = self.fbm(1.3 * px + 5.2, 1.3 * py + 1.3, 3, 0.5, WARP_Y);
        (px + 0.25 * wx, py + 0.25 * wy)
    }

    /// The height in metres of sample `(x, y)`: between ~150 and ~4500 m.
    fn height_m(&self, x: f64, y: f64) -> f64 {
        let (qx, qy) = self.warp(x, y);
        // Where the ranges stand (1) and where the lowlands lie (0): the ranges
        // rise toward the middle of the terrain and lowlands ring it, so that the
        // whole terrain seen from above reads as a mountain region.
        let size = f64::from(self.size - 1).max(1.0);
        let rim = 2.0 * (x / size - 0.5).hypot(y / size - 0.5);
        let region = self.fbm(1.4 * qx, 1.4 * qy, 3, 0.5, UPLIFT) + 0.35 - 0.6 * rim * rim;
        let uplift = smoothstep(-0.5, 0.2, region);
        let ridges = self.ridged(
            1.6 * qx,
            1.6 * qy,
            self.octaves.saturating_sub(1).max(1),
            RIDGES,
        );
        // Valleys cut through the ranges, to a fifth of the height the range
        // would have, where another low-frequency noise crosses the value it has
        // at the terrain's centre: a valley always runs through the middle.
        let river = (self.valley_noise(qx, qy) - self.valley_level).abs();
        let carve = 0.2 + 0.8 * smoothstep(0.0, 0.3, river);
        let mountains = 3600.0 * uplift * ridges.powf(1.2) * carve;
        // Rolling hills everywhere, rougher in the ranges.
        let hills = self.fbm(3.0 * qx, 3.0 * qy, self.octaves, 0.5, HILLS);
        let floor = 350.0 + 200.0 * region;
        floor + mountains + (60.0 + 100.0 * uplift) * hills
    }

    fn quantize(h: f64) -> u16 {
        ((h - OFFSET) / SCALE).round().clamp(0.0, 65535.0) as u16
    }
}

impl Raster for Synthetic {
    fn width(&self) -> u32 {
        self.size
    }

    fn height(&self) -> u32 {
        self.size
    }

    fn depth_counts(&self) -> raster::DepthCounts {
        raster::all_valid_depth_counts(self.size, self.size)
    }

    fn read_window(&self, x0: u32, y0: u32, w: u32, h: u32, out: &mut [u16]) -> anyhow::Result<()> {
        debug_assert!(out.len() >= (w as usize) * (h as usize));
        for (row, line) in out
            .chunks_exact_mut(w as usize)
            .take(h as usize)
            .enumerate()
        {
            let y = f64::from(y0) + row as f64;
            for (col, v) in line.iter_mut().enumerate() {
                *v = Self::quantize(self.height_m(f64::from(x0) + col as f64, y));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn window(s: &Synthetic, x0: u32, y0: u32, w: u32, h: u32) -> Vec<u16> {
        let mut v = vec![0; (w * h) as usize];
        s.read_window(x0, y0, w, h, &mut v).unwrap();
        v
    }

    fn metres(q: u16) -> f64 {
        OFFSET + SCALE * f64::from(q)
    }

    #[test]
    fn windows_agree_wherever_they_overlap() {
        let s = Synthetic::new(1000, 7).unwrap();
        let big = window(&s, 0, 0, 300, 200);
        let small = window(&s, 100, 50, 90, 70);
        for y in 0..70 {
            for x in 0..90 {
                assert_eq!(small[y * 90 + x], big[(y + 50) * 300 + x + 100]);
            }
        }
        // A point read alone equals the same point inside a window.
        assert_eq!(window(&s, 128, 64, 1, 1)[0], big[64 * 300 + 128]);
        assert_eq!(window(&s, 299, 199, 1, 1)[0], big[199 * 300 + 299]);
    }

    #[test]
    fn seeds_and_sizes_are_deterministic_and_distinct() {
        let a = window(&Synthetic::new(2049, 1).unwrap(), 500, 500, 64, 64);
        let b = window(&Synthetic::new(2049, 1).unwrap(), 500, 500, 64, 64);
        let c = window(&Synthetic::new(2049, 2).unwrap(), 500, 500, 64, 64);
        assert_eq!(a, b);
        assert_ne!(a, c);
        // Real relief: not flat and not pinned at the ends of the quantization range.
        let (lo, hi) = (a.iter().min().unwrap(), a.iter().max().unwrap());
        assert!(hi > lo && *lo > 0 && *hi < u16::MAX);
    }

    /// Heights are plausible metres, with mountains and valleys: the whole terrain
    /// spans kilometres of relief, and windows a kilometre, ten kilometres and a
    /// hundred kilometres across (at 30 m a sample) each have relief of their own
    /// in most places, growing with the window (fractal, not flat at any scale) up
    /// to the height of the ranges.
    #[test]
    fn relief_is_plausible_at_every_scale() {
        for seed in [1, 7] {
            let n = 2049u32;
            let s = Synthetic::new(n, seed).unwrap();
            let all: Vec<f64> = window(&s, 0, 0, n, n).into_iter().map(metres).collect();
            let lo = all.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = all.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            assert!(lo > -100.0 && hi < 6000.0, "seed {seed}: {lo}..{hi} m");
            assert!(hi - lo > 2000.0, "seed {seed}: only {lo}..{hi} m");
            // Median relief (max − min) of windows of each side, on a grid.
            let relief = |side: u32| {
                let mut r: Vec<f64> = (0..8)
                    .flat_map(|j| (0..8).map(move |i| (i, j)))
                    .map(|(i, j)| {
                        let x0 = i * (n - side) / 7;
                        let y0 = j * (n - side) / 7;
                        let mut lo = f64::INFINITY;
                        let mut hi = f64::NEG_INFINITY;
                        for y in y0..y0 + side {
                            let row = &all[(y * n + x0) as usize..(y * n + x0 + side) as usize];
                            for &h in row {
                                lo = lo.min(h);
                                hi = hi.max(h);
                            }
                        }
                        hi - lo
                    })
                    .collect();
                r.sort_by(f64::total_cmp);
                r[r.len() / 2]
            };
            let (small, mid, large) = (relief(33), relief(257), relief(1025));
            println!(
                "seed {seed}: {lo:.0}..{hi:.0} m; median relief {small:.0} / {mid:.0} / {large:.0} m"
            );
            assert!(
                small > 15.0,
                "seed {seed}: 1 km windows nearly flat: {small} m"
            );
            assert!(mid > 2.0 * small, "seed {seed}: {mid} m vs {small} m");
            assert!(large > 1.5 * mid, "seed {seed}: {large} m vs {mid} m");
        }
    }

    /// No creases: the curvature (second difference) across rows on a lattice of
    /// 64 samples (where midpoint displacement's blocks met, and where a naive
    /// noise lattice would line up) is no larger than across all rows.
    #[test]
    fn no_creases_along_lattice_lines() {
        let s = Synthetic::new(1025, 1).unwrap();
        let n = 1025usize;
        let v: Vec<f64> = window(&s, 0, 0, n as u32, n as u32)
            .into_iter()
            .map(f64::from)
            .collect();
        let (mut on, mut on_n, mut all, mut all_n) = (0.0, 0.0, 0.0, 0.0);
        for y in 1..n - 1 {
            for x in 0..n {
                let d = (v[(y - 1) * n + x] - 2.0 * v[y * n + x] + v[(y + 1) * n + x]).abs();
                all += d;
                all_n += 1.0;
                if y % 64 == 0 {
                    on += d;
                    on_n += 1.0;
                }
            }
        }
        let ratio = (on / on_n) / (all / all_n);
        assert!(
            ratio < 1.15,
            "curvature on the 64-lattice is {ratio}× the mean"
        );
    }

    #[test]
    fn gradients_are_unit_vectors_every_22_5_degrees() {
        for (k, (x, y)) in GRADIENTS.iter().enumerate() {
            let a = (k as f64 + 0.5) * std::f64::consts::TAU / 16.0;
            assert!(
                (x - a.cos()).abs() < 1e-15 && (y - a.sin()).abs() < 1e-15,
                "{k}"
            );
        }
    }

    #[test]
    fn bad_specs_are_rejected() {
        assert!(Synthetic::parse("abc").is_err());
        assert!(Synthetic::parse("1").is_err());
        assert!(Synthetic::parse("100:x").is_err());
        assert!(Synthetic::parse("100:1:2").is_err());
        assert!(Synthetic::parse("262146").is_err());
        assert_eq!(Synthetic::parse("65537").unwrap().size(), 65537);
    }
}
