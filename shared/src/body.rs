//! The body a dataset lies on (DECISIONS.md "The globe"): its ellipsoid's semi-axes and
//! whether the grid is geographic (longitude/latitude degrees, affine in the grid
//! indices), which is what a client needs to draw the dataset on the globe.
//!
//! The server fills [`Body`] from its projection library (`Crs::body_radii`). A
//! client that reads a pyramid file itself (serverless) has no projection library,
//! so [`Body::from_georef`] derives the same from what the file says: the EPSG
//! codes of the WGS 84 family, a PROJ string's `+R=`/`+a=`/`+b=`/`+rf=`/`+ellps=`/
//! `+datum=`, or a WKT `ELLIPSOID[...]`/`SPHEROID[...]`. Anything else is `None`
//! (the client then draws the dataset flat).
//!
//! ```
//! use tessera_shared::body::Body;
//! use tessera_shared::{GeoRef, RasterType};
//!
//! let moon = GeoRef {
//!     epsg: None,
//!     crs_name: None,
//!     proj: Some("+proj=longlat +R=1737400 +no_defs".into()),
//!     wkt: None,
//!     geotransform: [51.0, 1.0 / 256.0, 0.0, 25.0, 0.0, -1.0 / 256.0],
//!     raster_type: RasterType::PixelIsArea,
//! };
//! let b = Body::from_georef(&moon).unwrap();
//! assert_eq!((b.semi_major, b.semi_minor, b.geographic), (1_737_400.0, 1_737_400.0, true));
//! ```

use crate::GeoRef;
use serde::{Deserialize, Serialize};

/// WGS 84's semi-major axis (m) and inverse flattening (EPSG:7030).
pub const WGS84_A: f64 = 6_378_137.0;
pub const WGS84_RF: f64 = 298.257_223_563;
/// GRS 80 (EPSG:7019): NAD83, ETRS89.
const GRS80_RF: f64 = 298.257_222_101;

/// An ellipsoid of revolution (or a sphere) and how the grid sits on it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Body {
    /// Equatorial semi-axis `a`, metres.
    pub semi_major: f64,
    /// Polar semi-axis `b ≤ a`, metres (`= a` for a sphere).
    pub semi_minor: f64,
    /// Whether the grid's coordinates are longitude/latitude in degrees (the
    /// geotransform maps grid indices to them); false for a projected CRS.
    pub geographic: bool,
}

impl Body {
    /// A body of semi-axes `a ≥ b > 0`, finite; `None` otherwise.
    pub fn new(semi_major: f64, semi_minor: f64, geographic: bool) -> Option<Self> {
        (semi_major.is_finite() && semi_minor.is_finite() && semi_minor > 0.0)
            .then_some(())
            .filter(|()| semi_minor <= semi_major)
            .map(|()| Self {
                semi_major,
                semi_minor,
                geographic,
            })
    }

    /// WGS 84's ellipsoid.
    pub fn wgs84(geographic: bool) -> Self {
        Self {
            semi_major: WGS84_A,
            semi_minor: WGS84_A * (1.0 - 1.0 / WGS84_RF),
            geographic,
        }
    }

    /// The body a GeoRef's CRS names, without a projection library (see the module
    /// documentation for what is understood).
    pub fn from_georef(georef: &GeoRef) -> Option<Self> {
        let proj = georef.proj.as_deref();
        let geographic = match (proj, georef.epsg) {
            (Some(p), _) => p.contains("+proj=longlat") || p.contains("+proj=latlong"),
            (None, Some(code)) => GEOGRAPHIC_WGS84.contains(&code),
            (None, None) => georef
                .wkt
                .as_deref()
                .is_some_and(|w| w.trim_start().starts_with("GEOGCS")),
        };
        if let Some(b) = proj.and_then(|p| from_proj(p, geographic)) {
            return Some(b);
        }
        if let Some(code) = georef.epsg
            && (GEOGRAPHIC_WGS84.contains(&code) || (32601..=32760).contains(&code))
        {
            return Some(Self::wgs84(geographic));
        }
        georef.wkt.as_deref().and_then(|w| from_wkt(w, geographic))
    }
}

/// EPSG codes of WGS 84 longitude/latitude (2-D, 3-D).
const GEOGRAPHIC_WGS84: [u32; 2] = [4326, 4979];

/// `+key=value` of a PROJ string.
fn proj_param<'a>(p: &'a str, key: &str) -> Option<&'a str> {
    p.split_whitespace()
        .find_map(|t| t.strip_prefix('+')?.strip_prefix(key)?.strip_prefix('='))
}

