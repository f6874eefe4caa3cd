//! Where a dataset lies in the standard grids: its CRS, the way from a grid's
//! coordinates to the dataset's samples, its bounds in WGS 84 and in each grid, and
//! the zooms it is worth serving at. Built once per dataset, whatever its CRS; every
//! coordinate goes through the projection library (crs.rs).

use super::tile_matrix::{MAX_ZOOM, TileMatrixSet, WebTile};
use crate::crs::{Crs, ground_spacing};
use anyhow::{anyhow, bail};
use tessera_shared::{GeoRef, Metadata, RasterType};

/// Web Mercator's latitude limit (where WebMercatorQuad is square): atan(sinh π).
const MERCATOR_MAX_LAT: f64 = 85.051_128_779_806_59;

/// A dataset as the standard grids see it.
pub struct Footprint {
    crs: Crs,
    /// The grids' CRSs, in [`TileMatrixSet::ALL`] order; `None` where the grid's
    /// CRS is the dataset's own (no transform needed).
    grids: [Option<Crs>; 2],
    /// Inverse geotransform: dataset CRS → fractional sample column and row.
    inverse: [f64; 6],
    width: u32,
    height: u32,
    /// `[west, south, east, north]` of the pixel area (each sample standing for
    /// its pixel, as GDAL counts extents) in degrees (WGS 84), as documents state
    /// it: all longitudes where the data crosses the antimeridian (a box whose east is
    /// less than its west is not one every client reads).
    pub lon_lat: [f64; 4],
    /// The pixel area's bounding box in each grid's CRS, [`TileMatrixSet::ALL`] order,
    /// as documents state it (all longitudes where the data crosses the antimeridian).
    grid_bounds: [[f64; 4]; 2],
    /// The same in the data's own longitudes: east past 180° where it crosses the
    /// antimeridian, which tiles from −180 then find one world east (`tile_bounds`).
    data_bounds: [[f64; 4]; 2],
    /// Whether the data is a longitude/latitude grid that crosses the antimeridian.
    wrap: bool,
    /// Metres between samples at the dataset's centre, the finer of x and y.
    spacing_m: f64,
}

impl std::fmt::Debug for Footprint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Footprint")
            .field("crs", &self.crs)
            .field("lon_lat", &self.lon_lat)
            .finish_non_exhaustive()
    }
}

fn index(tms: TileMatrixSet) -> usize {
    TileMatrixSet::ALL
        .iter()
        .position(|t| *t == tms)
        .unwrap_or_default()
}

