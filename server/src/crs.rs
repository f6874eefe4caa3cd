//! Coordinate reference systems, through a real projection library (DESIGN §9: never
//! hand-written formulas): `proj4rs`, a pure-Rust port of PROJ.4, with the EPSG
//! definitions of `crs-definitions` (PROJ strings and WKT for every EPSG code).
//!
//! ```
//! use tessera_server::crs::Crs;
//!
//! let utm = Crs::from_epsg(32611).unwrap();
//! let [lon, lat] = utm.to_lon_lat(500_000.0, 3_800_000.0).unwrap();
//! assert!((lon - (-117.0)).abs() < 1e-9 && (lat - 34.3).abs() < 0.05);
//! ```

use anyhow::{Context, anyhow, bail};
use proj4rs::Proj;
use tessera_shared::{GeoRef, GroundSpacing};

/// A CRS that coordinates can be transformed out of and into.
pub struct Crs {
    proj: Proj,
    epsg: Option<u32>,
    proj_string: String,
    wkt: Option<String>,
}

impl std::fmt::Debug for Crs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Crs")
            .field("epsg", &self.epsg)
            .field("proj", &self.proj_string)
            .finish_non_exhaustive()
    }
}

/// WGS 84 longitude/latitude (EPSG:4326), the pivot of every transform here.
const WGS84: &str = "+proj=longlat +datum=WGS84 +no_defs";

impl Crs {
    /// The CRS of an EPSG code, with its PROJ string and WKT.
    pub fn from_epsg(code: u32) -> anyhow::Result<Self> {
        let def = u16::try_from(code)
            .ok()
            .and_then(crs_definitions::from_code)
            .ok_or_else(|| anyhow!("EPSG:{code} is not a CRS this build knows"))?;
        let proj = Proj::from_proj_string(def.proj4)
            .map_err(|e| anyhow!("EPSG:{code} ({}): {e}", def.proj4))?;
        Ok(Self {
            proj,
            epsg: Some(code),
            proj_string: def.proj4.to_string(),
            wkt: Some(def.wkt.to_string()),
        })
    }

    /// A CRS from a PROJ string (`+proj=…`).
    pub fn from_proj_string(s: &str) -> anyhow::Result<Self> {
        let proj = Proj::from_proj_string(s).map_err(|e| anyhow!("PROJ string {s:?}: {e}"))?;
        Ok(Self {
            proj,
            epsg: None,
            proj_string: s.to_string(),
            wkt: None,
        })
    }

    /// `EPSG:CODE` or a PROJ string, as users write them on the command line.
    pub fn parse(s: &str) -> anyhow::Result<Self> {
        let t = s.trim();
        if let Some(code) = t.strip_prefix("EPSG:").or_else(|| t.strip_prefix("epsg:")) {
            let code: u32 = code
                .parse()
                .with_context(|| format!("{s:?}: EPSG code is not a number"))?;
            return Self::from_epsg(code);
        }
        if t.starts_with('+') {
            return Self::from_proj_string(t);
        }
        bail!("{s:?} is neither EPSG:CODE nor a PROJ string (+proj=…)")
    }

    /// The CRS a GeoRef names: by EPSG code, else by its PROJ string.
    pub fn of(georef: &GeoRef) -> Option<Self> {
        if let Some(c) = georef.epsg
            && let Ok(crs) = Self::from_epsg(c)
        {
            return Some(crs);
        }
        georef
            .proj
            .as_deref()
            .and_then(|p| Self::from_proj_string(p).ok())
    }

    pub fn epsg(&self) -> Option<u32> {
        self.epsg
    }

    pub fn proj_string(&self) -> &str {
        &self.proj_string
    }

    pub fn wkt(&self) -> Option<&str> {
        self.wkt.as_deref()
    }

    /// Whether coordinates are longitude/latitude (degrees).
    pub fn is_geographic(&self) -> bool {
        self.proj.is_latlong()
    }

    /// The CRS's name as its WKT gives it (`PROJCS["NAME",…` / `GEOGCS["NAME",…`).
    pub fn name(&self) -> Option<String> {
        let wkt = self.wkt.as_deref()?;
        let start = wkt.find("[\"")? + 2;
        let len = wkt[start..].find('"')?;
        Some(wkt[start..start + len].to_string())
    }

