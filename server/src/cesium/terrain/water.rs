//! A tile's water mask (quantized-mesh extension 2; DECISIONS.md "Cesium terrain",
//! "Water mask"): which of its 256 × 256 cells CesiumJS draws as water.
//!
//! Each cell is judged at its centre, on the pyramid level whose samples are the
//! coarsest still as dense as the cells (the finest when none is), by up to three
//! rules, a cell being water when any says so:
//!
//! - **`--water FILE`**: a raster in EPSG:4326 (one band; a nonzero sample that is
//!   not its no-data is water; outside the raster says nothing);
//! - **`--no-data-water`**: no data there (a no-data cell of the pyramid, a tile it
//!   does not hold, or beyond the DEM) is water: for a DEM whose sea is no-data;
//! - **`--sea-level METRES`**: a cell whose height (the dataset's own heights, before
//!   any geoid) is at or below it is water when it is connected, through such cells
//!   (edge neighbours), to the tile's edge or to a cell without data. A basin below
//!   sea level enclosed by land within the tile stays land; the rule is the tile's
//!   own, so it costs one pass over 65 536 cells and needs no other tile.
//!
//! A tile all land or all water takes the one-byte form.

use super::mapping::Mapping;
use super::{LevelData, Terrain};
use crate::cesium::quantized_mesh::{WATER_MASK_SIDE, WaterMask};
use crate::cesium::tiling::CesiumTile;
use crate::web::resample::SourceTile;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use tessera_shared::TileId;

/// What makes a cell water (`serve --water`, `--no-data-water`, `--sea-level`).
#[derive(Clone, Debug, Default)]
pub struct WaterRule {
    pub raster: Option<Arc<WaterRaster>>,
    pub no_data: bool,
    pub sea_level: Option<f64>,
}

impl WaterRule {
    /// Whether any rule is set: only then are masks made and `watermask` listed.
    pub fn is_set(&self) -> bool {
        self.raster.is_some() || self.no_data || self.sea_level.is_some()
    }
}

/// A water raster in longitude and latitude: one bit per sample.
pub struct WaterRaster {
    path: PathBuf,
    width: u32,
    height: u32,
    /// GDAL geotransform (north-up: no rotation terms).
    gt: [f64; 6],
    bits: Vec<u64>,
}

impl std::fmt::Debug for WaterRaster {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WaterRaster")
            .field("path", &self.path)
            .field("width", &self.width)
            .field("height", &self.height)
            .finish_non_exhaustive()
    }
}

/// The most samples a water raster may have (a bit each: 32 MiB).
pub const MAX_WATER_SAMPLES: u64 = 1 << 28;

/// Why a `--water` raster cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum WaterError {
    #[error("--water {path}: {reason}")]
    Unreadable { path: String, reason: String },
    #[error("--water {path}: no georeferencing (want a GeoTIFF in EPSG:4326)")]
    NoGeoref { path: String },
    #[error(
        "--water {path}: its CRS is {crs}, not EPSG:4326 (reproject it: gdalwarp -t_srs EPSG:4326)"
    )]
    OtherCrs { path: String, crs: String },
    #[error("--water {path}: its geotransform is rotated or degenerate")]
    BadGeotransform { path: String },
    #[error("--water {path}: {samples} samples, more than {MAX_WATER_SAMPLES}")]
    TooLarge { path: String, samples: u64 },
}

