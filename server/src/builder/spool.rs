//! Spooling a row-streamed input into a temporary file of raw `f32` samples, so the
//! tile builder can read any window while memory stays bounded
//! (docs/ARCHITECTURE.md#building-out-of-core).
//!
//! While spooling, no-data samples are counted and filled (never ±32768 spikes,
//! docs/ARCHITECTURE.md#heights-and-no-data): each takes the value of its nearest valid
//! sample, found by a two-pass chamfer distance transform over the band of rows in memory
//! plus the already-filled row above it. Rows that precede the first valid sample copy
//! the first filled row (their nearest valid samples lie straight below).

use crate::ingest::raster::{DepthCounts, Raster, depth};
use crate::ingest::{RowSource, SampleType};
use anyhow::{Context, bail};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::os::unix::fs::FileExt;
use std::path::Path;
use tessera_shared::Quantization;

/// Raw value → quantized `u16`: `q = round((raw − raw_offset) / raw_step)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawQuantizer {
    pub raw_offset: f64,
    pub raw_step: f64,
}

impl RawQuantizer {
    /// Integer samples, stored exactly: a step of one raw unit from the type's least
    /// value.
    pub fn exact(sample_type: SampleType) -> Self {
        Self {
            raw_offset: if sample_type == SampleType::Int16 {
                -32768.0
            } else {
                0.0
            },
            raw_step: 1.0,
        }
    }

    /// Floating-point samples between raw values `lo` and `hi`, in 65 536 steps.
    pub fn over(lo: f64, hi: f64) -> Self {
        Self {
            raw_offset: lo,
            raw_step: if hi > lo { (hi - lo) / 65535.0 } else { 1.0 },
        }
    }

    pub fn quantize(&self, raw: f32) -> u16 {
        ((f64::from(raw) - self.raw_offset) / self.raw_step)
            .round()
            .clamp(0.0, 65535.0) as u16
    }

    /// The dataset quantization after the user's `metres = offset + scale · raw`.
    pub fn to_metres(&self, scale: f64, offset: f64, exact: bool) -> Quantization {
        Quantization {
            offset: offset + scale * self.raw_offset,
            scale: scale * self.raw_step,
            max_error: if exact {
                0.0
            } else {
                (scale * self.raw_step).abs() / 2.0
            },
        }
    }
}

/// `--height-range` in raw sample values: what floating-point samples are quantized
/// over, whatever their own range, so that a part of a distributed build that reads
/// only its share quantizes as the whole build does.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StatedRange {
    /// Raw values (`(metres − offset) / scale`).
    pub raw: [f64; 2],
    /// As the user gave it, in metres, for messages.
    pub metres: [f64; 2],
}

impl StatedRange {
    /// `--height-range` (metres) under `metres = offset + scale · raw` (`scale > 0`).
    pub fn new(metres: [f64; 2], scale: f64, offset: f64) -> Self {
        Self {
            raw: metres.map(|m| (m - offset) / scale),
            metres,
        }
    }

    pub fn quantizer(&self) -> RawQuantizer {
        RawQuantizer::over(self.raw[0], self.raw[1])
    }

    /// Refuses samples from raw `lo` to `hi` that reach beyond the range.
    pub fn check(&self, lo: f32, hi: f32) -> anyhow::Result<()> {
        let [a, b] = self.raw;
        let [ma, mb] = self.metres;
        if f64::from(lo) < a || f64::from(hi) > b {
            let scale = (mb - ma) / (b - a);
            let out = if f64::from(lo) < a { lo } else { hi };
            bail!(
                "a sample is {:.3} m, outside --height-range {ma},{mb}: give a range that \
                 holds every height",
                ma + (f64::from(out) - a) * scale
            );
        }
        Ok(())
    }
}

