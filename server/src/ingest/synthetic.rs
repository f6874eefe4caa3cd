//! `synthetic:SIZE[:SEED]`: a deterministic fractal terrain of any size, for demos
//! and scale tests.
//!
//! Midpoint displacement: a coarse grid (one sample every 64) is refined from four
//! random corners, then every 64×64 block is refined from its own four corners.
//! A new point is the mean of the two ends of its edge (or the four corners of
//! its cell) plus noise hashed from its position and the seed, with amplitude
//! `A · (s / S)^H`, scaled by the local height (the mean of the parents) so that
//! lowlands stay smooth and highlands turn rugged, as eroded terrain does. Every value depends only on its position and the seed, so any
//! window can be generated independently, in any order, on any thread, and a
//! 65537² terrain never needs more than one block per thread in memory.

use crate::build::raster::Raster;
use anyhow::{Context, bail};

/// Coarse-grid spacing: blocks of `BLOCK × BLOCK` cells are generated independently.
const BLOCK: u32 = 64;
/// Largest synthetic terrain (the coarse grid of 2^12+1 squared values stays small).
const MAX_SIZE: u32 = 262_145;
/// Root amplitude in metres and roughness exponent.
const AMPLITUDE: f32 = 2200.0;
const HURST: f32 = 0.8;
/// Quantization: `h = OFFSET + SCALE · q`.
pub const OFFSET: f64 = -2000.0;
pub const SCALE: f64 = 0.125;

#[derive(Debug)]
pub struct Synthetic {
    size: u32,
    seed: u64,
    /// Padded side `2^m · BLOCK + 1`.
    padded: u32,
    /// Coarse samples at multiples of `BLOCK`, `side × side`.
    coarse: Vec<f32>,
    side: usize,
}

/// Uniform noise in `[-1, 1)` from a position and the seed (SplitMix64 finaliser).
fn noise(x: u32, y: u32, seed: u64) -> f32 {
    let mut z = (u64::from(x) << 32 | u64::from(y)) ^ seed.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    ((z >> 40) as f32 / (1u64 << 23) as f32) - 1.0
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
        let blocks = (size - 1).div_ceil(BLOCK).next_power_of_two();
        let padded = blocks * BLOCK + 1;
        let side = blocks as usize + 1;
        let mut coarse = vec![0f32; side * side];
        let top = padded - 1;
        for (i, (x, y)) in [(0, 0), (top, 0), (0, top), (top, top)]
            .into_iter()
            .enumerate()
        {
            let (cx, cy) = ((x / BLOCK) as usize, (y / BLOCK) as usize);
            // Corners: half the amplitude so the terrain sits mostly inside the range.
            coarse[cy * side + cx] = 0.5 * AMPLITUDE * noise(x, y, seed ^ i as u64);
        }
        let mut s = Self {
            size,
            seed,
            padded,
            coarse,
            side,
        };
        let mut grid = std::mem::take(&mut s.coarse);
        s.refine(&mut grid, side, BLOCK, 0, 0);
        s.coarse = grid;
        Ok(s)
    }

    pub fn size(&self) -> u32 {
        self.size
    }

    /// Bytes the terrain holds in memory (its coarse grid), for the build's budget.
    pub fn memory_bytes(&self) -> u64 {
        (self.coarse.len() * size_of::<f32>()) as u64
    }

    pub fn description(&self) -> String {
        format!(
            "synthetic fractal terrain {0}×{0}, seed {1}",
            self.size, self.seed
        )
    }

    fn amplitude(&self, spacing: u32) -> f32 {
        AMPLITUDE * (spacing as f32 / (self.padded - 1) as f32).powf(HURST)
    }

    /// Midpoint displacement on a `side × side` buffer of samples `unit` apart whose
    /// first sample is at global `(ox, oy)`; only the four corners are set on entry.
    fn refine(&self, buf: &mut [f32], side: usize, unit: u32, ox: u32, oy: u32) {
        let mut step = side - 1;
        while step > 1 {
            let half = step / 2;
            let amp = self.amplitude(half as u32 * unit);
            let gx = |i: usize| ox + i as u32 * unit;
            let gy = |j: usize| oy + j as u32 * unit;
            // Cell centres from their four corners.
            for j in (half..side).step_by(step) {
                for i in (half..side).step_by(step) {
                    let c = buf[(j - half) * side + i - half]
                        + buf[(j - half) * side + i + half]
                        + buf[(j + half) * side + i - half]
                        + buf[(j + half) * side + i + half];
                    let m = 0.25 * c;
                    buf[j * side + i] =
                        m + amp * Self::roughness(m) * noise(gx(i), gy(j), self.seed);
                }
            }
            // Edge midpoints from the two ends of their edge only, so blocks agree.
            for j in (0..side).step_by(step) {
                for i in (half..side).step_by(step) {
                    let m = 0.5 * (buf[j * side + i - half] + buf[j * side + i + half]);
                    buf[j * side + i] =
                        m + amp * Self::roughness(m) * noise(gx(i), gy(j), self.seed);
                }
            }
            for j in (half..side).step_by(step) {
                for i in (0..side).step_by(step) {
                    let m = 0.5 * (buf[(j - half) * side + i] + buf[(j + half) * side + i]);
                    buf[j * side + i] =
                        m + amp * Self::roughness(m) * noise(gx(i), gy(j), self.seed);
                }
            }
            step = half;
        }
    }

    /// Roughness grows with height: ×0.25 in the deepest lowlands, ×1.75 on the peaks.
    fn roughness(mean: f32) -> f32 {
        (1.0 + mean / (0.5 * AMPLITUDE)).clamp(0.25, 1.75)
    }

    fn quantize(h: f32) -> u16 {
        ((f64::from(h) - OFFSET) / SCALE)
            .round()
            .clamp(0.0, 65535.0) as u16
    }

    /// Heights of block `(bx, by)`: `(BLOCK + 1)²` samples.
    fn block(&self, bx: u32, by: u32, buf: &mut [f32]) {
        let n = BLOCK as usize + 1;
        buf.fill(0.0);
        let c = |i: u32, j: u32| self.coarse[j as usize * self.side + i as usize];
        buf[0] = c(bx, by);
        buf[n - 1] = c(bx + 1, by);
        buf[(n - 1) * n] = c(bx, by + 1);
        buf[n * n - 1] = c(bx + 1, by + 1);
        self.refine(buf, n, 1, bx * BLOCK, by * BLOCK);
    }
}