    /// Fills a GeoRef's CRS texts (PROJ string, WKT, name) from the library.
    pub fn describe(&self, georef: &mut GeoRef) {
        georef.proj = Some(self.proj_string.clone());
        georef.wkt.clone_from(&self.wkt);
        if georef.crs_name.is_none() {
            georef.crs_name = self.name();
        }
    }

    /// `(x, y)` of this CRS → `[lon, lat]` in degrees on WGS 84.
    pub fn to_lon_lat(&self, x: f64, y: f64) -> anyhow::Result<[f64; 2]> {
        let wgs84 = wgs84();
        let mut p = self.input(x, y);
        proj4rs::transform::transform(&self.proj, &wgs84, &mut p)
            .map_err(|e| anyhow!("cannot transform ({x}, {y}) to WGS 84: {e}"))?;
        Ok([p.0.to_degrees(), p.1.to_degrees()])
    }

    /// `[lon, lat]` in degrees on WGS 84 → `(x, y)` of this CRS.
    pub fn from_lon_lat(&self, lon: f64, lat: f64) -> anyhow::Result<[f64; 2]> {
        let wgs84 = wgs84();
        let mut p = (lon.to_radians(), lat.to_radians(), 0.0);
        proj4rs::transform::transform(&wgs84, &self.proj, &mut p)
            .map_err(|e| anyhow!("cannot transform ({lon}°, {lat}°) from WGS 84: {e}"))?;
        Ok(self.output(p))
    }

    /// `(x, y)` of this CRS → `(x, y)` of `to`.
    pub fn transform_to(&self, to: &Crs, x: f64, y: f64) -> anyhow::Result<[f64; 2]> {
        let mut p = self.input(x, y);
        proj4rs::transform::transform(&self.proj, &to.proj, &mut p)
            .map_err(|e| anyhow!("cannot transform ({x}, {y}): {e}"))?;
        Ok(to.output(p))
    }

    /// proj4rs works in radians for geographic CRSs.
    fn input(&self, x: f64, y: f64) -> (f64, f64, f64) {
        if self.is_geographic() {
            (x.to_radians(), y.to_radians(), 0.0)
        } else {
            (x, y, 0.0)
        }
    }

    fn output(&self, p: (f64, f64, f64)) -> [f64; 2] {
        if self.is_geographic() {
            [p.0.to_degrees(), p.1.to_degrees()]
        } else {
            [p.0, p.1]
        }
    }
}

fn wgs84() -> Proj {
    Proj::from_proj_string(WGS84).expect("the WGS 84 PROJ string parses")
}

