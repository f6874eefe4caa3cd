//! Coordinate reference systems, through PROJ itself (never hand-written formulas;
//! docs/ARCHITECTURE.md#coordinate-systems, DECISIONS.md "Projection library: PROJ"):
//! EPSG and other authority codes from PROJ's database, WKT 1 and 2 (GDAL's and
//! ESRI's), PROJ strings and compound CRSs with a vertical part, with the datum-shift
//! and geoid grids the system has installed (`proj-data`).
//!
//! ```
//! use tessera_server::crs::Crs;
//!
//! let utm = Crs::from_epsg(32611).unwrap();
//! let [lon, lat] = utm.to_lon_lat(500_000.0, 3_800_000.0).unwrap();
//! assert!((lon - (-117.0)).abs() < 1e-9 && (lat - 34.3).abs() < 0.05);
//! ```

mod proj;

pub use proj::version as proj_version;

use anyhow::{anyhow, bail};
use tessera_shared::{GeoRef, GroundSpacing};

/// A CRS that coordinates can be transformed out of and into: its definition and
/// what PROJ said about it when it was made. Plain data, so it can be shared between
/// threads; each thread keeps its own PROJ objects for it (`crs/proj.rs`).
#[derive(Clone)]
pub struct Crs {
    /// What PROJ is given: `EPSG:2056`, a WKT, a PROJ string.
    definition: String,
    /// xxh3 of `definition`: the key of each thread's PROJ objects.
    key: u64,
    epsg: Option<u32>,
    name: Option<String>,
    proj_string: String,
    wkt: Option<String>,
    radii: Option<(f64, f64)>,
    geographic: bool,
    has_vertical: bool,
}

impl std::fmt::Debug for Crs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Crs")
            .field("epsg", &self.epsg)
            .field("name", &self.name)
            .field("proj", &self.proj_string)
            .finish_non_exhaustive()
    }
}

/// Two CRSs are equal when PROJ is given the same definition.
impl PartialEq for Crs {
    fn eq(&self, other: &Self) -> bool {
        self.definition == other.definition
    }
}

/// WGS 84 longitude/latitude (EPSG:4326), the pivot of [`Crs::to_lon_lat`].
fn wgs84() -> &'static Crs {
    static WGS84: std::sync::OnceLock<Crs> = std::sync::OnceLock::new();
    WGS84.get_or_init(|| Crs::from_epsg(4326).expect("PROJ's database has EPSG:4326"))
}

impl Crs {
    /// Any definition PROJ reads: `EPSG:CODE` (and other authorities' `AUTH:CODE`),
    /// a compound `EPSG:4326+5773`, WKT 1 or 2 (GDAL's or ESRI's), PROJJSON, or a
    /// PROJ string. The error is PROJ's, with the definition (shortened) in front.
    pub fn from_definition(definition: &str) -> anyhow::Result<Self> {
        let trimmed = definition.trim();
        // PROJ reads a bare PROJ string as an operation; `+type=crs` makes it the CRS
        // users (and PROJ.4-era files) mean, as GDAL's importFromProj4 does.
        let typed;
        let definition = if trimmed.starts_with('+') && !trimmed.contains("+type=crs") {
            typed = format!("{trimmed} +type=crs");
            typed.as_str()
        } else {
            trimmed
        };
        let d = proj::describe_cached(definition)
            .map_err(|e| anyhow!("{}: {e}", shorten(definition)))?;
        let epsg =
            d.id.as_ref()
                .filter(|(auth, _)| auth.eq_ignore_ascii_case("EPSG"))
                .and_then(|(_, code)| code.parse().ok());
        Ok(Self {
            definition: definition.to_string(),
            key: xxhash_rust::xxh3::xxh3_64(definition.as_bytes()),
            epsg,
            name: d
                .name
                .filter(|n| !n.is_empty() && n != "unknown" && n != "unnamed"),
            proj_string: d.proj_string.unwrap_or_default(),
            wkt: d.wkt,
            radii: d
                .radii
                .filter(|&(a, b)| a.is_finite() && b.is_finite() && b > 0.0 && b <= a),
            geographic: d.geographic,
            has_vertical: d.has_vertical,
        })
    }

