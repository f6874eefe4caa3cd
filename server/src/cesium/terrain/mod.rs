//! One dataset as Cesium terrain (DECISIONS.md "Cesium terrain"): which pyramid level and
//! threshold each zoom meshes with, and one tile's mesh — the level's RTIN
//! ([`super::mesh`]) cut to the tile, the rest of the tile filled down to sea level.
//!
//! **The bound.** CesiumJS refines assuming zoom `z` is within
//! `ε_z = ε_0 / 2^z` of the truth ([`super::tiling::level_zero_error`]). A tile's
//! heights at the finest samples are off by at most
//!
//! `V (≤ τ, the RTIN against level L)` + `e_L (the error tables: level L against
//! the finest)` + `q (height quantization, half a step of the largest possible
//! tile range)` + `p (vertex positions quantized to 1/32767 of the tile)`.
//!
//! `p` is at most `√2 · slope · span / 65534`; `ε_z` is 252 of those steps of height
//! on a 1:1 slope (Earth or Moon alike, since both scale with the radius), so 5 % of
//! `ε_z` covers slopes up to 83°. Hence `τ = 0.95 ε_z − e_L − q`. Level `L` is the
//! coarsest whose `e_L` plus its largest leaf twist (see [`super::mesh`]) is at most
//! `ε_z / 2`, from the error tables, so coarse zooms read coarse levels.
//!
//! **Shared edges.** Level, square size and `τ` depend on the zoom only; vertex
//! errors near a line depend on the samples around it; clip points are computed from
//! the full original edge with its endpoints in a fixed order; tile edges are
//! `−180 + x·span`. So neighbours compute bit-identical edge points.
//!
//! **Outside the data** (a tile the DEM covers only in part), the tile is filled
//! by a constrained Delaunay triangulation ([`spade`]) between the data's boundary
//! and the tile's corners, at sea level (the geoid, or the body's sphere): every
//! tile covers its rectangle, and the fill never touches a DEM sample.
//!
//! Modules: [`mapping`] (where the finest samples are on the body), [`plan`] (the
//! level and threshold of each zoom), [`tile`] (one tile's mesh), [`clip`] (its
//! triangles clipped to the tile and the data), [`tile_builder`] (its vertices and
//! triangles collected, the rest of the tile filled), [`pyramid`] (a pyramid read
//! directly, for tests and tools), [`availability`] (which tiles hold data),
//! [`water`] (a tile's water mask).

pub mod availability;
pub mod clip;
pub mod lean;
pub mod mapping;
pub mod plan;
pub mod pyramid;
pub mod tile;
pub mod tile_builder;
pub mod water;

pub use plan::ZoomPlan;
pub use pyramid::{PyramidLevels, TileReadError};

use crate::cesium::tiling::{CesiumTile, MAX_ZOOM, geometric_error, level_zero_error};
use crate::crs::Crs;
use crate::geoid::Geoid;
use crate::web::resample::SourceTile;
use mapping::{Mapping, invert};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use tessera_shared::ellipsoid::Ellipsoid;
use tessera_shared::tile::GeometryError;
use tessera_shared::{Level, Metadata, Quantization, TileGeometry, TileId, VerticalDatum};

/// What a tile needs from the pyramid: decoded tiles, and the largest
/// full-resolution error of a level's tiles (error tables).
pub trait LevelData {
    type Error;
    /// The decoded level tile (`(T+1)²` quantized heights, north row first); `None`
    /// when the pyramid has no such tile.
    fn tile(&self, tile: TileId) -> Result<Option<Arc<SourceTile>>, Self::Error>;
    /// The largest full-resolution error (metres) of any tile of `level`.
    fn level_error(&self, level: Level) -> Result<f64, Self::Error>;
    /// `Err` when the work should stop (its requester is gone: serve/compute/);
    /// called between rows of squares.
    fn check(&self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// One dataset as terrain: what `layer.json` says and how tiles are meshed.
#[derive(Debug)]
pub struct Terrain {
    geometry: TileGeometry,
    quantization: Quantization,
    mapping: Mapping,
    pub ellipsoid: Ellipsoid,
    pub level_zero_error: f64,
    geoid: Option<Arc<Geoid>>,
    /// Said in `layer.json` when heights could not be put on the ellipsoid.
    pub datum_warning: Option<String>,
    /// `[west, south, east, north]` of the finest samples' centres (the data region's
    /// bounding box; exact for a geographic grid).
    pub bounds: [f64; 4],
    pub max_zoom: u8,
    /// Degrees between finest samples at the data's centre (the smaller axis).
    spacing_deg: f64,
    /// Half a height step of the widest tile range possible.
    quantization_margin: f64,
    /// Per level: `e_L` from the tables and the largest leaf twist, once known.
    level_bounds: Mutex<HashMap<u8, (f64, Option<f64>)>>,
}

/// Why a dataset cannot be terrain. Cloned: the server keeps it beside the terrain
/// plans it caches, and says it on every request.
#[derive(Debug, Clone, thiserror::Error)]
pub enum TerrainError {
    #[error("bad tile geometry: {0:?}")]
    Geometry(GeometryError),
    #[error(
        "it has no georeferencing (build it from a georeferenced input, or with --crs and --bounds)"
    )]
    NoGeoref,
    #[error("its CRS is not one the projection library knows")]
    UnknownCrs,
    #[error("its CRS names no ellipsoid")]
    NoEllipsoid,
    #[error("its CRS has no usable ellipsoid")]
    UnusableEllipsoid,
    #[error("its geotransform is singular")]
    SingularGeotransform,
    /// The longitude–latitude CRS of its body could not be made.
    #[error("{0:#}")]
    BodyCrs(Arc<anyhow::Error>),
    #[error("its corners do not transform to longitude and latitude")]
    CornersDoNotTransform,
    /// `[west, south, east, north]` of its corners.
    #[error(
        "it spans longitudes {:.6}..{:.6} and latitudes {:.6}..{:.6}, outside −180..180 × −90..90 (a grid in longitude and latitude may cross the antimeridian; a projected one may not)",
        .0[0], .0[2], .0[1], .0[3]
    )]
    OutsideLonLat([f64; 4]),
    #[error("its centre does not transform")]
    CentreDoesNotTransform,
}