impl Raster for Synthetic {
    fn width(&self) -> u32 {
        self.size
    }

    fn height(&self) -> u32 {
        self.size
    }

    fn depth_counts(&self) -> crate::build::raster::DepthCounts {
        crate::build::raster::all_valid_depth_counts(self.size, self.size)
    }

    fn read_window(&self, x0: u32, y0: u32, w: u32, h: u32, out: &mut [u16]) -> anyhow::Result<()> {
        debug_assert!(x0 + w <= self.padded && y0 + h <= self.padded);
        if w == 1 && h == 1 && x0.is_multiple_of(BLOCK) && y0.is_multiple_of(BLOCK) {
            out[0] = Self::quantize(
                self.coarse[(y0 / BLOCK) as usize * self.side + (x0 / BLOCK) as usize],
            );
            return Ok(());
        }
        let n = BLOCK as usize + 1;
        let mut buf = vec![0f32; n * n];
        let last_bx = ((x0 + w - 1) / BLOCK).min(self.padded / BLOCK - 1);
        let last_by = ((y0 + h - 1) / BLOCK).min(self.padded / BLOCK - 1);
        for by in y0 / BLOCK..=last_by {
            for bx in x0 / BLOCK..=last_bx {
                self.block(bx, by, &mut buf);
                let (gx0, gy0) = (bx * BLOCK, by * BLOCK);
                let ys = y0.max(gy0)..(y0 + h).min(gy0 + BLOCK + 1);
                let xs = x0.max(gx0)..(x0 + w).min(gx0 + BLOCK + 1);
                for y in ys {
                    let src = (y - gy0) as usize * n;
                    let dst = (y - y0) as usize * w as usize;
                    for x in xs.clone() {
                        out[dst + (x - x0) as usize] =
                            Self::quantize(buf[src + (x - gx0) as usize]);
                    }
                }
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
        // A coarse-grid point read alone equals the same point inside a window.
        assert_eq!(window(&s, 128, 64, 1, 1)[0], big[64 * 300 + 128]);
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

    #[test]
    fn bad_specs_are_rejected() {
        assert!(Synthetic::parse("abc").is_err());
        assert!(Synthetic::parse("1").is_err());
        assert!(Synthetic::parse("100:x").is_err());
        assert!(Synthetic::parse("100:1:2").is_err());
        assert_eq!(Synthetic::parse("65537").unwrap().size(), 65537);
    }
}