/// A spooled input: random access to quantized samples.
#[derive(Debug)]
pub struct SpooledRaster {
    file: File,
    /// One byte per sample (1 = input data, 0 = filled no-data), row-major; `None`
    /// when the input had no no-data at all (the common case costs nothing).
    validity: Option<File>,
    depth_counts: DepthCounts,
    width: u32,
    height: u32,
    pub quantizer: RawQuantizer,
    pub nodata_count: u64,
    pub sample_type: SampleType,
}

const SPOOL_WRITE: &str = "cannot write the spooled input in the output directory";

/// Write buffer of the spool file.
pub const SPOOL_BUFFER: usize = 1 << 20;
/// Band memory per sample: the `f32` value, its validity flag and its `u32` distance.
pub const BAND_BYTES_PER_SAMPLE: usize = 9;

/// Chamfer weights (3 for edge neighbours, 4 for diagonals) approximate Euclidean distance.
const EDGE: u32 = 3;
const DIAG: u32 = 4;

/// Fills the void samples of `rows` (a `w`-wide band) from their nearest valid sample.
/// Returns `false` when the band has no valid sample at all.
fn fill_band(rows: &mut [f32], w: usize, valid: &[bool]) -> bool {
    if valid.iter().all(|v| *v) {
        return true;
    }
    if !valid.iter().any(|v| *v) {
        return false;
    }
    let h = rows.len() / w;
    let mut dist: Vec<u32> = valid
        .iter()
        .map(|&v| if v { 0 } else { u32::MAX })
        .collect();
    let relax = |dist: &mut [u32], rows: &mut [f32], i: usize, j: usize, wgt: u32| {
        let d = dist[j].saturating_add(wgt);
        if d < dist[i] {
            dist[i] = d;
            rows[i] = rows[j];
        }
    };
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if x > 0 {
                relax(&mut dist, rows, i, i - 1, EDGE);
            }
            if y > 0 {
                relax(&mut dist, rows, i, i - w, EDGE);
                if x > 0 {
                    relax(&mut dist, rows, i, i - w - 1, DIAG);
                }
                if x + 1 < w {
                    relax(&mut dist, rows, i, i - w + 1, DIAG);
                }
            }
        }
    }
    for y in (0..h).rev() {
        for x in (0..w).rev() {
            let i = y * w + x;
            if x + 1 < w {
                relax(&mut dist, rows, i, i + 1, EDGE);
            }
            if y + 1 < h {
                relax(&mut dist, rows, i, i + w, EDGE);
                if x + 1 < w {
                    relax(&mut dist, rows, i, i + w + 1, DIAG);
                }
                if x > 0 {
                    relax(&mut dist, rows, i, i + w - 1, DIAG);
                }
            }
        }
    }
    true
}

