//! A CRS from GeoTIFF GeoKeys that name no EPSG CRS code (GeoTIFF 1.0 §6.3.2–6.3.3,
//! "user-defined", 32767), read the way libgeotiff and GDAL read them: the projection
//! method (`ProjCoordTransGeoKey`) and its parameters, or an EPSG conversion code
//! (`ProjectionGeoKey`, e.g. 16125 = UTM zone 25S); the geographic base by EPSG code,
//! datum or ellipsoid code, or its own axes, prime meridian and TOWGS84; the linear
//! units. The result is a PROJ string that [`crate::crs::Crs`] reads.
//!
//! An ESRI WKT in the citation keys (`ESRI PE String = PROJCS[…]`) is taken whole
//! instead, as GDAL does.

use crate::crs::Crs;
use std::collections::BTreeMap;
use std::fmt::Write;

/// The GeoKeys a CRS is read from: shorts, doubles and ASCII values by key id.
#[derive(Debug, Default, Clone)]
pub(super) struct KeyValues {
    pub shorts: BTreeMap<u16, u16>,
    pub doubles: BTreeMap<u16, Vec<f64>>,
    pub ascii: BTreeMap<u16, String>,
}

const USER_DEFINED: u16 = 32767;

// GeoKey ids (GeoTIFF 1.0 §6.2.2–6.2.3).
const GT_MODEL_TYPE: u16 = 1024;
const GT_CITATION: u16 = 1026;
const GEOGRAPHIC_TYPE: u16 = 2048;
const GEOG_CITATION: u16 = 2049;
const GEOG_GEODETIC_DATUM: u16 = 2050;
const GEOG_PRIME_MERIDIAN: u16 = 2051;
const GEOG_ANGULAR_UNITS: u16 = 2054;
const GEOG_ANGULAR_UNIT_SIZE: u16 = 2055;
const GEOG_ELLIPSOID: u16 = 2056;
const GEOG_SEMI_MAJOR: u16 = 2057;
const GEOG_SEMI_MINOR: u16 = 2058;
const GEOG_INV_FLATTENING: u16 = 2059;
const GEOG_PRIME_MERIDIAN_LONG: u16 = 2061;
const GEOG_TOWGS84: u16 = 2062;
const PROJECTED_CS_TYPE: u16 = 3072;
const PCS_CITATION: u16 = 3073;
const PROJECTION: u16 = 3074;
const PROJ_COORD_TRANS: u16 = 3075;
const PROJ_LINEAR_UNITS: u16 = 3076;
const PROJ_LINEAR_UNIT_SIZE: u16 = 3077;
const STD_PARALLEL1: u16 = 3078;
const STD_PARALLEL2: u16 = 3079;
const NAT_ORIGIN_LONG: u16 = 3080;
const NAT_ORIGIN_LAT: u16 = 3081;
const FALSE_EASTING: u16 = 3082;
const FALSE_NORTHING: u16 = 3083;
const FALSE_ORIGIN_LONG: u16 = 3084;
const FALSE_ORIGIN_LAT: u16 = 3085;
const FALSE_ORIGIN_EASTING: u16 = 3086;
const FALSE_ORIGIN_NORTHING: u16 = 3087;
const CENTER_LONG: u16 = 3088;
const CENTER_LAT: u16 = 3089;
const CENTER_EASTING: u16 = 3090;
const CENTER_NORTHING: u16 = 3091;
const SCALE_AT_NAT_ORIGIN: u16 = 3092;
const SCALE_AT_CENTER: u16 = 3093;
const AZIMUTH_ANGLE: u16 = 3094;
const STRAIGHT_VERT_POLE_LONG: u16 = 3095;

impl KeyValues {
    fn short(&self, id: u16) -> Option<u16> {
        self.shorts.get(&id).copied().filter(|&v| v != 0)
    }

    fn double(&self, id: u16) -> Option<f64> {
        self.doubles
            .get(&id)
            .and_then(|v| v.first().copied())
            .filter(|v| v.is_finite())
    }

    fn first_double(&self, ids: &[u16]) -> Option<f64> {
        ids.iter().find_map(|&id| self.double(id))
    }

    /// An ESRI WKT carried in a citation key, as ArcGIS writes GeoTIFFs.
    fn esri_wkt(&self) -> Option<String> {
        [GT_CITATION, PCS_CITATION, GEOG_CITATION]
            .iter()
            .find_map(|id| {
                let text = self.ascii.get(id)?;
                let start = text.find("ESRI PE String = ")? + "ESRI PE String = ".len();
                let wkt = text[start..].trim_end_matches(['|', '\0', ' ']);
                (wkt.starts_with("PROJCS[") || wkt.starts_with("GEOGCS[")).then(|| wkt.to_string())
            })
    }
}