impl Footprint {
    /// The footprint of a dataset, or why it cannot be placed on a map (no
    /// georeferencing, a CRS the projection library does not know, a degenerate
    /// geotransform).
    pub fn new(m: &Metadata) -> anyhow::Result<Self> {
        let g = m.georef.as_ref().ok_or_else(|| {
            anyhow!("the dataset has no georeferencing, so it has no place on a map")
        })?;
        let crs = Crs::of(g).ok_or_else(|| {
            anyhow!(
                "the dataset's CRS ({}) is not known to the projection library",
                g.crs()
                    .or_else(|| g.crs_name.clone())
                    .unwrap_or_else(|| "unnamed".into())
            )
        })?;
        let gt = g.geotransform;
        let det = gt[1] * gt[5] - gt[2] * gt[4];
        if !(det.is_finite() && det != 0.0) {
            bail!("the dataset's geotransform {gt:?} is degenerate");
        }
        let inverse = [
            gt[5] / det,
            -gt[2] / det,
            -gt[4] / det,
            gt[1] / det,
            gt[0],
            gt[3],
        ];
        let grids = TileMatrixSet::ALL.map(|t| {
            let grid = Crs::from_epsg(t.epsg()).ok()?;
            (grid.proj_string() != crs.proj_string()).then_some(grid)
        });
        let spacing = match m.ground_spacing {
            Some(s) => s,
            None => ground_spacing(g, m.width, m.height)?,
        };
        let mut me = Self {
            crs,
            grids,
            inverse,
            width: m.width,
            height: m.height,
            lon_lat: [0.0; 4],
            grid_bounds: [[0.0; 4]; 2],
            data_bounds: [[0.0; 4]; 2],
            wrap: false,
            spacing_m: spacing.x.min(spacing.y),
        };
        me.lon_lat = me.border_bounds(|x, y| me.crs.to_lon_lat(x, y).ok(), g)?;
        // A longitude/latitude grid's own longitudes, from its geotransform: the
        // projection library folds those past 180° back to −180, which would make a
        // grid crossing the antimeridian look as wide as the world.
        if me.crs.is_geographic() && gt[2] == 0.0 {
            let (a, b) = (gt[0], gt[0] + f64::from(m.width) * gt[1]);
            let turns = ((a.min(b) + 180.0) / 360.0).floor();
            let (w, e) = (a.min(b) - 360.0 * turns, a.max(b) - 360.0 * turns);
            if e > 180.0 && e - w <= 360.0 {
                me.wrap = true;
                me.lon_lat = [w, me.lon_lat[1], e, me.lon_lat[3]];
            }
        }
        let data = me.lon_lat;
        let documents = if me.wrap {
            [-180.0, data[1], 180.0, data[3]]
        } else {
            data
        };
        let merc = Crs::from_epsg(3857)?;
        let world = TileMatrixSet::WebMercatorQuad.extent();
        let in_grid = |tms: TileMatrixSet, [w, s, e, n]: [f64; 4]| -> anyhow::Result<[f64; 4]> {
            Ok(match tms {
                TileMatrixSet::WorldCrs84Quad => [w, s, e, n],
                TileMatrixSet::WebMercatorQuad => {
                    let clamp = |lat: f64| lat.clamp(-MERCATOR_MAX_LAT, MERCATOR_MAX_LAT);
                    let lo = merc.from_lon_lat(w, clamp(s))?;
                    // East of the antimeridian: one world east of its point from −180.
                    let (east, shift) = if e > 180.0 {
                        (e - 360.0, world[2] - world[0])
                    } else {
                        (e, 0.0)
                    };
                    let hi = merc.from_lon_lat(east, clamp(n))?;
                    [lo[0], lo[1], hi[0] + shift, hi[1]]
                }
            })
        };
        for tms in TileMatrixSet::ALL {
            me.grid_bounds[index(tms)] = in_grid(tms, documents)?;
            me.data_bounds[index(tms)] = in_grid(tms, data)?;
        }
        me.lon_lat = documents;
        Ok(me)
    }

    /// The bounding box of the pixel area's border (64 points an edge, since
    /// straight edges bend under most projections) carried by `to`.
    fn border_bounds(
        &self,
        to: impl Fn(f64, f64) -> Option<[f64; 2]>,
        g: &GeoRef,
    ) -> anyhow::Result<[f64; 4]> {
        let (w, h) = (f64::from(self.width), f64::from(self.height));
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        let n = 64;
        for k in 0..=n {
            let t = f64::from(k) / f64::from(n);
            for (c, r) in [(t * w, 0.0), (t * w, h), (0.0, t * h), (w, t * h)] {
                // Sample centres are at +0.5: (c, r) − 0.5 is the pixel corner.
                let [x, y] = g.sample_centre(c - 0.5, r - 0.5);
                let [px, py] = to(x, y).ok_or_else(|| {
                    anyhow!("the dataset's border point ({x}, {y}) does not transform to WGS 84")
                })?;
                b = [b[0].min(px), b[1].min(py), b[2].max(px), b[3].max(py)];
            }
        }
        Ok(b)
    }

    /// The dataset's CRS.
    pub fn crs(&self) -> &Crs {
        &self.crs
    }

    /// A point of `tms`'s CRS as fractional finest-level sample coordinates
    /// (column, row of sample centres), or `None` where it does not transform.
    pub fn to_samples(&self, tms: TileMatrixSet, x: f64, y: f64) -> Option<[f64; 2]> {
        let [dx, dy] = match &self.grids[index(tms)] {
            Some(grid) => grid.transform_to(&self.crs, x, y).ok()?,
            None => [x, y],
        };
        self.dataset_to_samples(dx, dy)
    }