impl SpooledRaster {
    /// Reads every row of `src` into an unnamed temporary file in `dir`.
    /// `nodata` overrides the source's own no-data value; `band_bytes` bounds the
    /// memory used for one band of rows.
    pub fn spool(
        src: &mut dyn RowSource,
        dir: &Path,
        nodata: Option<f64>,
        band_bytes: usize,
        stated: Option<&StatedRange>,
        mut progress: impl FnMut(u32) -> anyhow::Result<()>,
    ) -> anyhow::Result<Self> {
        let info = src.info().clone();
        let w = info.width as usize;
        let nodata = nodata.or(info.nodata).map(|v| v as f32);
        let file = tempfile::tempfile_in(dir)
            .with_context(|| format!("cannot create a temporary file in {}", dir.display()))?;
        let mut out = BufWriter::with_capacity(SPOOL_BUFFER, file);
        // Per sample: the value, its validity flag, and a distance while filling.
        let band_rows = (band_bytes / (w * BAND_BYTES_PER_SAMPLE)).clamp(1, info.height as usize);
        let mut band = vec![0f32; (band_rows + 1) * w];
        let mut valid = vec![false; (band_rows + 1) * w];
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        let mut nodata_count = 0u64;
        let mut depth_counts: DepthCounts = [[0; 2]; 33];
        // Created at the first no-data sample, with the rows before it marked valid.
        let mut validity: Option<BufWriter<File>> = None;
        let mut have_prev = false;
        let mut leading_void_rows = 0u32;
        let mut row = 0u32;
        while row < info.height {
            let n = band_rows.min((info.height - row) as usize);
            // Slot 0 holds the previous (already filled) row as context for the fill.
            let (ctx, rows) = if have_prev {
                (1, &mut band[..(n + 1) * w])
            } else {
                (0, &mut band[..n * w])
            };
            src.read_rows(&mut rows[ctx * w..])?;
            let valid = &mut valid[..rows.len()];
            valid[..ctx * w].fill(true);
            let band_nodata = nodata_count;
            for (i, (v, ok)) in rows[ctx * w..]
                .iter()
                .zip(valid[ctx * w..].iter_mut())
                .enumerate()
            {
                *ok = !v.is_nan() && Some(*v) != nodata;
                let (x, y) = ((i % w) as u32, row + (i / w) as u32);
                depth_counts[depth(x, y)][usize::from(!*ok)] += 1;
                if *ok {
                    lo = lo.min(*v);
                    hi = hi.max(*v);
                } else {
                    nodata_count += 1;
                }
            }
            if validity.is_none() && nodata_count > band_nodata {
                let f = tempfile::tempfile_in(dir).with_context(|| {
                    format!("cannot create a temporary file in {}", dir.display())
                })?;
                let mut b = BufWriter::with_capacity(SPOOL_BUFFER, f);
                let before = vec![1u8; w];
                for _ in 0..row {
                    b.write_all(&before).context(SPOOL_WRITE)?;
                }
                validity = Some(b);
            }
            if let Some(b) = validity.as_mut() {
                let flags: Vec<u8> = valid[ctx * w..].iter().map(|&v| u8::from(v)).collect();
                b.write_all(&flags).context(SPOOL_WRITE)?;
            }
            if fill_band(rows, w, valid) {
                let body = &rows[ctx * w..];
                for v in body {
                    out.write_all(&v.to_le_bytes()).context(SPOOL_WRITE)?;
                }
                if !have_prev && leading_void_rows > 0 {
                    // Rows above the first valid sample copy the first filled row.
                    out.flush().context(SPOOL_WRITE)?;
                    let first: Vec<u8> = body[..w].iter().flat_map(|v| v.to_le_bytes()).collect();
                    for r in 0..leading_void_rows {
                        out.get_ref()
                            .write_all_at(&first, u64::from(r) * 4 * w as u64)
                            .context(SPOOL_WRITE)?;
                    }
                }
                let last = rows.len() - w;
                rows.copy_within(last.., 0);
                have_prev = true;
            } else {
                for _ in 0..n * w {
                    out.write_all(&f32::NAN.to_le_bytes())
                        .context(SPOOL_WRITE)?;
                }
                leading_void_rows += n as u32;
            }
            row += n as u32;
            progress(row)?;
        }
        if !have_prev {
            bail!("input has no valid samples: every sample is no-data");
        }
        let file = out
            .into_inner()
            .map_err(std::io::IntoInnerError::into_error)
            .context(SPOOL_WRITE)?;
        let validity = validity
            .map(|b| b.into_inner().map_err(std::io::IntoInnerError::into_error))
            .transpose()
            .context(SPOOL_WRITE)?;
        let quantizer = if info.sample_type.is_integer() {
            RawQuantizer::exact(info.sample_type)
        } else if let Some(range) = stated {
            range.check(lo, hi)?;
            range.quantizer()
        } else {
            RawQuantizer::over(f64::from(lo), f64::from(hi))
        };
        Ok(Self {
            file,
            validity,
            depth_counts,
            width: info.width,
            height: info.height,
            quantizer,
            nodata_count,
            sample_type: info.sample_type,
        })
    }
}

