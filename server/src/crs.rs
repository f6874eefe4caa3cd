//! Coordinate reference systems, through a real projection library (never hand-written
//! formulas; docs/ARCHITECTURE.md#coordinate-systems): `proj4rs`, a pure-Rust port of
//! PROJ.4, with the EPSG definitions of `crs-definitions` (PROJ strings and WKT for every
//! EPSG code).
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

    /// The semi-axes `(equatorial, polar)` in metres of the ellipsoid (or sphere) this
    /// CRS's coordinates are on, as the projection library parsed them: WGS 84's
    /// `(6 378 137, 6 356 752.314…)` for EPSG:4326, `(1 737 400, 1 737 400)` for the
    /// Moon's `+proj=longlat +R=1737400`, whatever `+ellps`/`+datum`/`+a`/`+b`/`+rf`/`+R`
    /// the definition uses. `None` only if the library's values are not a usable
    /// ellipsoid (non-finite, non-positive, or polar > equatorial).
    ///
    /// ```
    /// use tessera_server::crs::Crs;
    ///
    /// let moon = Crs::parse("+proj=longlat +R=1737400 +no_defs").unwrap();
    /// assert_eq!(moon.body_radii(), Some((1_737_400.0, 1_737_400.0)));
    /// let (a, b) = Crs::parse("EPSG:4326").unwrap().body_radii().unwrap();
    /// assert_eq!(a, 6_378_137.0);
    /// assert!((b - 6_356_752.314_245).abs() < 1e-3);
    /// ```
    pub fn body_radii(&self) -> Option<(f64, f64)> {
        let (a, b) = self.proj.ellipse_parameters();
        (a.is_finite() && b.is_finite() && b > 0.0 && b <= a).then_some((a, b))
    }

    /// Longitude/latitude (degrees) on this CRS's own ellipsoid, with no datum shift:
    /// where [`Crs::to_lon_lat`] pivots through WGS 84, which means nothing for a CRS
    /// of another body.
    fn own_geographic(&self) -> anyhow::Result<Self> {
        let (a, b) = self
            .body_radii()
            .ok_or_else(|| anyhow!("the CRS {} has no usable ellipsoid", self.proj_string))?;
        Self::from_proj_string(&format!("+proj=longlat +a={a} +b={b} +no_defs"))
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
/// (columns) and y (rows), on the CRS's own body: the sample steps are carried to
/// longitude/latitude on the CRS's ellipsoid ([`Crs::body_radii`]: WGS 84's for
/// EPSG:4326, the Moon's sphere for `+proj=longlat +R=1737400`) and measured in a
/// transverse Mercator on that ellipsoid centred on the DEM (scale 1 on its central
/// meridian and, over one cell, true to well under a millimetre).
pub fn ground_spacing(georef: &GeoRef, width: u32, height: u32) -> anyhow::Result<GroundSpacing> {
    let crs =
        Crs::of(georef).ok_or_else(|| anyhow!("the CRS is not known to the projection library"))?;
    let geographic = crs.own_geographic()?;
    let (a, b) = crs.body_radii().expect("own_geographic checked the radii");
    let (c, r) = (f64::from(width) / 2.0 - 0.5, f64::from(height) / 2.0 - 0.5);
    let at = |dc: f64, dr: f64| {
        let [x, y] = georef.sample_centre(c + dc, r + dr);
        crs.transform_to(&geographic, x, y)
    };
    let centre = at(0.0, 0.0)?;
    let local = Crs::from_proj_string(&format!(
        "+proj=tmerc +lat_0={} +lon_0={} +k=1 +x_0=0 +y_0=0 +a={a} +b={b} +units=m +no_defs",
        centre[1], centre[0]
    ))?;
    let metres = |p: [f64; 2], q: [f64; 2]| -> anyhow::Result<f64> {
        let pa = geographic.transform_to(&local, p[0], p[1])?;
        let pb = geographic.transform_to(&local, q[0], q[1])?;
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
        // 76.6 km by 111.2 km: a cell 0.689× as wide as tall, within 1 %.
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
    fn body_radii_are_the_crs_own_ellipsoid() {
        let wgs84 = Crs::parse("EPSG:4326").unwrap().body_radii().unwrap();
        assert_eq!(wgs84.0, 6_378_137.0);
        // b = a (1 − 1/298.257223563).
        assert!((wgs84.1 - 6_356_752.314_245_18).abs() < 1e-6, "{wgs84:?}");
        // A projected CRS is on its datum's ellipsoid: LV95 on Bessel 1841.
        let bessel = Crs::parse("EPSG:2056").unwrap().body_radii().unwrap();
        assert_eq!(bessel.0, 6_377_397.155);
        assert!((bessel.1 - 6_356_078.963).abs() < 1e-3, "{bessel:?}");
        let moon = Crs::parse("+proj=longlat +R=1737400 +no_defs").unwrap();
        assert_eq!(moon.body_radii(), Some((1_737_400.0, 1_737_400.0)));
        // Mars (IAU 2015 49900): a = 3 396 190 m, b = 3 376 200 m.
        let mars = Crs::parse("+proj=longlat +a=3396190 +b=3376200 +no_defs").unwrap();
        assert_eq!(mars.body_radii(), Some((3_396_190.0, 3_376_200.0)));
    }

    /// On the Moon's sphere (R = 1 737.4 km) a 1/256° cell is R·π/180/256 =
    /// 118.4506 m north–south and that times cos φ east–west, whatever the Earth's
    /// ellipsoid would say (430 m there).
    #[test]
    fn ground_spacing_on_another_body_uses_its_sphere() {
        let step = 1.0 / 256.0;
        let g = GeoRef {
            epsg: None,
            proj: Some("+proj=longlat +R=1737400 +no_defs".into()),
            geotransform: [51.0, step, 0.0, 24.992_187_5, 0.0, -step],
            ..geographic(0.0, 0.0, 1.0)
        };
        let s = ground_spacing(&g, 4096, 4096).unwrap();
        let ns = 1_737_400.0 * step.to_radians();
        assert!((s.y - ns).abs() < 1e-6, "{} vs {ns}", s.y);
        let lat = 24.992_187_5 - 2048.0 * step;
        assert!((s.x - ns * lat.to_radians().cos()).abs() < 1e-6, "{}", s.x);
        assert!((s.y - 118.4506).abs() < 1e-3);
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