    /// Many WGS 84 `[lon, lat]` as [`Footprint::to_samples`] carries them (one
    /// PROJ call for all); `None` for those that do not transform.
    pub fn lon_lat_to_samples(&self, lon_lat: &[[f64; 2]]) -> Vec<Option<[f64; 2]>> {
        let tms = TileMatrixSet::WorldCrs84Quad;
        let mut points: Vec<[f64; 3]> = lon_lat.iter().map(|&[x, y]| [x, y, 0.0]).collect();
        if let Some(grid) = &self.grids[index(tms)] {
            // Points PROJ cannot carry come back NaN; the rest are done.
            let _ = grid.transform_points(&self.crs, &mut points);
        }
        points
            .iter()
            .map(|&[x, y, _]| self.dataset_to_samples(x, y))
            .collect()
    }

    /// Metres between samples at the dataset's centre, the finer of x and y.
    pub fn spacing_m(&self) -> f64 {
        self.spacing_m
    }

    /// A point of the dataset's CRS as fractional sample coordinates.
    fn dataset_to_samples(&self, dx: f64, dy: f64) -> Option<[f64; 2]> {
        // A grid across the antimeridian: longitudes into its own range.
        let dx = if self.wrap {
            let west = self.data_bounds[index(TileMatrixSet::WorldCrs84Quad)][0];
            dx - 360.0 * ((dx - west) / 360.0).floor()
        } else {
            dx
        };
        let [a, b, c, d, x0, y0] = self.inverse;
        let (ex, ey) = (dx - x0, dy - y0);
        let p = [a * ex + b * ey - 0.5, c * ex + d * ey - 0.5];
        (p[0].is_finite() && p[1].is_finite()).then_some(p)
    }

    /// The pixel area's bounding box in `tms`'s CRS.
    pub fn grid_bounds(&self, tms: TileMatrixSet) -> [f64; 4] {
        self.grid_bounds[index(tms)]
    }

    /// The data's bounding box in `tms`'s CRS, in its own longitudes (east past
    /// the antimeridian where it crosses it: see [`Footprint::tile_bounds`]).
    pub fn data_bounds(&self, tms: TileMatrixSet) -> [f64; 4] {
        self.data_bounds[index(tms)]
    }

    /// A tile's bounds in the frame of [`Footprint::data_bounds`]: as they are, or
    /// one world east for a tile west of the data that the data reaches across the
    /// antimeridian (whichever frame holds more of the data).
    pub fn tile_bounds(&self, tile: WebTile) -> [f64; 4] {
        let b = tile.bounds();
        if !self.wrap {
            return b;
        }
        let [ex0, _, ex1, _] = tile.tms.extent();
        let world = ex1 - ex0;
        let [dx0, _, dx1, _] = self.data_bounds(tile.tms);
        let overlap = |a: f64, c: f64| (c.min(dx1) - a.max(dx0)).max(0.0);
        if overlap(b[0] + world, b[2] + world) > overlap(b[0], b[2]) {
            [b[0] + world, b[1], b[2] + world, b[3]]
        } else {
            b
        }
    }

    /// Whether a tile's bounds meet the dataset's bounding box (a tile that does
    /// may still hold no sample: the box is wider than a slanted footprint).
    pub fn meets(&self, tile: WebTile) -> bool {
        let [x0, y0, x1, y1] = self.tile_bounds(tile);
        let [bx0, by0, bx1, by1] = self.data_bounds(tile.tms);
        x0 <= bx1 && bx0 <= x1 && y0 <= by1 && by0 <= y1
    }