/// The CRS definition the keys state without an EPSG CRS code, or `None` when they
/// name an EPSG code (read elsewhere) or too little to make a CRS of. `Err` names
/// what is there but cannot be read (an unsupported projection method).
pub(super) fn definition(keys: &KeyValues) -> Result<Option<String>, String> {
    if let Some(wkt) = keys.esri_wkt() {
        return Ok(Some(wkt));
    }
    let model = keys.short(GT_MODEL_TYPE);
    let projected = keys.short(PROJECTED_CS_TYPE);
    let geographic = keys.short(GEOGRAPHIC_TYPE);
    match model {
        Some(1)
            if projected == Some(USER_DEFINED) || (projected.is_none() && has_projection(keys)) =>
        {
            let base = geodetic(keys)?;
            let conversion = conversion(keys)?;
            let units = linear_units(keys)?;
            Ok(Some(format!(
                "{conversion} {base}{} +no_defs +type=crs",
                units.proj
            )))
        }
        Some(2)
            if geographic == Some(USER_DEFINED) || (geographic.is_none() && has_geodetic(keys)) =>
        {
            Ok(Some(format!(
                "+proj=longlat {} +no_defs +type=crs",
                geodetic(keys)?
            )))
        }
        _ => Ok(None),
    }
}

fn has_projection(keys: &KeyValues) -> bool {
    keys.short(PROJECTION).is_some() || keys.short(PROJ_COORD_TRANS).is_some()
}

fn has_geodetic(keys: &KeyValues) -> bool {
    keys.short(GEOG_GEODETIC_DATUM).is_some()
        || keys.short(GEOG_ELLIPSOID).is_some()
        || keys.double(GEOG_SEMI_MAJOR).is_some()
}

/// PROJ's terms for an EPSG CRS code's datum (`+datum=…` or `+ellps=… +towgs84=…`).
fn epsg_datum_terms(code: u32) -> Option<String> {
    let crs = Crs::from_epsg(code).ok()?;
    let terms: Vec<&str> = crs
        .proj_string()
        .split_whitespace()
        .filter(|t| {
            [
                "+datum=",
                "+ellps=",
                "+towgs84=",
                "+a=",
                "+b=",
                "+rf=",
                "+R=",
                "+pm=",
                "+nadgrids=",
            ]
            .iter()
            .any(|k| t.starts_with(k))
        })
        .collect();
    (!terms.is_empty()).then(|| terms.join(" "))
}

/// The geographic base as PROJ terms: by EPSG geographic CRS code, else datum code
/// (EPSG datum 6xxx is the datum of geographic CRS 4xxx), else ellipsoid code or own
/// axes, with the prime meridian and TOWGS84 the keys give.
fn geodetic(keys: &KeyValues) -> Result<String, String> {
    if let Some(code) = keys.short(GEOGRAPHIC_TYPE).filter(|&c| c != USER_DEFINED)
        && let Some(terms) = epsg_datum_terms(u32::from(code))
    {
        return Ok(terms);
    }
    if let Some(datum) = keys
        .short(GEOG_GEODETIC_DATUM)
        .filter(|&c| (6000..7000).contains(&c))
        && let Some(terms) = epsg_datum_terms(u32::from(datum) - 2000)
    {
        return Ok(terms);
    }
    let mut out = if let Some(code) = keys.short(GEOG_ELLIPSOID).filter(|&c| c != USER_DEFINED) {
        ellipsoid_terms(code)?
    } else {
        let a = keys.double(GEOG_SEMI_MAJOR).ok_or(
            "a user-defined datum with no ellipsoid code and no semi-major axis (GeogSemiMajorAxisGeoKey)",
        )?;
        match (
            keys.double(GEOG_INV_FLATTENING),
            keys.double(GEOG_SEMI_MINOR),
        ) {
            (Some(rf), _) if rf > 0.0 => format!("+a={a} +rf={rf}"),
            (_, Some(b)) if b > 0.0 => format!("+a={a} +b={b}"),
            // GeoTIFF: an inverse flattening of 0 is a sphere.
            _ => format!("+R={a}"),
        }
    };
    if let Some(t) = keys.doubles.get(&GEOG_TOWGS84)
        && matches!(t.len(), 3 | 7)
    {
        let _ = write!(
            out,
            " +towgs84={}",
            t.iter().map(f64::to_string).collect::<Vec<_>>().join(",")
        );
    }
    let pm = match keys.short(GEOG_PRIME_MERIDIAN) {
        Some(8901) | None => keys.double(GEOG_PRIME_MERIDIAN_LONG).filter(|&l| l != 0.0),
        Some(USER_DEFINED) => keys.double(GEOG_PRIME_MERIDIAN_LONG),
        Some(code) => Some(prime_meridian(code)?),
    };
    if let Some(pm) = pm {
        let _ = write!(out, " +pm={}", pm * angular_unit(keys)?);
    }
    Ok(out)
}

