//! The globe (DECISIONS.md "The globe"): a geographic dataset (longitude/latitude grid on
//! a known body, [`tessera_shared::body::Body`]) drawn on its ellipsoid instead of as a
//! flat sheet.
//!
//! Poses stay on the map: the camera's world position `(x, y, z)` is read as finest
//! grid `(x/sx, z/sy)`, height `y` above the ellipsoid, and its yaw and pitch are
//! relative to the local east–up–south frame at the eye ([`frame`]). Vertex positions
//! are made in one place, `relative()` in `terrain.wgsl`, from per-row and per-column
//! tables that are relative to the eye ([`tables`]), so that they are exact near the
//! eye and depend only on a vertex's global integers and height. Selection measures
//! distances to, and culls, bounding spheres of the curved tiles ([`volume`]) and
//! drops tiles behind the limb ([`horizon`]).

#[cfg(test)]
pub(crate) mod fixtures;
pub mod frame;
pub mod grid;
pub mod horizon;
pub mod tables;
pub mod volume;

use glam::{DVec2, DVec3};
use grid::LonLatGrid;
use tessera_shared::api::DatasetInfo;
use tessera_shared::ellipsoid::Ellipsoid;

/// Whether to draw on the globe (`tessera fly --globe`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum GlobeMode {
    /// The globe for a geographic dataset on a known body, flat otherwise
    /// (projected datasets are regional: DECISIONS.md).
    Auto,
    /// The globe; an error for a dataset that is not geographic on a known body.
    On,
    /// Always flat.
    #[default]
    Off,
}

/// A geographic dataset on its body.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Globe {
    pub ellipsoid: Ellipsoid,
    pub grid: LonLatGrid,
    /// The flat world's metres per finest sample (x east–west, y north–south):
    /// how map poses `(x, z)` are read back as grid coordinates.
    pub spacing: DVec2,
    /// The lowest height of the dataset, metres (for the horizon's occluder).
    pub min_height: f64,
}

/// `--globe on` for a dataset that is not a longitude/latitude grid on a known body.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error(
    "--globe on: dataset {name:?} is not a longitude/latitude grid on a known body (its CRS: {crs})"
)]
pub struct NotAGlobe {
    pub name: String,
    pub crs: String,
}

impl Globe {
    /// The globe of a dataset document, `None` when it is not geographic on a known
    /// body or its geotransform is rotated.
    pub fn of(info: &DatasetInfo, spacing: DVec2) -> Option<Self> {
        let body = info.body?;
        if !body.geographic {
            return None;
        }
        Some(Self {
            ellipsoid: Ellipsoid::new(body.semi_major, body.semi_minor)?,
            grid: LonLatGrid::from_georef(info.georef.as_ref()?)?,
            spacing,
            min_height: info.min_height,
        })
    }

    /// What `mode` asks for on this dataset: `Ok(None)` flat; an error when `mode`
    /// is [`GlobeMode::On`] and the dataset cannot be drawn on the globe.
    pub fn choose(
        mode: GlobeMode,
        info: &DatasetInfo,
        spacing: DVec2,
    ) -> Result<Option<Self>, NotAGlobe> {
        match mode {
            GlobeMode::Off => Ok(None),
            GlobeMode::Auto => Ok(Self::of(info, spacing)),
            GlobeMode::On => Self::of(info, spacing).map(Some).ok_or_else(|| NotAGlobe {
                name: info.name.clone(),
                crs: info.crs.clone().unwrap_or_else(|| "none".into()),
            }),
        }
    }

    /// ECEF (metres, f64) of finest-grid point `(x, y)` at height `h`: the exact
    /// position `relative()` approximates.
    pub fn ecef(&self, x: f64, y: f64, h: f64) -> DVec3 {
        let (lon, lat) = self.grid.lon_lat(x, y);
        self.ellipsoid.to_ecef(lon, lat, h)
    }

    /// ECEF of a flat-world point `(x, h, z)` (a map pose, a box corner).
    pub fn ecef_of_world(&self, p: DVec3) -> DVec3 {
        self.ecef(p.x / self.spacing.x, p.z / self.spacing.y, p.y)
    }

    /// Radius of a sphere inside the body under every point of the dataset: the
    /// polar semi-axis lowered by the deepest height below the ellipsoid.
    pub fn occluder_radius(&self) -> f64 {
        self.ellipsoid.polar_radius() + self.min_height.min(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::{GeoRef, RasterType};

    fn info(proj: &str, epsg: Option<u32>) -> DatasetInfo {
        let mut meta = tessera_shared::fixtures::metadata(4097, 4097, 256);
        meta.georef = Some(GeoRef {
            epsg,
            crs_name: None,
            proj: Some(proj.into()),
            wkt: None,
            geotransform: [51.0, 1.0 / 256.0, 0.0, 25.0, 0.0, -1.0 / 256.0],
            raster_type: RasterType::PixelIsArea,
        });
        DatasetInfo::new("d", &meta, 2, 0)
    }

    #[test]
    fn auto_is_the_globe_for_geographic_grids_only_and_on_says_why_not() {
        let s = DVec2::splat(100.0);
        let moon = info("+proj=longlat +R=1737400 +no_defs", None);
        let g = Globe::choose(GlobeMode::Auto, &moon, s).unwrap().unwrap();
        assert_eq!(
            (g.ellipsoid.equatorial_radius(), g.ellipsoid.polar_radius()),
            (1_737_400.0, 1_737_400.0)
        );
        // Sample (0, 0)'s centre is half a sample in from the corner.
        let (lon, lat) = g.grid.lon_lat(0.0, 0.0);
        assert!((lon.to_degrees() - (51.0 + 0.5 / 256.0)).abs() < 1e-12);
        assert!((lat.to_degrees() - (25.0 - 0.5 / 256.0)).abs() < 1e-12);
        assert_eq!(Globe::choose(GlobeMode::Off, &moon, s).unwrap(), None);
        let utm = info(
            "+proj=utm +zone=11 +datum=WGS84 +units=m +no_defs",
            Some(32611),
        );
        assert_eq!(Globe::choose(GlobeMode::Auto, &utm, s).unwrap(), None);
        let e = Globe::choose(GlobeMode::On, &utm, s)
            .unwrap_err()
            .to_string();
        assert!(e.contains("--globe on") && e.contains("EPSG:32611"), "{e}");
    }
}