impl Terrain {
    /// The terrain of a dataset, with `geoid` for EGM96 heights (when given).
    pub fn new(m: &Metadata, geoid: Option<Arc<Geoid>>) -> Result<Self, TerrainError> {
        let geometry =
            TileGeometry::new(m.width, m.height, m.tile_size).map_err(TerrainError::Geometry)?;
        let georef = m.georef.as_ref().ok_or(TerrainError::NoGeoref)?;
        let crs = Crs::of(georef).ok_or(TerrainError::UnknownCrs)?;
        let (a, b) = crs.body_radii().ok_or(TerrainError::NoEllipsoid)?;
        let ellipsoid = Ellipsoid::new(a, b).ok_or(TerrainError::UnusableEllipsoid)?;
        // Earth datasets go to WGS 84 longitude and latitude, what Cesium's globe is;
        // other bodies to their own ellipsoid's.
        let earth = (a - Ellipsoid::WGS84.equatorial_radius()).abs() < 1000.0;
        let ellipsoid = if earth { Ellipsoid::WGS84 } else { ellipsoid };
        let gt = georef.geotransform;
        let plain_lon_lat = crs.is_geographic() && (!earth || crs.epsg() == Some(4326));
        let mapping = if plain_lon_lat && gt[2] == 0.0 && gt[4] == 0.0 {
            let lon0 = gt[0] + 0.5 * gt[1];
            // Longitudes as the data's west edge has them in −180..180: a grid
            // stated from 0 to 360, or past 180, keeps its samples, and those east of
            // 180 are found by tiles at −180 + their longitude (see `frame_rect`).
            let west = lon0.min(lon0 + f64::from(m.width - 1) * gt[1]);
            let turns = ((west + 180.0) / 360.0).floor();
            Mapping::Affine {
                lon0: lon0 - 360.0 * turns,
                dlon: gt[1],
                lat0: gt[3] + 0.5 * gt[5],
                dlat: gt[5],
            }
        } else {
            let inverse = invert(&gt).ok_or(TerrainError::SingularGeotransform)?;
            let body = if earth {
                Crs::from_epsg(4326)
            } else {
                Crs::from_proj_string(&format!("+proj=longlat +a={a} +b={b} +no_defs"))
            }
            .map_err(|e| TerrainError::BodyCrs(Arc::new(e)))?;
            Mapping::Projected {
                crs: Box::new(crs),
                body: Box::new(body),
                gt,
                inverse,
            }
        };
        let (wm, hm) = (f64::from(m.width - 1), f64::from(m.height - 1));
        let mut bounds = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for k in 0..=16 {
            let t = f64::from(k) / 16.0;
            for (c, r) in [(t * wm, 0.0), (t * wm, hm), (0.0, t * hm), (wm, t * hm)] {
                let [lon, lat] = mapping
                    .lon_lat(c, r)
                    .ok_or(TerrainError::CornersDoNotTransform)?;
                bounds = [
                    bounds[0].min(lon),
                    bounds[1].min(lat),
                    bounds[2].max(lon),
                    bounds[3].max(lat),
                ];
            }
        }
        // A geographic grid may cross the antimeridian (west in −180..180, east up to
        // 360° further); any other must lie in −180..180 as its corners transform.
        let lon_ok = match mapping {
            Mapping::Affine { .. } => {
                bounds[0] >= -180.0 && bounds[0] < 180.0 && bounds[2] - bounds[0] <= 360.0
            }
            Mapping::Projected { .. } => bounds[0] >= -180.0 && bounds[2] <= 180.0,
        };
        if !(lon_ok && bounds[1] >= -90.0 && bounds[3] <= 90.0) {
            return Err(TerrainError::OutsideLonLat(bounds));
        }
        let (geoid, datum_warning) = match (m.vertical_datum, geoid) {
            (VerticalDatum::Ellipsoid, _) => (None, None),
            (VerticalDatum::Egm96, Some(g)) => (Some(g), None),
            (VerticalDatum::Egm96, None) => (
                None,
                Some("heights are above the EGM96 geoid and no geoid grid was found (--geoid): served as-is, up to ~100 m off the ellipsoid".to_string()),
            ),
            (VerticalDatum::Egm2008, _) => (
                None,
                Some("heights are above the EGM2008 geoid, which this server does not apply: served as-is, up to ~100 m off the ellipsoid".to_string()),
            ),
            (VerticalDatum::Unknown, _) => (
                None,
                Some("the dataset's vertical datum is unknown: heights are served as-is, as if above the ellipsoid".to_string()),
            ),
        };
        // The widest tile range: the data's, the geoid's whole range (−107..+86 m) and
        // sea level for the fill.
        let geoid_range = if geoid.is_some() { 200.0 } else { 0.0 };
        let range = m.max_height.max(0.0) - m.min_height.min(0.0) + geoid_range;
        let level_zero_error = level_zero_error(ellipsoid.maximum_radius());
        // The deepest zoom: tiles of at most 4 finest samples, where the mesh is the
        // data; and no deeper than the quantization leaves half the error to the mesh.
        let spacing = mapping
            .spacing_at(wm / 2.0, hm / 2.0)
            .ok_or(TerrainError::CentreDoesNotTransform)?;
        let mut max_zoom = 0;
        while max_zoom < MAX_ZOOM
            && CesiumTile::span(max_zoom) > 4.0 * spacing
            && 0.45 * geometric_error(level_zero_error, max_zoom + 1) >= range / 65534.0
        {
            max_zoom += 1;
        }
        Ok(Self {
            geometry,
            quantization: m.quantization,
            mapping,
            ellipsoid,
            level_zero_error,
            geoid,
            datum_warning,
            bounds,
            max_zoom,
            spacing_deg: spacing,
            quantization_margin: range / 65534.0,
            level_bounds: Mutex::new(HashMap::new()),
        })
    }