    /// The CRS of an EPSG code.
    pub fn from_epsg(code: u32) -> anyhow::Result<Self> {
        // PROJ's own words for a missing code are "Unknown error (code 4096)".
        Self::from_definition(&format!("EPSG:{code}")).map_err(|_| {
            anyhow!(
                "EPSG:{code} is not a CRS in PROJ's database ({})",
                proj_version_text()
            )
        })
    }

    /// A CRS from a PROJ string (`+proj=…`).
    pub fn from_proj_string(s: &str) -> anyhow::Result<Self> {
        Self::from_definition(s).map_err(|e| anyhow!("PROJ string {s:?}: {e}"))
    }

    /// What users write on the command line: `EPSG:CODE`, `AUTH:CODE`, a PROJ string
    /// or a WKT (see [`Crs::from_definition`]).
    pub fn parse(s: &str) -> anyhow::Result<Self> {
        let t = s.trim();
        if let Some(code) = t.strip_prefix("EPSG:").or_else(|| t.strip_prefix("epsg:"))
            && !code.contains('+')
        {
            let code: u32 = code
                .parse()
                .map_err(|_| anyhow!("{s:?}: EPSG code is not a number"))?;
            return Self::from_epsg(code);
        }
        // PROJ would also take a bare name ("moon" is ESRI's GCS_Moon_2000): too
        // easy to get by mistake on a command line, so only definitions are read.
        let definition_like =
            t.starts_with('+') || t.starts_with('{') || t.contains('[') || t.contains(':');
        if !definition_like {
            bail!(
                "{s:?} is neither EPSG:CODE nor a PROJ string (+proj=…) nor a WKT \
                 (AUTH:CODE and PROJJSON are read too)"
            );
        }
        Self::from_definition(t).map_err(|e| {
            anyhow!("{e} (want EPSG:CODE, AUTH:CODE, a PROJ string (+proj=…) or a WKT)")
        })
    }

    /// The CRS a GeoRef names: by EPSG code, else by its PROJ string, else by its
    /// WKT. The PROJ string first: PROJ 9.1 finds no operation out of some WKTs that
    /// it reads (a GDAL WKT 1 of the Moon's sphere, whose prime meridian is named
    /// "Reference meridian"), where the PROJ string it exports for the same CRS works.
    pub fn of(georef: &GeoRef) -> Option<Self> {
        if let Some(c) = georef.epsg
            && let Ok(crs) = Self::from_epsg(c)
        {
            return Some(crs);
        }
        [georef.proj.as_deref(), georef.wkt.as_deref()]
            .into_iter()
            .flatten()
            .find_map(|d| Self::from_definition(d).ok())
    }

    /// The EPSG code, when the definition names one or PROJ identifies it as one
    /// with full confidence.
    pub fn epsg(&self) -> Option<u32> {
        self.epsg
    }

    /// The definition as given to PROJ.
    pub fn definition(&self) -> &str {
        &self.definition
    }

    pub fn proj_string(&self) -> &str {
        &self.proj_string
    }

    pub fn wkt(&self) -> Option<&str> {
        self.wkt.as_deref()
    }

    /// Whether the CRS says what heights are measured from (a compound CRS such as
    /// `EPSG:4326+5773`, or a 3-D geographic CRS such as `EPSG:4979`).
    pub fn has_vertical(&self) -> bool {
        self.has_vertical
    }