/// An EPSG ellipsoid code (7xxx) as PROJ's `+ellps=` name, for the ellipsoids GeoTIFF
/// writers use (a datum or geographic CRS code, read first, covers the rest).
fn ellipsoid_terms(code: u16) -> Result<String, String> {
    // Common ellipsoids by code; PROJ's own +ellps names for them.
    let name = match code {
        7001 => "airy",
        7002 => "mod_airy",
        7003 => "aust_SA",
        7004 => "bessel",
        7008 => "clrk66",
        7012 => "clrk80ign",
        7019 => "GRS80",
        7022 => "intl",
        7024 => "krass",
        7030 => "WGS84",
        7043 => "WGS72",
        7034 => "clrk80",
        7036 => "GRS67",
        7015 => "evrst30",
        7016 => "evrstSS",
        7044 => "evrst69",
        _ => {
            return Err(format!(
                "the ellipsoid code {code} (GeogEllipsoidGeoKey) is not one this reader knows"
            ));
        }
    };
    Ok(format!("+ellps={name}"))
}

fn prime_meridian(code: u16) -> Result<f64, String> {
    // EPSG prime meridians, longitudes from Greenwich in degrees.
    Ok(match code {
        8901 => 0.0,
        8902 => -9.131_906_111,  // Lisbon
        8903 => 2.337_229_166_7, // Paris
        8904 => -74.080_916_7,   // Bogota
        8905 => -3.687_938_9,    // Madrid
        8906 => 12.452_333_3,    // Rome
        8907 => 7.439_583_3,     // Bern
        8908 => 106.807_719_4,   // Jakarta
        8909 => -17.666_666_7,   // Ferro
        8910 => 4.367_975,       // Brussels
        8911 => 18.058_277_8,    // Stockholm
        8912 => 23.716_337_5,    // Athens
        8913 => 10.722_916_7,    // Oslo
        _ => {
            return Err(format!(
                "the prime meridian code {code} is not one this reader knows"
            ));
        }
    })
}

/// Degrees per unit of the angular parameters (GeogAngularUnitsGeoKey; default degree).
fn angular_unit(keys: &KeyValues) -> Result<f64, String> {
    match keys.short(GEOG_ANGULAR_UNITS) {
        None | Some(9102 | 9122) => Ok(1.0),
        Some(9101) => Ok(180.0 / std::f64::consts::PI),
        Some(9105) => Ok(0.9), // grad
        Some(9104) => Ok(1.0 / 3600.0),
        Some(USER_DEFINED) => keys
            .double(GEOG_ANGULAR_UNIT_SIZE)
            .map(f64::to_degrees)
            .ok_or_else(|| "a user-defined angular unit with no size".to_string()),
        Some(other) => Err(format!(
            "the angular unit code {other} is not one this reader knows"
        )),
    }
}

struct Units {
    /// Metres per unit.
    metres: f64,
    /// PROJ's `+units=`/`+to_meter=` term, with its leading space.
    proj: String,
}

fn linear_units(keys: &KeyValues) -> Result<Units, String> {
    let (metres, proj) = match keys.short(PROJ_LINEAR_UNITS) {
        None | Some(9001) => (1.0, " +units=m".to_string()),
        Some(9002) => (0.3048, " +units=ft".to_string()),
        Some(9003) => (1200.0 / 3937.0, " +units=us-ft".to_string()),
        Some(9036) => (1000.0, " +units=km".to_string()),
        Some(USER_DEFINED) => {
            let m = keys
                .double(PROJ_LINEAR_UNIT_SIZE)
                .filter(|m| *m > 0.0)
                .ok_or("a user-defined linear unit with no size (ProjLinearUnitSizeGeoKey)")?;
            (m, format!(" +to_meter={m}"))
        }
        Some(other) => {
            return Err(format!(
                "the linear unit code {other} is not one this reader knows"
            ));
        }
    };
    Ok(Units { metres, proj })
}

