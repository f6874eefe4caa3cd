//! Reprojection at build time (`build --to EPSG:CODE`;
//! DECISIONS.md "Coordinate systems, masks and reprojection"): a [`RowSource`] that
//! resamples another one onto a north-up grid in a new CRS.
//!
//! 1. The source is spooled once into a temporary file of raw `f32` samples, its
//!    no-data as NaN, so any source row can be read back.
//! 2. The output grid covers the source's footprint (its pixel-area border, sampled
//!    densely, carried to the target CRS) with the spacing a source sample has at
//!    the DEM's centre (or `--spacing`).
//! 3. Each output row is inverse-transformed to source pixel coordinates: exactly
//!    at span ends, linearly inside spans whose middle is within [`MAX_ERROR_PX`]
//!    (GDAL's approximate transformer does the same with 1/8 pixel), then sampled
//!    bilinearly (weights renormalised over valid neighbours, as `gdalwarp` does
//!    with no-data) or by nearest neighbour. Outside the source, or where every
//!    neighbour is no-data, the output is no-data.
//!
//! Memory: the band of source rows one output row touches, held as a sliding
//! window (its size is estimated up front for the build's memory plan).

use super::{RowSource, SampleType, SourceInfo};
use crate::approx_transform::along_row;
use crate::crs::Crs;
use anyhow::{Context, anyhow, bail};
use grid::plan_grid;
pub use grid::{Grid, border_ring, bounds, footprint, source_step};
use std::collections::VecDeque;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::os::unix::fs::FileExt;
use std::path::Path;
use tessera_shared::{GeoRef, RasterType};

/// Largest error, in source pixels, of an interpolated source position.
pub const MAX_ERROR_PX: f64 = 1e-3;

/// How output samples are computed from the source's.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Resampling {
    /// Bilinear over the four nearest source samples.
    #[default]
    Bilinear,
    /// Cubic convolution over the 4 × 4 nearest source samples (Keys' kernel with
    /// a = −0.5, as GDAL's `cubic`), weights renormalised over valid neighbours.
    Cubic,
    /// The nearest source sample (keeps integer heights exact).
    Nearest,
}

impl Resampling {
    pub const fn name(self) -> &'static str {
        match self {
            Self::Bilinear => "bilinear",
            Self::Cubic => "cubic",
            Self::Nearest => "nearest",
        }
    }

    /// Source rows (and columns) a sample reads before and after the one at or
    /// above its position.
    const fn reach(self) -> (usize, usize) {
        match self {
            Self::Cubic => (1, 2),
            Self::Bilinear | Self::Nearest => (0, 1),
        }
    }
}

/// Keys' cubic convolution kernel with a = −0.5 (GDAL's `cubic`).
fn cubic_weight(x: f64) -> f64 {
    const A: f64 = -0.5;
    let x = x.abs();
    if x <= 1.0 {
        ((A + 2.0) * x - (A + 3.0)) * x * x + 1.0
    } else if x < 2.0 {
        ((A * x - 5.0 * A) * x + 8.0 * A) * x - 4.0 * A
    } else {
        0.0
    }
}

/// What `--to`, `--resampling` and `--spacing` asked for.
#[derive(Clone, Debug)]
pub struct ReprojectOptions {
    /// `EPSG:CODE` or a PROJ string.
    pub to: String,
    pub resampling: Resampling,
    /// Output spacing `[x, y]` in target CRS units; `None`: the source's resolution
    /// at the DEM's centre.
    pub spacing: Option<[f64; 2]>,
}

/// A source resampled onto a grid in another CRS.
pub struct Reprojected {
    info: SourceInfo,
    spool: File,
    map: Mapping,
    row: u32,
    /// Source rows `band_start .. band_start + band.len()`.
    band: VecDeque<Vec<f32>>,
    band_start: usize,
    band_rows_estimate: usize,
    /// For each sample of the last row read, its distance in source samples to the
    /// source grid's outer edge (negative outside): what a mosaic feathers seams by.
    edge: Vec<f32>,
}

/// Where each output sample of a grid in one CRS reads a source grid in another:
/// what [`Reprojected`] samples with, and what a mosaic sizes an input's memory
/// with before opening it ([`Mapping::buffer_bytes`]).
#[derive(Clone, Debug)]
pub struct Mapping {
    pub source: Crs,
    pub target: Crs,
    /// Source geotransform (north-up: no rotation terms) and size.
    pub src_gt: [f64; 6],
    pub src_w: usize,
    pub src_h: usize,
    pub out: Grid,
    pub resampling: Resampling,
}