    /// The semi-axes `(equatorial, polar)` in metres of the ellipsoid (or sphere) this
    /// CRS's coordinates are on, as PROJ reads the definition: WGS 84's
    /// `(6 378 137, 6 356 752.314…)` for EPSG:4326, `(1 737 400, 1 737 400)` for the
    /// Moon's `+proj=longlat +R=1737400`, whatever `+ellps`/`+datum`/`+a`/`+b`/`+rf`/`+R`
    /// or WKT `ELLIPSOID` the definition uses. `None` only if the values are not a
    /// usable ellipsoid (non-finite, non-positive, or polar > equatorial).
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
        self.radii
    }

    /// Longitude/latitude (degrees) on this CRS's own ellipsoid, with no datum shift:
    /// where [`Crs::to_lon_lat`] pivots through WGS 84, which means nothing for a CRS
    /// of another body.
    pub fn own_geographic(&self) -> anyhow::Result<Self> {
        let (a, b) = self
            .body_radii()
            .ok_or_else(|| anyhow!("the CRS {} has no usable ellipsoid", self.label()))?;
        Self::from_proj_string(&format!("+proj=longlat +a={a} +b={b} +no_defs +type=crs"))
    }

    /// Whether the CRS is on the Earth (an ellipsoid of 6 300–6 400 km): where WGS 84
    /// longitude/latitude and the geoid mean something.
    pub fn is_earth(&self) -> bool {
        self.radii
            .is_some_and(|(a, _)| (6_300_000.0..6_400_000.0).contains(&a))
    }

    /// Whether coordinates are longitude/latitude (degrees).
    pub fn is_geographic(&self) -> bool {
        self.geographic
    }

    /// The CRS's name as PROJ gives it ("CH1903+ / LV95").
    pub fn name(&self) -> Option<String> {
        self.name.clone()
    }

    /// How messages name the CRS: `EPSG:CODE (name)`, the name, or the definition.
    pub fn label(&self) -> String {
        match (self.epsg, &self.name) {
            (Some(c), Some(n)) => format!("EPSG:{c} ({n})"),
            (Some(c), None) => format!("EPSG:{c}"),
            (None, Some(n)) => n.clone(),
            (None, None) => shorten(&self.definition),
        }
    }

    /// Fills a GeoRef's CRS texts (EPSG code when identified, PROJ string, WKT, name)
    /// from the library.
    pub fn describe(&self, georef: &mut GeoRef) {
        if georef.epsg.is_none() {
            georef.epsg = self.epsg;
        }
        georef.proj = (!self.proj_string.is_empty()).then(|| self.proj_string.clone());
        georef.wkt.clone_from(&self.wkt);
        if georef.crs_name.is_none() {
            georef.crs_name = self.name();
        }
    }

    /// `(x, y)` of this CRS → `[lon, lat]` in degrees on WGS 84.
    pub fn to_lon_lat(&self, x: f64, y: f64) -> anyhow::Result<[f64; 2]> {
        self.transform_to(wgs84(), x, y)
            .map_err(|e| anyhow!("cannot transform ({x}, {y}) to WGS 84: {e}"))
    }

    /// `[lon, lat]` in degrees on WGS 84 → `(x, y)` of this CRS.
    pub fn from_lon_lat(&self, lon: f64, lat: f64) -> anyhow::Result<[f64; 2]> {
        wgs84()
            .transform_to(self, lon, lat)
            .map_err(|e| anyhow!("cannot transform ({lon}°, {lat}°) from WGS 84: {e}"))
    }

    /// `(x, y)` of this CRS → `(x, y)` of `to`.
    pub fn transform_to(&self, to: &Crs, x: f64, y: f64) -> anyhow::Result<[f64; 2]> {
        let mut p = [[x, y, 0.0]];
        self.transform_points(to, &mut p)
            .map_err(|e| anyhow!("cannot transform ({x}, {y}): {e}"))?;
        Ok([p[0][0], p[0][1]])
    }

    /// Transforms many `(x, y, z)` at once (one PROJ call). Points PROJ cannot
    /// transform become NaN, and the error says how many; the others are done.
    pub fn transform_points(&self, to: &Crs, points: &mut [[f64; 3]]) -> anyhow::Result<()> {
        proj::transform(
            (self.key, &self.definition),
            (to.key, &to.definition),
            points,
            false,
        )
        .map_err(|e| anyhow!("{} → {}: {e}", self.label(), to.label()))
    }

    /// [`Crs::transform_points`] with no "ballpark" operation: where PROJ lacks a
    /// grid the transformation needs (a geoid model), an error rather than the
    /// identity PROJ would otherwise fall back to.
    pub fn transform_points_exactly(
        &self,
        to: &Crs,
        points: &mut [[f64; 3]],
    ) -> anyhow::Result<()> {
        proj::transform(
            (self.key, &self.definition),
            (to.key, &to.definition),
            points,
            true,
        )
        .map_err(|e| anyhow!("{} → {}: {e}", self.label(), to.label()))
    }
}

fn proj_version_text() -> String {
    format!("PROJ {}", proj_version())
}

/// A definition cut to its first 80 characters, for messages (a WKT is long).
fn shorten(definition: &str) -> String {
    let one_line: String = definition.split_whitespace().collect::<Vec<_>>().join(" ");
    match one_line.char_indices().nth(80) {
        Some((i, _)) => format!("{}…", &one_line[..i]),
        None => one_line,
    }
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
