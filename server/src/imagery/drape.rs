//! Texels of the DEM's grid, sampled from an image in any CRS.
//!
//! A texel's centre is a point of the DEM's finest sample grid (fractional sample
//! coordinates, FORMAT.md "Imagery pyramids"); it is carried to the DEM's CRS by the
//! DEM's geotransform, to the image's CRS by the projection library ([`Crs`]), and to
//! image pixels by the image's geotransform. Over a tile the chain is smooth, so it is
//! evaluated exactly only where [`approx_transform::over_grid`] needs it, within
//! [`MAX_ERROR_PX`] image pixels — the machinery `build --to` uses
//! (`ingest/reproject.rs`). Samples are bilinear; texels outside the image are black
//! (they are outside the DEM's terrain too, or the image does not cover them).

use super::source::SourceImage;
use super::stretch::Stretch;
use crate::approx_transform;
use crate::crs::Crs;
use crate::ingest::reproject::MAX_ERROR_PX;
use tessera_shared::GeoRef;

/// How the DEM's grid maps into an image.
#[derive(Debug)]
pub struct Drape<'a> {
    image: &'a SourceImage,
    dem_georef: GeoRef,
    /// `None` when the DEM and the image share one CRS definition.
    dem_crs: Option<Crs>,
    bands: [usize; 3],
    stretch: Stretch,
}

impl<'a> Drape<'a> {
    pub fn new(
        image: &'a SourceImage,
        dem_georef: GeoRef,
        dem_crs: Crs,
        bands: [usize; 3],
        stretch: Stretch,
    ) -> Self {
        let same = dem_crs.proj_string() == image.crs.proj_string();
        Self {
            image,
            dem_georef,
            dem_crs: (!same).then_some(dem_crs),
            bands,
            stretch,
        }
    }

    /// Image pixel coordinates (corner convention) of finest-grid sample
    /// coordinates `(col, row)`; `None` where the projection fails.
    pub fn pixel_of_sample(&self, col: f64, row: f64) -> Option<[f64; 2]> {
        let [x, y] = self.dem_georef.sample_centre(col, row);
        let [x, y] = match &self.dem_crs {
            None => [x, y],
            Some(dem) => dem.transform_to(&self.image.crs, x, y).ok()?,
        };
        let p = self.image.pixel_of(x, y);
        p.iter().all(|v| v.is_finite()).then_some(p)
    }

    /// `n × n` RGB texels covering finest-grid samples `[x0, x0 + span] × [y0, y0 +
    /// span]`, texel `(u, v)` centred at `(x0 + (u + ½)·span/n, y0 + (v + ½)·span/n)`;
    /// and how many texels fell inside the image.
    pub fn texels(&self, x0: f64, y0: f64, span: f64, n: usize) -> (Vec<u8>, usize) {
        let step = span / n as f64;
        let exact = |u: usize, v: usize| {
            self.pixel_of_sample(x0 + (u as f64 + 0.5) * step, y0 + (v as f64 + 0.5) * step)
        };
        let pixels = approx_transform::over_grid(n, n, MAX_ERROR_PX, &exact);
        let mut rgb = vec![0u8; n * n * 3];
        let mut inside = 0;
        for (px, out) in pixels.iter().zip(rgb.chunks_exact_mut(3)) {
            if let Some(c) = self.colour_at(px[0], px[1]) {
                out.copy_from_slice(&c);
                inside += 1;
            }
        }
        (rgb, inside)
    }

    /// The stretched colour at image pixel coordinates (corner convention), bilinear
    /// between pixel centres; `None` outside the image.
    pub fn colour_at(&self, px: f64, py: f64) -> Option<[u8; 3]> {
        let (w, h) = (self.image.width, self.image.height);
        if !(px >= 0.0 && py >= 0.0 && px <= w as f64 && py <= h as f64) {
            return None;
        }
        // Centre coordinates, clamped so the outer half pixel takes the edge value.
        let fx = (px - 0.5).clamp(0.0, (w - 1) as f64);
        let fy = (py - 0.5).clamp(0.0, (h - 1) as f64);
        let (x0, y0) = (fx.floor() as usize, fy.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (tx, ty) = ((fx - x0 as f64) as f32, (fy - y0 as f64) as f32);
        Some(std::array::from_fn(|c| {
            let b = self.bands[c];
            let s = |x, y| self.image.sample(b, x, y);
            let top = s(x0, y0) * (1.0 - tx) + s(x1, y0) * tx;
            let bottom = s(x0, y1) * (1.0 - tx) + s(x1, y1) * tx;
            self.stretch.apply(c, top * (1.0 - ty) + bottom * ty)
        }))
    }

    /// Whether any of the DEM's `width × height` samples (its border, densely, and
    /// its centre) falls inside the image: a cheap check before any tile is made.
    pub fn overlaps(&self, width: u32, height: u32) -> bool {
        const STEPS: u32 = 64;
        let (w, h) = (f64::from(width - 1), f64::from(height - 1));
        let mut pts = vec![[w / 2.0, h / 2.0]];
        for i in 0..=STEPS {
            let t = f64::from(i) / f64::from(STEPS);
            pts.extend([[t * w, 0.0], [t * w, h], [0.0, t * h], [w, t * h]]);
        }
        let px: Vec<[f64; 2]> = pts
            .iter()
            .filter_map(|&[c, r]| self.pixel_of_sample(c, r))
            .collect();
        if px.is_empty() {
            return false;
        }
        let min = |i: usize| px.iter().map(|p| p[i]).fold(f64::INFINITY, f64::min);
        let max = |i: usize| px.iter().map(|p| p[i]).fold(f64::NEG_INFINITY, f64::max);
        min(0) < self.image.width as f64
            && max(0) > 0.0
            && min(1) < self.image.height as f64
            && max(1) > 0.0
    }

    /// Size of one image pixel in the DEM CRS's units at the image's centre, `[x, y]`
    /// (measured through the projection, so it holds across CRSs).
    pub fn image_pixel_in_dem_units(&self) -> Option<[f64; 2]> {
        let img = self.image;
        let (cx, cy) = (img.width as f64 / 2.0, img.height as f64 / 2.0);
        let gt = img.georef.geotransform;
        let to_dem = |px: f64, py: f64| -> Option<[f64; 2]> {
            let (x, y) = (gt[0] + px * gt[1], gt[3] + py * gt[5]);
            match &self.dem_crs {
                None => Some([x, y]),
                Some(dem) => img.crs.transform_to(dem, x, y).ok(),
            }
        };
        let c = to_dem(cx, cy)?;
        let e = to_dem(cx + 1.0, cy)?;
        let s = to_dem(cx, cy + 1.0)?;
        let d = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
        Some([d(c, e), d(c, s)])
    }
}