impl std::fmt::Debug for Reprojected {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reprojected")
            .field("info", &self.info)
            .field("target", &self.map.target)
            .finish_non_exhaustive()
    }
}

impl Reprojected {
    /// Spools `src` into a temporary file in `dir` and plans the output grid.
    /// `nodata` (the user's override, else the source's own value) marks missing
    /// source samples.
    pub fn new(
        src: Box<dyn RowSource>,
        opts: &ReprojectOptions,
        nodata: Option<f64>,
        dir: &Path,
    ) -> anyhow::Result<Self> {
        let info = src.info();
        let georef = info
            .georef
            .clone()
            .ok_or_else(|| anyhow!("--to needs a georeferenced input; this one has no CRS"))?;
        let gt = georef.geotransform;
        if gt[2] != 0.0 || gt[4] != 0.0 {
            bail!("--to: rotated source grids are not supported (geotransform {gt:?})");
        }
        let source = Crs::of(&georef).ok_or_else(|| {
            anyhow!(
                "--to: the input's CRS ({}) is not known to the projection library",
                georef.crs_name.as_deref().unwrap_or("unnamed")
            )
        })?;
        let target = Crs::parse(&opts.to).with_context(|| format!("--to {}", opts.to))?;
        let (w, h) = (info.width as usize, info.height as usize);
        let out = plan_grid(&source, &target, &gt, w, h, opts.spacing)?;
        Self::onto(src, &source, target, out, opts.resampling, nodata, dir)
    }

    /// Resamples `src` (in CRS `source`) onto the grid `out` of CRS `target`: what
    /// [`Reprojected::new`] does once it has planned the grid, and what a mosaic of
    /// inputs on different grids does for each input, onto its window of the
    /// mosaic's grid.
    pub fn onto(
        mut src: Box<dyn RowSource>,
        source: &Crs,
        target: Crs,
        out: Grid,
        resampling: Resampling,
        nodata: Option<f64>,
        dir: &Path,
    ) -> anyhow::Result<Self> {
        let info = src.info().clone();
        let gt = info
            .georef
            .as_ref()
            .map(|g| g.geotransform)
            .ok_or_else(|| anyhow!("a reprojected input needs a geotransform"))?;
        let (w, h) = (info.width as usize, info.height as usize);
        // 1. Spool the source with no-data as NaN.
        let nodata = nodata.or(info.nodata).map(|v| v as f32);
        let file = tempfile::tempfile_in(dir)
            .with_context(|| format!("cannot create a temporary file in {}", dir.display()))?;
        let mut writer = BufWriter::with_capacity(1 << 20, file);
        let mut row = vec![0f32; w];
        for _ in 0..h {
            src.read_rows(&mut row)?;
            for v in &mut row {
                if Some(*v) == nodata {
                    *v = f32::NAN;
                }
            }
            let bytes: Vec<u8> = row.iter().flat_map(|v| v.to_le_bytes()).collect();
            writer
                .write_all(&bytes)
                .context("cannot write the reprojection spool")?;
        }
        let spool = writer
            .into_inner()
            .map_err(std::io::IntoInnerError::into_error)
            .context("cannot write the reprojection spool")?;
        let mut out_georef = GeoRef {
            epsg: target.epsg(),
            crs_name: target.name(),
            proj: None,
            wkt: None,
            geotransform: out.gt,
            raster_type: RasterType::PixelIsArea,
        };
        target.describe(&mut out_georef);
        let sample_type = match resampling {
            Resampling::Nearest => info.sample_type,
            Resampling::Bilinear | Resampling::Cubic => SampleType::Float32,
        };
        let mut me = Self {
            info: SourceInfo {
                width: out.width,
                height: out.height,
                sample_type,
                nodata: None,
                georef: Some(out_georef),
                description: format!(
                    "{}, reprojected to {} ({})",
                    info.description,
                    target
                        .epsg()
                        .map_or_else(|| target.proj_string().to_string(), |c| format!("EPSG:{c}")),
                    resampling.name()
                ),
            },
            spool,
            map: Mapping {
                source: source.clone(),
                target,
                src_gt: gt,
                src_w: w,
                src_h: h,
                out,
                resampling,
            },
            row: 0,
            band: VecDeque::new(),
            band_start: 0,
            band_rows_estimate: 0,
            edge: Vec::new(),
        };
        me.band_rows_estimate = me.map.estimate_band_rows();
        Ok(me)
    }