impl WaterRaster {
    /// Reads a water raster (GeoTIFF, or any raster input the build reads) in EPSG:4326.
    pub fn open(path: &Path) -> Result<Self, WaterError> {
        let name = path.display().to_string();
        let unreadable = |e: anyhow::Error| WaterError::Unreadable {
            path: name.clone(),
            reason: format!("{e:#}").replace('\n', " "),
        };
        let (mut src, _) = crate::ingest::open_raster(path).map_err(unreadable)?;
        let info = src.info().clone();
        let georef = info
            .georef
            .as_ref()
            .ok_or_else(|| WaterError::NoGeoref { path: name.clone() })?;
        let crs = crate::crs::Crs::of(georef);
        if crs.as_ref().and_then(crate::crs::Crs::epsg) != Some(4326) {
            return Err(WaterError::OtherCrs {
                path: name,
                crs: georef
                    .epsg
                    .map(|c| format!("EPSG:{c}"))
                    .or_else(|| crs.as_ref().and_then(crate::crs::Crs::name))
                    .or_else(|| georef.crs_name.clone())
                    .unwrap_or_else(|| "unknown".into()),
            });
        }
        let gt = georef.geotransform;
        let north_up = gt[2] == 0.0 && gt[4] == 0.0 && gt[1] > 0.0 && gt[5] < 0.0;
        if !north_up {
            return Err(WaterError::BadGeotransform { path: name });
        }
        let samples = u64::from(info.width) * u64::from(info.height);
        if samples > MAX_WATER_SAMPLES {
            return Err(WaterError::TooLarge {
                path: name,
                samples,
            });
        }
        let w = info.width as usize;
        let mut bits = vec![0u64; (samples as usize).div_ceil(64)];
        let rows_at_once = (1 << 20) / w.max(1) + 1;
        let mut row = 0usize;
        let mut buf = Vec::new();
        while row < info.height as usize {
            let n = rows_at_once.min(info.height as usize - row);
            buf.resize(n * w, 0.0f32);
            src.read_rows(&mut buf).map_err(unreadable)?;
            for (k, &v) in buf.iter().enumerate() {
                let nodata = info.nodata.is_some_and(|d| f64::from(v) == d);
                if v.is_finite() && v != 0.0 && !nodata {
                    let i = row * w + k;
                    bits[i / 64] |= 1 << (i % 64);
                }
            }
            row += n;
        }
        Ok(Self {
            path: path.to_path_buf(),
            width: info.width,
            height: info.height,
            gt,
            bits,
        })
    }

    /// Whether the raster says water at a longitude and latitude; `None` outside it.
    pub fn is_water(&self, lon: f64, lat: f64) -> Option<bool> {
        let c = ((lon - self.gt[0]) / self.gt[1]).floor();
        let r = ((lat - self.gt[3]) / self.gt[5]).floor();
        if !(c >= 0.0 && r >= 0.0 && c < f64::from(self.width) && r < f64::from(self.height)) {
            return None;
        }
        let i = r as usize * self.width as usize + c as usize;
        Some(self.bits[i / 64] >> (i % 64) & 1 == 1)
    }
}

/// What the data says at a cell's centre.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Ground {
    /// No data (no-data, an absent tile, beyond the DEM).
    Void,
    /// Data at or below the sea level.
    Low,
    High,
}

impl Terrain {
    /// The water mask of `tile` by `rule` (see the module doc).
    pub fn water_mask<D: LevelData>(
        &self,
        tile: CesiumTile,
        rule: &WaterRule,
        data: &D,
    ) -> Result<WaterMask, D::Error> {
        let n = WATER_MASK_SIDE;
        // In the data's longitudes (east of the antimeridian, +360° where it crosses).
        let [w, s, e, nn] = self.frame_rect(tile);
        let centre = |i: usize, j: usize| {
            let t = |k: usize| (k as f64 + 0.5) / n as f64;
            [w + t(i) * (e - w), nn - t(j) * (nn - s)]
        };
        let needs_data = rule.no_data || rule.sea_level.is_some();
        let ground = if needs_data {
            self.ground(tile, rule.sea_level, data, &centre)?
        } else {
            Vec::new()
        };
        let mut water = vec![false; n * n];
        if let Some(r) = &rule.raster {
            for j in 0..n {
                for i in 0..n {
                    let [lon, lat] = centre(i, j);
                    let wet = r
                        .is_water(lon, lat)
                        .or_else(|| r.is_water(lon - 360.0, lat));
                    water[j * n + i] = wet == Some(true);
                }
            }
        }
        if rule.no_data {
            for (wet, g) in water.iter_mut().zip(&ground) {
                *wet |= *g == Ground::Void;
            }
        }
        if rule.sea_level.is_some() {
            for (wet, sea) in water.iter_mut().zip(connected_low(&ground, n)) {
                *wet |= sea;
            }
        }
        let grid = water.iter().map(|&b| if b { 255 } else { 0 }).collect();
        Ok(WaterMask::from_grid(grid).expect("a 256 × 256 grid"))
    }