/// Metres on the ground between neighbouring samples at the DEM's centre, in x
/// (columns) and y (rows): the sample steps are carried to WGS 84 and measured in a
/// transverse Mercator centred on the DEM (scale 1 on its central meridian and,
/// over one cell, true to well under a millimetre).
pub fn ground_spacing(georef: &GeoRef, width: u32, height: u32) -> anyhow::Result<GroundSpacing> {
    let crs =
        Crs::of(georef).ok_or_else(|| anyhow!("the CRS is not known to the projection library"))?;
    let (c, r) = (f64::from(width) / 2.0 - 0.5, f64::from(height) / 2.0 - 0.5);
    let at = |dc: f64, dr: f64| {
        let [x, y] = georef.sample_centre(c + dc, r + dr);
        crs.to_lon_lat(x, y)
    };
    let centre = at(0.0, 0.0)?;
    let local = Crs::from_proj_string(&format!(
        "+proj=tmerc +lat_0={} +lon_0={} +k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs",
        centre[1], centre[0]
    ))?;
    let metres = |a: [f64; 2], b: [f64; 2]| -> anyhow::Result<f64> {
        let pa = local.from_lon_lat(a[0], a[1])?;
        let pb = local.from_lon_lat(b[0], b[1])?;
        Ok((pa[0] - pb[0]).hypot(pa[1] - pb[1]))
    };
    let s = GroundSpacing {
        x: metres(at(-0.5, 0.0)?, at(0.5, 0.0)?)?,
        y: metres(at(0.0, -0.5)?, at(0.0, 0.5)?)?,
    };
    if !s.is_plausible() {
        bail!("ground spacing {} × {} m is not plausible", s.x, s.y);
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::RasterType;

    fn geographic(lon0: f64, lat0: f64, step: f64) -> GeoRef {
        GeoRef {
            epsg: Some(4326),
            crs_name: None,
            proj: None,
            wkt: None,
            geotransform: [lon0, step, 0.0, lat0, 0.0, -step],
            raster_type: RasterType::PixelIsArea,
        }
    }

    /// At latitude φ on WGS 84 (a = 6 378 137 m, e² = 0.006 694 38), a degree of
    /// longitude is π/180 · a·cos φ / √(1 − e² sin² φ) and a degree of latitude
    /// π/180 · a(1 − e²) / (1 − e² sin² φ)^{3/2}: 76.6 km and 111.2 km at 46.5° N.
    /// These are the reference values the library's answer is checked against.
    #[test]
    fn geographic_cells_are_not_square() {
        let step = 1.0 / 1200.0;
        // 1201 × 1201 samples from 8°E, 47°N: centre at 46.5°N.
        let g = geographic(8.0 - step / 2.0, 47.0 + step / 2.0, step);
        let s = ground_spacing(&g, 1201, 1201).unwrap();
        let (a, e2) = (6_378_137.0f64, 0.006_694_379_990_14f64);
        let phi = 46.5f64.to_radians();
        let w = 1.0 - e2 * phi.sin().powi(2);
        let deg_lon = std::f64::consts::PI / 180.0 * a * phi.cos() / w.sqrt();
        let deg_lat = std::f64::consts::PI / 180.0 * a * (1.0 - e2) / w.powf(1.5);
        assert!(
            (s.x - deg_lon * step).abs() < 1e-3,
            "{} vs {}",
            s.x,
            deg_lon * step
        );
        assert!(
            (s.y - deg_lat * step).abs() < 1e-3,
            "{} vs {}",
            s.y,
            deg_lat * step
        );
        // The issue's figure: a footprint 0.689× as wide as tall, within 1 %.
        assert!((s.x / s.y / 0.689 - 1.0).abs() < 0.01, "{}", s.x / s.y);
    }

    #[test]
    fn projected_spacing_is_the_pixel_size_times_the_scale_factor() {
        // UTM 11N near its central meridian (-117°): scale 0.9996, so a 10 m pixel
        // is 10.004 m on the ground.
        let g = GeoRef {
            epsg: Some(32611),
            geotransform: [499_000.0, 10.0, 0.0, 3_800_000.0, 0.0, -10.0],
            ..geographic(0.0, 0.0, 1.0)
        };
        let s = ground_spacing(&g, 201, 201).unwrap();
        assert!((s.x - 10.0 / 0.9996).abs() < 2e-3, "{}", s.x);
        assert!((s.y - 10.0 / 0.9996).abs() < 2e-3, "{}", s.y);
    }

    #[test]
    fn epsg_codes_come_with_their_texts_and_bad_ones_are_named() {
        let c = Crs::parse("EPSG:2056").unwrap();
        assert!(c.proj_string().contains("+proj=somerc"));
        assert_eq!(c.name().as_deref(), Some("CH1903+ / LV95"));
        assert!(!c.is_geographic() && Crs::parse("EPSG:4326").unwrap().is_geographic());
        let e = Crs::parse("EPSG:1").unwrap_err().to_string();
        assert!(e.contains("EPSG:1 "), "{e}");
        assert!(
            Crs::parse("UTM11")
                .unwrap_err()
                .to_string()
                .contains("UTM11")
        );
    }

    #[test]
    fn round_trips_through_wgs84() {
        let lv95 = Crs::from_epsg(2056).unwrap();
        // Bern's old observatory, the origin of the Swiss grid.
        let [lon, lat] = lv95.to_lon_lat(2_600_000.0, 1_200_000.0).unwrap();
        assert!(
            (lon - 7.4386).abs() < 1e-3 && (lat - 46.9511).abs() < 1e-3,
            "{lon} {lat}"
        );
        // Back within a centimetre (the datum shift is inverted iteratively).
        let [x, y] = lv95.from_lon_lat(lon, lat).unwrap();
        assert!(
            (x - 2_600_000.0).abs() < 1e-2 && (y - 1_200_000.0).abs() < 1e-2,
            "{x} {y}"
        );
    }
}