/// The conversion as PROJ terms: an EPSG conversion code (UTM zones directly, others
/// through PROJ's database), else the method and its parameters.
fn conversion(keys: &KeyValues) -> Result<String, String> {
    if let Some(code) = keys.short(PROJECTION).filter(|&c| c != USER_DEFINED) {
        return match code {
            16001..=16060 => Ok(format!("+proj=utm +zone={}", code - 16000)),
            16101..=16160 => Ok(format!("+proj=utm +zone={} +south", code - 16100)),
            _ => Err(format!(
                "the EPSG conversion {code} (ProjectionGeoKey) is not one this reader knows; \
                 give the CRS with --crs"
            )),
        };
    }
    let method = keys.short(PROJ_COORD_TRANS).ok_or(
        "a user-defined projected CRS with neither ProjectionGeoKey nor ProjCoordTransGeoKey",
    )?;
    let deg = angular_unit(keys)?;
    let metres = linear_units(keys)?.metres;
    let angle = |ids: &[u16]| keys.first_double(ids).unwrap_or(0.0) * deg;
    // PROJ's +x_0/+y_0 are metres whatever the CRS's unit (GeoTIFF's are in it).
    let len = |ids: &[u16]| keys.first_double(ids).unwrap_or(0.0) * metres;
    let scale = |ids: &[u16]| keys.first_double(ids).unwrap_or(1.0);
    let fe = len(&[FALSE_EASTING, FALSE_ORIGIN_EASTING, CENTER_EASTING]);
    let fn_ = len(&[FALSE_NORTHING, FALSE_ORIGIN_NORTHING, CENTER_NORTHING]);
    let false_en = format!("+x_0={fe} +y_0={fn_}");
    let lat0 = angle(&[NAT_ORIGIN_LAT, FALSE_ORIGIN_LAT, CENTER_LAT]);
    let lon0 = angle(&[NAT_ORIGIN_LONG, FALSE_ORIGIN_LONG, CENTER_LONG]);
    let k0 = scale(&[SCALE_AT_NAT_ORIGIN, SCALE_AT_CENTER]);
    let sp1 = angle(&[STD_PARALLEL1]);
    let sp2 = angle(&[STD_PARALLEL2]);
    let centre = format!(
        "+lat_0={} +lon_0={}",
        angle(&[CENTER_LAT, NAT_ORIGIN_LAT]),
        angle(&[CENTER_LONG, NAT_ORIGIN_LONG])
    );
    // GeoTIFF 1.0 §6.3.3.3 coordinate transformation codes.
    Ok(match method {
        1 => format!("+proj=tmerc +lat_0={lat0} +lon_0={lon0} +k={k0} {false_en}"),
        27 => format!("+proj=tmerc +axis=wsu +lat_0={lat0} +lon_0={lon0} +k={k0} {false_en}"),
        3 => format!(
            "+proj=omerc +lat_0={} +lonc={} +alpha={} +k={} {false_en}",
            angle(&[CENTER_LAT, NAT_ORIGIN_LAT]),
            angle(&[CENTER_LONG, NAT_ORIGIN_LONG]),
            angle(&[AZIMUTH_ANGLE]),
            scale(&[SCALE_AT_CENTER, SCALE_AT_NAT_ORIGIN])
        ),
        7 => match keys.double(STD_PARALLEL1) {
            Some(ts) => format!("+proj=merc +lat_ts={} +lon_0={lon0} {false_en}", ts * deg),
            None => format!("+proj=merc +lon_0={lon0} +k={k0} {false_en}"),
        },
        8 => format!(
            "+proj=lcc +lat_1={sp1} +lat_2={sp2} +lat_0={} +lon_0={} {false_en}",
            angle(&[FALSE_ORIGIN_LAT, NAT_ORIGIN_LAT]),
            angle(&[FALSE_ORIGIN_LONG, NAT_ORIGIN_LONG])
        ),
        9 => format!("+proj=lcc +lat_1={lat0} +lat_0={lat0} +lon_0={lon0} +k_0={k0} {false_en}"),
        10 => format!("+proj=laea {centre} {false_en}"),
        11 => format!(
            "+proj=aea +lat_1={sp1} +lat_2={sp2} +lat_0={} +lon_0={} {false_en}",
            angle(&[NAT_ORIGIN_LAT, FALSE_ORIGIN_LAT, CENTER_LAT]),
            angle(&[NAT_ORIGIN_LONG, FALSE_ORIGIN_LONG, CENTER_LONG])
        ),
        12 => format!("+proj=aeqd {centre} {false_en}"),
        13 => {
            format!("+proj=eqdc +lat_1={sp1} +lat_2={sp2} +lat_0={lat0} +lon_0={lon0} {false_en}")
        }
        14 => format!("+proj=stere {centre} +k={k0} {false_en}"),
        15 => {
            let lat_ts = angle(&[NAT_ORIGIN_LAT, STD_PARALLEL1]);
            let pole = if lat_ts < 0.0 { -90.0 } else { 90.0 };
            let lon = angle(&[STRAIGHT_VERT_POLE_LONG, NAT_ORIGIN_LONG]);
            if keys.double(SCALE_AT_NAT_ORIGIN).is_some()
                && keys.double(STD_PARALLEL1).is_none()
                && lat_ts.abs() == 90.0
            {
                format!("+proj=stere +lat_0={pole} +lon_0={lon} +k={k0} {false_en}")
            } else {
                format!("+proj=stere +lat_0={pole} +lat_ts={lat_ts} +lon_0={lon} {false_en}")
            }
        }
        16 => format!("+proj=sterea +lat_0={lat0} +lon_0={lon0} +k={k0} {false_en}"),
        17 => format!(
            "+proj=eqc +lat_ts={} +lat_0={lat0} +lon_0={lon0} {false_en}",
            angle(&[STD_PARALLEL1])
        ),
        18 => format!("+proj=cass +lat_0={lat0} +lon_0={lon0} {false_en}"),
        19 => format!("+proj=gnom {centre} {false_en}"),
        20 => format!("+proj=mill {centre} {false_en}"),
        21 => format!("+proj=ortho {centre} {false_en}"),
        22 => format!("+proj=poly +lat_0={lat0} +lon_0={lon0} {false_en}"),
        23 => format!("+proj=robin +lon_0={lon0} {false_en}"),
        24 => format!(
            "+proj=sinu +lon_0={} {false_en}",
            angle(&[CENTER_LONG, NAT_ORIGIN_LONG])
        ),
        25 => format!("+proj=vandg +lon_0={lon0} {false_en}"),
        26 => format!("+proj=nzmg +lat_0={lat0} +lon_0={lon0} {false_en}"),
        other => {
            return Err(format!(
                "the projection method {other} (ProjCoordTransGeoKey) is not one this reader knows"
            ));
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn keys(shorts: &[(u16, u16)], doubles: &[(u16, &[f64])]) -> KeyValues {
        KeyValues {
            shorts: shorts.iter().copied().collect(),
            doubles: doubles.iter().map(|&(k, v)| (k, v.to_vec())).collect(),
            ascii: BTreeMap::new(),
        }
    }

    /// Where both CRSs put the same ground points, within a millimetre.
    fn agree(ours: &str, reference: &str, points: &[[f64; 2]]) {
        let ours = Crs::from_definition(ours).unwrap();
        let reference = Crs::parse(reference).unwrap();
        for &[x, y] in points {
            let a = ours.to_lon_lat(x, y).unwrap();
            let b = reference.to_lon_lat(x, y).unwrap();
            // 1 mm is 1e-8° of latitude.
            assert!(
                (a[0] - b[0]).abs() < 1e-8 && (a[1] - b[1]).abs() < 1e-8,
                "{a:?} vs {b:?} at ({x}, {y})"
            );
        }
    }

    /// olinda_dem_utm25s.tif's keys: ProjectionGeoKey 16125 (UTM zone 25S) over a
    /// user-defined GRS 1980 datum with TOWGS84 0, as GDAL reads them.
    #[test]
    fn an_epsg_conversion_over_a_user_defined_datum() {
        let k = keys(
            &[
                (GT_MODEL_TYPE, 1),
                (GEOGRAPHIC_TYPE, USER_DEFINED),
                (GEOG_GEODETIC_DATUM, USER_DEFINED),
                (GEOG_ANGULAR_UNITS, 9102),
                (GEOG_ELLIPSOID, USER_DEFINED),
                (PROJECTED_CS_TYPE, USER_DEFINED),
                (PROJECTION, 16125),
                (PROJ_LINEAR_UNITS, 9001),
            ],
            &[
                (GEOG_SEMI_MAJOR, &[6_378_137.0]),
                (GEOG_INV_FLATTENING, &[298.257_222_101]),
                (GEOG_PRIME_MERIDIAN_LONG, &[0.0]),
                (GEOG_TOWGS84, &[0.0, 0.0, 0.0]),
            ],
        );
        let def = definition(&k).unwrap().unwrap();
        assert!(
            def.starts_with("+proj=utm +zone=25 +south +a=6378137 +rf=298.257222101"),
            "{def}"
        );
        // SIRGAS 2000 / UTM 25S: the same ellipsoid and zone, no shift to WGS 84.
        agree(
            &def,
            "EPSG:31985",
            &[[288_776.25, 9_120_760.75], [500_000.0, 9_000_000.0]],
        );
    }

    /// NAD83 / California zone 3 (ftUS), EPSG:2227, spelled out as GeoKeys: Lambert
    /// conformal conic 2SP, parameters in degrees and US survey feet.
    #[test]
    fn lambert_conformal_conic_in_us_feet() {
        let k = keys(
            &[
                (GT_MODEL_TYPE, 1),
                (GEOGRAPHIC_TYPE, 4269),
                (PROJECTED_CS_TYPE, USER_DEFINED),
                (PROJ_COORD_TRANS, 8),
                (PROJ_LINEAR_UNITS, 9003),
            ],
            &[
                (STD_PARALLEL1, &[38.433_333_333_333_3]),
                (STD_PARALLEL2, &[37.066_666_666_666_7]),
                (FALSE_ORIGIN_LAT, &[36.5]),
                (FALSE_ORIGIN_LONG, &[-120.5]),
                (FALSE_ORIGIN_EASTING, &[6_561_666.667]),
                (FALSE_ORIGIN_NORTHING, &[1_640_416.667]),
            ],
        );
        let def = definition(&k).unwrap().unwrap();
        assert!(
            def.contains("+units=us-ft") && def.contains("+proj=lcc"),
            "{def}"
        );
        agree(
            &def,
            "EPSG:2227",
            &[[6_000_000.0, 2_100_000.0], [6_500_000.0, 1_900_000.0]],
        );
    }

    /// A user-defined geographic CRS: Bessel 1841 by ellipsoid code, Greenwich.
    #[test]
    fn a_user_defined_geographic_crs() {
        let k = keys(
            &[
                (GT_MODEL_TYPE, 2),
                (GEOGRAPHIC_TYPE, USER_DEFINED),
                (GEOG_ELLIPSOID, 7004),
            ],
            &[],
        );
        let def = definition(&k).unwrap().unwrap();
        assert_eq!(def, "+proj=longlat +ellps=bessel +no_defs +type=crs");
        let crs = Crs::from_definition(&def).unwrap();
        assert!(crs.is_geographic());
        assert_eq!(crs.body_radii().unwrap().0, 6_377_397.155);
    }

    #[test]
    fn an_esri_wkt_in_the_citation_is_taken_whole() {
        let mut k = keys(
            &[(GT_MODEL_TYPE, 1), (PROJECTED_CS_TYPE, USER_DEFINED)],
            &[],
        );
        let wkt = r#"PROJCS["WGS_1984_UTM_Zone_32N",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],PARAMETER["False_Easting",500000.0],PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",9.0],PARAMETER["Scale_Factor",0.9996],PARAMETER["Latitude_Of_Origin",0.0],UNIT["Meter",1.0]]"#;
        k.ascii
            .insert(GT_CITATION, format!("ESRI PE String = {wkt}|"));
        let def = definition(&k).unwrap().unwrap();
        assert_eq!(def, wkt);
        agree(&def, "EPSG:32632", &[[420_000.0, 5_150_000.0]]);
        // PROJ identifies it as the EPSG CRS it spells out, as gdalinfo names it.
        assert_eq!(Crs::from_definition(&def).unwrap().epsg(), Some(32632));
    }

    #[test]
    fn what_cannot_be_read_is_named() {
        let k = keys(
            &[
                (GT_MODEL_TYPE, 1),
                (PROJECTED_CS_TYPE, USER_DEFINED),
                (PROJ_COORD_TRANS, 99),
            ],
            &[(GEOG_SEMI_MAJOR, &[6e6])],
        );
        let e = definition(&k).unwrap_err();
        assert!(
            e.contains("99") && e.contains("ProjCoordTransGeoKey"),
            "{e}"
        );
        // An EPSG CRS code is read elsewhere; no keys at all say nothing.
        assert_eq!(
            definition(&keys(&[(GT_MODEL_TYPE, 1), (PROJECTED_CS_TYPE, 2056)], &[])),
            Ok(None)
        );
        assert_eq!(definition(&KeyValues::default()), Ok(None));
    }
}