    /// Makes the band hold source rows `lo..=hi`.
    fn load_band(&mut self, lo: usize, hi: usize) -> anyhow::Result<()> {
        if lo < self.band_start || lo > self.band_start + self.band.len() {
            self.band.clear();
            self.band_start = lo;
        }
        while self.band_start < lo && !self.band.is_empty() {
            self.band.pop_front();
            self.band_start += 1;
        }
        if self.band.is_empty() {
            self.band_start = lo;
        }
        let mut raw = vec![0u8; 4 * self.map.src_w];
        while self.band_start + self.band.len() <= hi {
            let r = self.band_start + self.band.len();
            self.spool
                .read_exact_at(&mut raw, (r * self.map.src_w * 4) as u64)
                .context("reading the reprojection spool")?;
            self.band.push_back(
                raw.chunks_exact(4)
                    .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                    .collect(),
            );
        }
        Ok(())
    }

    fn sample(&self, col: f64, row: f64) -> f32 {
        let (w, h) = (self.map.src_w as f64, self.map.src_h as f64);
        // Inside the source's pixel areas: centres −0.5 ..= size − 0.5.
        if !(col >= -0.5 && col <= w - 0.5 && row >= -0.5 && row <= h - 0.5) {
            return f32::NAN;
        }
        let at = |c: usize, r: usize| -> f32 {
            r.checked_sub(self.band_start)
                .and_then(|i| self.band.get(i))
                .map_or(f32::NAN, |line| line[c])
        };
        let (c, r) = (col.clamp(0.0, w - 1.0), row.clamp(0.0, h - 1.0));
        match self.map.resampling {
            Resampling::Nearest => at(c.round() as usize, r.round() as usize),
            Resampling::Bilinear => {
                let (c0, r0) = (c.floor() as usize, r.floor() as usize);
                let (c1, r1) = (
                    (c0 + 1).min(self.map.src_w - 1),
                    (r0 + 1).min(self.map.src_h - 1),
                );
                let (fx, fy) = (c - c0 as f64, r - r0 as f64);
                let mut sum = 0.0f64;
                let mut weight = 0.0f64;
                for (v, wgt) in [
                    (at(c0, r0), (1.0 - fx) * (1.0 - fy)),
                    (at(c1, r0), fx * (1.0 - fy)),
                    (at(c0, r1), (1.0 - fx) * fy),
                    (at(c1, r1), fx * fy),
                ] {
                    if !v.is_nan() && wgt > 0.0 {
                        sum += f64::from(v) * wgt;
                        weight += wgt;
                    }
                }
                if weight > 0.0 {
                    (sum / weight) as f32
                } else {
                    f32::NAN
                }
            }
            Resampling::Cubic => {
                let (c0, r0) = (c.floor(), r.floor());
                let (fx, fy) = (c - c0, r - r0);
                let mut sum = 0.0f64;
                let mut weight = 0.0f64;
                for dr in -1i64..=2 {
                    let rr = r0 as i64 + dr;
                    if rr < 0 || rr >= self.map.src_h as i64 {
                        continue;
                    }
                    let wy = cubic_weight(fy - dr as f64);
                    for dc in -1i64..=2 {
                        let cc = c0 as i64 + dc;
                        if cc < 0 || cc >= self.map.src_w as i64 {
                            continue;
                        }
                        let v = at(cc as usize, rr as usize);
                        let wgt = wy * cubic_weight(fx - dc as f64);
                        if !v.is_nan() && wgt != 0.0 {
                            sum += f64::from(v) * wgt;
                            weight += wgt;
                        }
                    }
                }
                if weight.abs() > 1e-9 {
                    (sum / weight) as f32
                } else {
                    f32::NAN
                }
            }
        }
    }
}

impl Mapping {
    /// Source pixel coordinates (`col`, `row` of sample centres, fractional) of each
    /// output sample of output row `j`: exact at the ends of spans of up to
    /// [`crate::approx_transform::STEP`] samples, halved until the middle sample's linear estimate is within
    /// [`MAX_ERROR_PX`] of its exact transform (GDAL's approximate transformer does
    /// the same with 1/8 pixel), linear inside.
    pub fn source_coords(&self, j: u32) -> Vec<[f64; 2]> {
        let w = self.out.width as usize;
        let y = self.out.gt[3] + (f64::from(j) + 0.5) * self.out.gt[5];
        let exact = |i: usize| -> Option<[f64; 2]> {
            let x = self.out.gt[0] + (i as f64 + 0.5) * self.out.gt[1];
            let [sx, sy] = self.target.transform_to(&self.source, x, y).ok()?;
            let c = [
                (sx - self.src_gt[0]) / self.src_gt[1] - 0.5,
                (sy - self.src_gt[3]) / self.src_gt[5] - 0.5,
            ];
            (c[0].is_finite() && c[1].is_finite()).then_some(c)
        };
        along_row(w, MAX_ERROR_PX, &exact)
    }