    /// The deepest zoom worth serving: the first whose pixels, at the dataset's
    /// centre, are at most half the dataset's finer sample spacing on the ground.
    /// Every sample's own pixel area then covers at least 2 × 2 tile pixels, so a
    /// map reproduces every sample, and a client's bilinear lookup at a valid sample
    /// beside a void reads only that sample's pixels (MapLibre ignores alpha in
    /// elevation tiles: a transparent no-data pixel would read as −32768 m). Deeper
    /// zooms only magnify; clients over-zoom past this by themselves.
    pub fn max_zoom(&self, tms: TileMatrixSet, px: u32) -> u8 {
        let Some(z0) = self.pixel_metres_at_zoom0(tms, px) else {
            return 0;
        };
        let z = (z0 / (self.spacing_m / 2.0)).log2().ceil();
        if z.is_finite() {
            z.clamp(0.0, f64::from(MAX_ZOOM)) as u8
        } else {
            0
        }
    }

    /// The deepest zoom at which the whole dataset fits in one tile (where a map
    /// showing all of it should start).
    pub fn overview_zoom(&self, tms: TileMatrixSet) -> u8 {
        let [x0, y0, x1, y1] = self.grid_bounds(tms);
        let span = (x1 - x0).max(y1 - y0);
        let z = (tms.tile_span(0) / span).log2().floor();
        if z.is_finite() {
            z.clamp(0.0, f64::from(MAX_ZOOM)) as u8
        } else {
            0
        }
    }

    /// `[lon, lat]` of the centre of the dataset's WGS 84 bounds (in −180..180).
    pub fn centre(&self) -> [f64; 2] {
        let [w, s, e, n] = self.data_bounds(TileMatrixSet::WorldCrs84Quad);
        let lon = f64::midpoint(w, e);
        [
            if lon > 180.0 { lon - 360.0 } else { lon },
            f64::midpoint(s, n),
        ]
    }