    /// The tiles of zoom `z` over the data's bounds: `[x0, y0, x1, y1]` inclusive,
    /// the part west of the antimeridian where the data crosses it
    /// ([`Terrain::available_ranges`] has both parts).
    pub fn available(&self, z: u8) -> Option<[u32; 4]> {
        self.available_ranges(z).into_iter().next()
    }

    /// The tiles of zoom `z` over the data's bounds: one range, or two where the
    /// data crosses the antimeridian (east of it, the tiles from −180).
    pub fn available_ranges(&self, z: u8) -> Vec<[u32; 4]> {
        if z > self.max_zoom {
            return Vec::new();
        }
        let [w, s, e, n] = self.bounds;
        let mut out: Vec<[u32; 4]> = CesiumTile::covering(z, self.bounds).into_iter().collect();
        if e > 180.0 {
            out.extend(CesiumTile::covering(z, [w - 360.0, s, e - 360.0, n]));
        }
        out
    }

    /// Whether `tile` is over the data's bounds.
    pub fn is_available(&self, tile: CesiumTile) -> bool {
        self.available_ranges(tile.z)
            .into_iter()
            .any(|[x0, y0, x1, y1]| (x0..=x1).contains(&tile.x) && (y0..=y1).contains(&tile.y))
    }

    /// `tile`'s rectangle in the data's longitudes: as it is, or 360° east where the
    /// data crosses the antimeridian and the tile is east of it (so every
    /// computation of the tile is in the frame its samples are in; `−180 + 360` is
    /// exactly `180`, so the two tiles at the antimeridian still share their edge).
    /// A tile meeting the data in both frames (a dataset wider than a tile that
    /// crosses it, at zooms 0–1) is meshed in the frame holding more of it.
    pub fn frame_rect(&self, tile: CesiumTile) -> [f64; 4] {
        let r = tile.rect();
        let [w, _, e, _] = self.bounds;
        if e <= 180.0 {
            return r;
        }
        let overlap = |a: f64, b: f64| (b.min(e) - a.max(w)).max(0.0);
        if overlap(r[0] + 360.0, r[2] + 360.0) > overlap(r[0], r[2]) {
            [r[0] + 360.0, r[1], r[2] + 360.0, r[3]]
        } else {
            r
        }
    }

    /// Degrees between a level's samples (the smaller axis, at the centre).
    fn level_spacing_deg(&self, level: Level) -> f64 {
        // Locally linear: a level's spacing is its stride times the finest's.
        self.spacing_deg * self.geometry.spacing(level) as f64
    }

    /// Sea level at a point: the geoid's undulation above the ellipsoid, or 0.
    fn sea_level(&self, lon: f64, lat: f64) -> f64 {
        self.geoid.as_ref().map_or(0.0, |g| g.undulation(lon, lat))
    }
    /// Whether a longitude/latitude is inside the DEM's finest samples.
    fn inside_data(&self, lon: f64, lat: f64) -> bool {
        self.mapping.to_samples(lon, lat).is_some_and(|[c, r]| {
            c >= 0.0
                && r >= 0.0
                && c <= f64::from(self.geometry.width() - 1)
                && r <= f64::from(self.geometry.height() - 1)
        })
    }
}