    /// The widest band of source rows an output row needs, from every 64th row.
    pub fn estimate_band_rows(&self) -> usize {
        let mut most = 2usize;
        let h = self.out.height;
        for j in (0..h).step_by(64).chain(std::iter::once(h - 1)) {
            if let Some((lo, hi)) = self.row_span(&self.source_coords(j)) {
                most = most.max(hi - lo + 1);
            }
        }
        most
    }

    /// Source rows `lo..=hi` that the samples at `coords` read.
    pub fn row_span(&self, coords: &[[f64; 2]]) -> Option<(usize, usize)> {
        let last = self.src_h as f64 - 1.0;
        let rows = coords
            .iter()
            .map(|c| c[1])
            .filter(|r| r.is_finite() && *r > -0.5 && *r < last + 0.5);
        let (lo, hi) = rows.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), r| {
            (lo.min(r), hi.max(r))
        });
        if lo > hi {
            return None;
        }
        let (before, after) = self.resampling.reach();
        let lo = (lo.floor().max(0.0) as usize).saturating_sub(before);
        let hi = (hi.floor().max(0.0) as usize + after).min(self.src_h - 1);
        Some((lo, hi))
    }

    /// Memory a [`Reprojected`] over this mapping holds while reading: the widest
    /// band of source rows, the coordinates of one row and the spool's read buffer.
    pub fn buffer_bytes(&self) -> u64 {
        (self.estimate_band_rows() * self.src_w * 4 + self.out.width as usize * 16 + (1 << 20))
            as u64
    }
}

impl RowSource for Reprojected {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn read_rows(&mut self, out: &mut [f32]) -> anyhow::Result<()> {
        let w = self.info.width as usize;
        for line in out.chunks_exact_mut(w) {
            if self.row >= self.info.height {
                bail!("read past the last reprojected row");
            }
            let coords = self.map.source_coords(self.row);
            let (sw, sh) = (self.map.src_w as f64, self.map.src_h as f64);
            self.edge.clear();
            self.edge.extend(coords.iter().map(|c| {
                // Sample centres are at −0.5 + ½ … ; the pixel-area edge at −0.5 and
                // size − 0.5.
                let d = (c[0] + 0.5)
                    .min(sw - 0.5 - c[0])
                    .min(c[1] + 0.5)
                    .min(sh - 0.5 - c[1]);
                if d.is_finite() {
                    d as f32
                } else {
                    f32::NEG_INFINITY
                }
            }));
            match self.map.row_span(&coords) {
                Some((lo, hi)) => {
                    self.load_band(lo, hi)?;
                    for (o, c) in line.iter_mut().zip(&coords) {
                        *o = if c[0].is_finite() && c[1].is_finite() {
                            self.sample(c[0], c[1])
                        } else {
                            f32::NAN
                        };
                    }
                }
                None => line.fill(f32::NAN),
            }
            self.row += 1;
        }
        Ok(())
    }

    fn edge_distance(&self) -> Option<&[f32]> {
        Some(&self.edge)
    }

    fn buffer_bytes(&self) -> u64 {
        // The band, the coordinates of one row, and the spool's read buffer.
        (self.band_rows_estimate * self.map.src_w * 4 + self.info.width as usize * 16 + (1 << 20))
            as u64
    }
}

/// Why a `--spacing` value is refused ([`parse_spacing`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SpacingError {
    #[error("{0:?} is not a positive number")]
    NotPositive(String),
    #[error("{0:?}: want X or X,Y")]
    NotOneOrTwo(String),
}

/// Parses `--spacing X[,Y]`.
pub fn parse_spacing(s: &str) -> Result<[f64; 2], SpacingError> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let num = |p: &str| -> Result<f64, SpacingError> {
        p.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v > 0.0)
            .ok_or_else(|| SpacingError::NotPositive(p.into()))
    };
    match parts.as_slice() {
        [x] => Ok([num(x)?, num(x)?]),
        [x, y] => Ok([num(x)?, num(y)?]),
        _ => Err(SpacingError::NotOneOrTwo(s.into())),
    }
}

mod grid;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spacing_takes_one_or_two_positive_numbers() {
        assert_eq!(parse_spacing("30").unwrap(), [30.0, 30.0]);
        assert_eq!(parse_spacing("0.001, 0.002").unwrap(), [0.001, 0.002]);
        assert!(parse_spacing("-1").is_err());
        assert!(parse_spacing("1,2,3").is_err());
        assert!(parse_spacing("x").is_err());
    }
}