fn from_proj(p: &str, geographic: bool) -> Option<Body> {
    let num = |k| proj_param(p, k).and_then(|v| v.parse::<f64>().ok());
    if let Some(r) = num("R") {
        return Body::new(r, r, geographic);
    }
    if let Some(a) = num("a") {
        let b = num("b").or_else(|| num("rf").map(|rf| a * (1.0 - 1.0 / rf)));
        return Body::new(a, b.unwrap_or(a), geographic);
    }
    let rf = match (proj_param(p, "ellps"), proj_param(p, "datum")) {
        (Some("WGS84"), _) | (None, Some("WGS84")) => WGS84_RF,
        (Some("GRS80"), _) | (None, Some("NAD83")) => GRS80_RF,
        _ => return None,
    };
    Body::new(WGS84_A, WGS84_A * (1.0 - 1.0 / rf), geographic)
}

/// The first `ELLIPSOID["name",a,rf` or `SPHEROID["name",a,rf` of a WKT (`rf = 0`:
/// a sphere, as WKT writes it).
fn from_wkt(w: &str, geographic: bool) -> Option<Body> {
    let start = w.find("ELLIPSOID[").or_else(|| w.find("SPHEROID["))?;
    let rest = &w[start..];
    let args = &rest[rest.find('[')? + 1..rest.find(']')?];
    let mut it = args.rsplitn(3, ',');
    let rf: f64 = it.next()?.trim().parse().ok()?;
    let a: f64 = it.next()?.trim().parse().ok()?;
    let b = if rf == 0.0 { a } else { a * (1.0 - 1.0 / rf) };
    Body::new(a, b, geographic)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::RasterType;

    fn georef(epsg: Option<u32>, proj: Option<&str>, wkt: Option<&str>) -> GeoRef {
        GeoRef {
            epsg,
            crs_name: None,
            proj: proj.map(Into::into),
            wkt: wkt.map(Into::into),
            geotransform: [8.0, 1.0 / 1200.0, 0.0, 47.0, 0.0, -1.0 / 1200.0],
            raster_type: RasterType::PixelIsPoint,
        }
    }

    #[test]
    fn wgs84_by_code_and_by_proj_string() {
        let by_code = Body::from_georef(&georef(Some(4326), None, None)).unwrap();
        assert!(by_code.geographic);
        assert_eq!(by_code.semi_major, 6_378_137.0);
        assert!((by_code.semi_minor - 6_356_752.314_245).abs() < 1e-3);
        let by_proj = Body::from_georef(&georef(
            None,
            Some("+proj=longlat +datum=WGS84 +no_defs"),
            None,
        ))
        .unwrap();
        assert_eq!(by_proj, by_code);
        // UTM on WGS 84 is projected: the body is known, the grid is not lon/lat.
        let utm = Body::from_georef(&georef(
            Some(32611),
            Some("+proj=utm +zone=11 +datum=WGS84 +units=m +no_defs"),
            None,
        ))
        .unwrap();
        assert!(!utm.geographic);
        assert_eq!(utm.semi_major, 6_378_137.0);
    }

    #[test]
    fn spheres_and_explicit_axes() {
        let moon = georef(None, Some("+proj=longlat +R=1737400 +no_defs"), None);
        assert_eq!(
            Body::from_georef(&moon),
            Some(Body {
                semi_major: 1_737_400.0,
                semi_minor: 1_737_400.0,
                geographic: true
            })
        );
        let mars = georef(None, Some("+proj=longlat +a=3396190 +b=3376200"), None);
        let m = Body::from_georef(&mars).unwrap();
        assert_eq!((m.semi_major, m.semi_minor), (3_396_190.0, 3_376_200.0));
        let wkt = georef(
            None,
            None,
            Some(
                r#"GEOGCS["Moon 2000",DATUM["D_Moon_2000",SPHEROID["Moon_2000_IAU_IAG",1737400.0,0.0]]]"#,
            ),
        );
        let w = Body::from_georef(&wkt).unwrap();
        assert_eq!(
            (w.semi_major, w.semi_minor, w.geographic),
            (1_737_400.0, 1_737_400.0, true)
        );
    }

    #[test]
    fn unknown_or_unusable_is_none() {
        assert_eq!(Body::from_georef(&georef(Some(2056), None, None)), None);
        assert_eq!(
            Body::from_georef(&georef(None, Some("+proj=longlat +a=1 +b=2"), None)),
            None
        );
        assert_eq!(Body::new(f64::NAN, 1.0, true), None);
        assert_eq!(Body::new(1.0, 0.0, true), None);
    }
}