impl SpooledRaster {
    /// The spool of a part's share (`share::read`): `file` holds the samples
    /// the part reads where a whole spool holds them, and no void (a share with one is
    /// read whole); the rest is never asked for. The depth counts are the whole
    /// raster's as if all valid: a part counts its own (`parts::split::share`).
    pub(crate) fn from_share(
        file: File,
        width: u32,
        height: u32,
        quantizer: RawQuantizer,
        sample_type: SampleType,
    ) -> Self {
        Self {
            file,
            validity: None,
            depth_counts: crate::ingest::raster::all_valid_depth_counts(width, height),
            width,
            height,
            quantizer,
            nodata_count: 0,
            sample_type,
        }
    }
}

impl Raster for SpooledRaster {
    fn width(&self) -> u32 {
        self.width
    }

    fn height(&self) -> u32 {
        self.height
    }

    fn read_window(&self, x0: u32, y0: u32, w: u32, h: u32, out: &mut [u16]) -> anyhow::Result<()> {
        let mut raw = vec![0u8; 4 * w as usize];
        for r in 0..h {
            let off = (u64::from(y0 + r) * u64::from(self.width) + u64::from(x0)) * 4;
            self.file
                .read_exact_at(&mut raw, off)
                .context("reading the spooled input")?;
            let dst = &mut out[(r * w) as usize..((r + 1) * w) as usize];
            for (d, c) in dst.iter_mut().zip(raw.chunks_exact(4)) {
                *d = self
                    .quantizer
                    .quantize(f32::from_le_bytes([c[0], c[1], c[2], c[3]]));
            }
        }
        Ok(())
    }

    fn read_validity(
        &self,
        x0: u32,
        y0: u32,
        w: u32,
        h: u32,
        out: &mut [bool],
    ) -> anyhow::Result<()> {
        let Some(file) = &self.validity else {
            out.fill(true);
            return Ok(());
        };
        let mut raw = vec![0u8; w as usize];
        for r in 0..h {
            let off = u64::from(y0 + r) * u64::from(self.width) + u64::from(x0);
            file.read_exact_at(&mut raw, off)
                .context("reading the spooled validity")?;
            for (d, &v) in out[(r * w) as usize..((r + 1) * w) as usize]
                .iter_mut()
                .zip(&raw)
            {
                *d = v != 0;
            }
        }
        Ok(())
    }

    fn has_nodata(&self) -> bool {
        self.validity.is_some()
    }

    fn depth_counts(&self) -> DepthCounts {
        self.depth_counts
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn voids_take_their_nearest_valid_value() {
        // 5 × 3 band; the void at (1, 1) is next to 10 and far from 99.
        let w = 5;
        let mut rows = vec![
            10.0,
            10.0,
            50.0,
            99.0,
            99.0, //
            10.0,
            f32::NAN,
            f32::NAN,
            f32::NAN,
            99.0, //
            10.0,
            10.0,
            50.0,
            99.0,
            99.0,
        ];
        let valid: Vec<bool> = rows.iter().map(|v: &f32| !v.is_nan()).collect();
        assert!(fill_band(&mut rows, w, &valid));
        assert_eq!(rows[6], 10.0);
        assert_eq!(rows[7], 50.0);
        assert_eq!(rows[8], 99.0);
        let mut void = vec![f32::NAN; 4];
        assert!(!fill_band(&mut void, 2, &[false; 4]));
    }

    #[test]
    fn float_quantization_error_is_half_a_step() {
        let q = RawQuantizer {
            raw_offset: 500.0,
            raw_step: 0.1,
        };
        let m = q.to_metres(2.0, -1.0, false);
        assert!((m.offset - 999.0).abs() < 1e-9 && (m.scale - 0.2).abs() < 1e-12);
        assert!((m.max_error - 0.1).abs() < 1e-12);
        assert_eq!(q.quantize(500.26), 3);
    }
}