    /// Each cell's ground, north row first, read on the level whose samples are
    /// the coarsest at least as dense as the cells.
    fn ground<D: LevelData>(
        &self,
        tile: CesiumTile,
        sea_level: Option<f64>,
        data: &D,
        centre: &impl Fn(usize, usize) -> [f64; 2],
    ) -> Result<Vec<Ground>, D::Error> {
        let n = WATER_MASK_SIDE;
        let cell_deg = CesiumTile::span(tile.z) / n as f64;
        let g = &self.geometry;
        let level = g
            .levels()
            .find(|&l| self.level_spacing_deg(l) <= cell_deg)
            .unwrap_or(g.finest());
        let stride = g.spacing(level) as f64;
        let t = g.tile_size();
        let (xmax, ymax) = (
            f64::from(g.width() - 1) / stride,
            f64::from(g.height() - 1) / stride,
        );
        let positions = self.sample_positions(centre);
        let mut tiles: HashMap<(u32, u32), Option<Arc<SourceTile>>> = HashMap::new();
        let mut out = Vec::with_capacity(n * n);
        for (k, p) in positions.into_iter().enumerate() {
            if k % n == 0 {
                data.check()?;
            }
            let Some([c, r]) = p else {
                out.push(Ground::Void);
                continue;
            };
            let (x, y) = (c / stride, r / stride);
            if !(x >= 0.0 && y >= 0.0 && x <= xmax && y <= ymax) {
                out.push(Ground::Void);
                continue;
            }
            // The cell holding the point (the last one for a point on the far edge).
            let cx = (x.floor() as u32).min((xmax.ceil() as u32).max(1) - 1);
            let cy = (y.floor() as u32).min((ymax.ceil() as u32).max(1) - 1);
            let (tx, ty) = (cx / t, cy / t);
            let src = if let Some(s) = tiles.get(&(tx, ty)) {
                s.clone()
            } else {
                let s = match TileId::new(level, tx, ty) {
                    Some(id) => data.tile(id)?,
                    None => None,
                };
                tiles.insert((tx, ty), s.clone());
                s
            };
            let (lx, ly) = (cx - tx * t, cy - ty * t);
            let ground = match src {
                Some(src) if src.mask.is_valid(lx, ly) => {
                    // The cell's corner nearest the point.
                    let sx = lx + u32::from(x - f64::from(cx) >= 0.5);
                    let sy = ly + u32::from(y - f64::from(cy) >= 0.5);
                    let q = src.heights[(sy * (t + 1) + sx) as usize];
                    let h = self.quantization.height(q);
                    if sea_level.is_some_and(|sea| h <= sea) {
                        Ground::Low
                    } else {
                        Ground::High
                    }
                }
                _ => Ground::Void,
            };
            out.push(ground);
        }
        Ok(out)
    }