    /// Metres on the ground of one zoom-0 pixel of `tms` at the dataset's centre,
    /// measured by the projection library (crs.rs `ground_spacing`).
    fn pixel_metres_at_zoom0(&self, tms: TileMatrixSet, px: u32) -> Option<f64> {
        let [lon, lat] = self.centre();
        let grid = Crs::from_epsg(tms.epsg()).ok()?;
        let [cx, cy] = grid
            .from_lon_lat(lon, lat.clamp(-MERCATOR_MAX_LAT, MERCATOR_MAX_LAT))
            .ok()?;
        // Measure a small cell (the projection is linear at that scale), then scale.
        let c = tms.cell_size(0, px);
        let small = c / 1024.0;
        let g = GeoRef {
            epsg: Some(tms.epsg()),
            crs_name: None,
            proj: None,
            wkt: None,
            geotransform: [cx - small / 2.0, small, 0.0, cy + small / 2.0, 0.0, -small],
            raster_type: RasterType::PixelIsArea,
        };
        let s = ground_spacing(&g, 1, 1).ok()?;
        Some((s.x * s.y).sqrt() * 1024.0)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use tessera_shared::{GroundSpacing, Quantization, VerticalDatum};

    /// A dataset's metadata with only its grid and CRS filled in (the other tests of
    /// web/ use it too).
    pub(crate) fn metadata(epsg: u32, gt: [f64; 6], width: u32, height: u32) -> Metadata {
        Metadata {
            width,
            height,
            tile_size: 64,
            levels: 1,
            quantization: Quantization {
                offset: 0.0,
                scale: 1.0,
                max_error: 0.0,
            },
            min_height: 0.0,
            max_height: 1.0,
            nodata_count: 0,
            nodata_fill: String::new(),
            georef: Some(GeoRef {
                epsg: Some(epsg),
                crs_name: None,
                proj: None,
                wkt: None,
                geotransform: gt,
                raster_type: RasterType::PixelIsArea,
            }),
            ground_spacing: None::<GroundSpacing>,
            vertical_datum: VerticalDatum::Unknown,
            level_counts: vec![],
            source: String::new(),
            generator: String::new(),
            content_hash: String::new(),
            sources: Vec::new(),
        }
    }

    /// N46E008's own grid: 3″ samples, the first centred on (8° E, 47° N).
    fn n46e008() -> Metadata {
        let d = 1.0 / 1200.0;
        metadata(
            4326,
            [8.0 - d / 2.0, d, 0.0, 47.0 + d / 2.0, 0.0, -d],
            1201,
            1201,
        )
    }

    #[test]
    fn a_geographic_dataset_maps_grid_points_to_its_samples() {
        let f = Footprint::new(&n46e008()).unwrap();
        let [w, s, e, n] = f.lon_lat;
        // Sample centres run from 8° to 9°; their pixels reach half a sample beyond.
        let half = 1.0 / 2400.0;
        assert!(
            (w - (8.0 - half)).abs() < 1e-9 && (e - (9.0 + half)).abs() < 1e-9,
            "{:?}",
            f.lon_lat
        );
        assert!((s - (46.0 - half)).abs() < 1e-9 && (n - (47.0 + half)).abs() < 1e-9);
        // A sample centre in CRS84 is that sample exactly (the same CRS: no transform).
        let p = f
            .to_samples(TileMatrixSet::WorldCrs84Quad, 8.5, 46.75)
            .unwrap();
        assert!(
            (p[0] - 600.0).abs() < 1e-6 && (p[1] - 300.0).abs() < 1e-6,
            "{p:?}"
        );
        // Through Web Mercator and back, through the projection library.
        let merc = Crs::from_epsg(3857).unwrap();
        let [x, y] = merc.from_lon_lat(8.5, 46.75).unwrap();
        let q = f.to_samples(TileMatrixSet::WebMercatorQuad, x, y).unwrap();
        assert!(
            (q[0] - 600.0).abs() < 1e-6 && (q[1] - 300.0).abs() < 1e-6,
            "{q:?}"
        );
    }

    #[test]
    fn zooms_follow_the_ground_resolution() {
        let f = Footprint::new(&n46e008()).unwrap();
        // 3″ at 46.5° N: 63.8 m east–west × 92.6 m; half the finer is 31.9 m. A
        // 512-px Web Mercator pixel there is 52.6 m at z 10 and 26.3 m at z 11:
        // z 11 is the first at most half a sample; at 256 px, z 12.
        assert_eq!(f.max_zoom(TileMatrixSet::WebMercatorQuad, 512), 11);
        assert_eq!(f.max_zoom(TileMatrixSet::WebMercatorQuad, 256), 12);
        // One degree of longitude by 46–47° N (1.45° of Mercator northing) fits
        // one tile at z 7 (2.8° wide), not at z 8 (1.4°).
        assert_eq!(f.overview_zoom(TileMatrixSet::WebMercatorQuad), 7);
        assert_eq!(f.overview_zoom(TileMatrixSet::WorldCrs84Quad), 7);
    }

    #[test]
    fn a_projected_dataset_lands_where_it_is() {
        // aletsch.tif's grid: EPSG:2056 (Swiss LV95), 200 m, corner (2601100, 1184500).
        let m = metadata(
            2056,
            [2_601_100.0, 200.0, 0.0, 1_184_500.0, 0.0, -200.0],
            358,
            310,
        );
        let f = Footprint::new(&m).unwrap();
        let [w, s, e, n] = f.lon_lat;
        // Bern to the Aletsch glacier: gdalinfo's wgs84Extent (PROJ) is 7.4529–8.3911° E,
        // 46.2500–46.8117° N; proj4rs agrees to 1e-4° (8 m).
        let near = |a: f64, b: f64| (a - b).abs() < 1e-4;
        assert!(
            near(w, 7.4529) && near(e, 8.3911) && near(s, 46.2500) && near(n, 46.8117),
            "{:?}",
            f.lon_lat
        );
        let t = WebTile::new(TileMatrixSet::WebMercatorQuad, 9, 267, 181).unwrap();
        assert!(f.meets(t), "{:?} vs {:?}", t.bounds(), f.grid_bounds(t.tms));
        assert!(!f.meets(WebTile::new(TileMatrixSet::WebMercatorQuad, 9, 0, 0).unwrap()));
    }

    #[test]
    fn a_dataset_without_georeferencing_is_refused_with_a_reason() {
        let mut m = n46e008();
        m.georef = None;
        let e = Footprint::new(&m).unwrap_err().to_string();
        assert!(e.contains("no georeferencing"), "{e}");
    }
}