    /// Finest-grid coordinates of every cell centre, north row first: exact for a
    /// geographic grid; for a projected one, the projection at 17 × 17 points and
    /// bilinear between them (a 256th of a tile is far below the curvature's scale).
    fn sample_positions(
        &self,
        centre: &impl Fn(usize, usize) -> [f64; 2],
    ) -> Vec<Option<[f64; 2]>> {
        let n = WATER_MASK_SIDE;
        let at = |i: usize, j: usize| {
            let [lon, lat] = centre(i, j);
            self.mapping.to_samples(lon, lat)
        };
        match self.mapping {
            Mapping::Affine { .. } => (0..n * n).map(|k| at(k % n, k / n)).collect(),
            Mapping::Projected { .. } => {
                const STEPS: usize = 16;
                let step = (n - 1) as f64 / STEPS as f64;
                let lattice: Vec<Option<[f64; 2]>> = (0..=STEPS)
                    .flat_map(|b| (0..=STEPS).map(move |a| (a, b)))
                    .map(|(a, b)| {
                        let [lon0, lat0] = centre(0, 0);
                        let [lon1, lat1] = centre(n - 1, n - 1);
                        let (fa, fb) = (a as f64 / STEPS as f64, b as f64 / STEPS as f64);
                        self.mapping
                            .to_samples(lon0 + fa * (lon1 - lon0), lat0 + fb * (lat1 - lat0))
                    })
                    .collect();
                (0..n * n)
                    .map(|k| {
                        let (i, j) = ((k % n) as f64 / step, (k / n) as f64 / step);
                        let (a, b) = ((i as usize).min(STEPS - 1), (j as usize).min(STEPS - 1));
                        let (fa, fb) = (i - a as f64, j - b as f64);
                        let l = |a: usize, b: usize| lattice[b * (STEPS + 1) + a];
                        let [p00, p10, p01, p11] =
                            [l(a, b)?, l(a + 1, b)?, l(a, b + 1)?, l(a + 1, b + 1)?];
                        let mix = |d: usize| {
                            (1.0 - fb) * ((1.0 - fa) * p00[d] + fa * p10[d])
                                + fb * ((1.0 - fa) * p01[d] + fa * p11[d])
                        };
                        Some([mix(0), mix(1)])
                    })
                    .collect()
            }
        }
    }
}

/// Low cells connected through low cells (edge neighbours) to the grid's edge or to
/// a void cell.
fn connected_low(ground: &[Ground], n: usize) -> Vec<bool> {
    let mut sea = vec![false; n * n];
    let mut stack = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let k = j * n + i;
            if ground[k] != Ground::Low {
                continue;
            }
            let edge = i == 0 || j == 0 || i == n - 1 || j == n - 1;
            let by_void = (i > 0 && ground[k - 1] == Ground::Void)
                || (i + 1 < n && ground[k + 1] == Ground::Void)
                || (j > 0 && ground[k - n] == Ground::Void)
                || (j + 1 < n && ground[k + n] == Ground::Void);
            if edge || by_void {
                sea[k] = true;
                stack.push(k);
            }
        }
    }
    while let Some(k) = stack.pop() {
        let (i, j) = (k % n, k / n);
        let mut visit = |m: usize| {
            if ground[m] == Ground::Low && !sea[m] {
                sea[m] = true;
                stack.push(m);
            }
        };
        if i > 0 {
            visit(k - 1);
        }
        if i + 1 < n {
            visit(k + 1);
        }
        if j > 0 {
            visit(k - n);
        }
        if j + 1 < n {
            visit(k + n);
        }
    }
    sea
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn low_cells_are_sea_only_when_connected_to_the_edge_or_a_void() {
        let n = 8;
        let mut g = vec![Ground::High; n * n];
        // A basin enclosed by high cells: stays land.
        g[3 * n + 3] = Ground::Low;
        // A channel from the west edge.
        for i in 0..3 {
            g[6 * n + i] = Ground::Low;
        }
        // Low cells beside a void in the middle.
        g[n + 5] = Ground::Void;
        g[n + 6] = Ground::Low;
        g[2 * n + 6] = Ground::Low;
        let sea = connected_low(&g, n);
        assert!(!sea[3 * n + 3]);
        assert!((0..3).all(|i| sea[6 * n + i]));
        assert!(sea[n + 6] && sea[2 * n + 6]);
        assert!(!sea[n + 5], "a void is not sea by this rule");
        assert_eq!(sea.iter().filter(|&&s| s).count(), 5);
    }
}
