//! The vertical datum a build records (DECISIONS.md "Real clients"): `--vertical-datum`
//! if given, else what the input states ([`ingest::RowSource::datum_clue`]), else
//! `unknown`. The build says what it decided: an info line naming the datum and where the
//! input states it; and, for unknown heights on Earth, a warning that Cesium terrain will
//! serve them as ellipsoidal, with the size of that error (the EGM96 geoid undulation
//! over the dataset, from the grid the server uses, [`crate::geoid`]) and the flag that
//! fixes it. The warning is returned, not logged: the command prints it once the
//! build has succeeded, also under `--quiet` (a failed build prints only its error).

use crate::crs::Crs;
use crate::ingest::{self, DatumClue};
use tessera_shared::{GeoRef, VerticalDatum};

/// Points per side of the footprint where the undulation is sampled.
const GRID: u32 = 5;

/// What the build records, and the warning to print when the heights' datum is unknown.
#[derive(Debug)]
pub(super) struct Decision {
    pub(super) datum: VerticalDatum,
    pub(super) warning: Option<String>,
}

/// Decides the datum of `source` (named `label`): `flag` wins, then its clue. A
/// warning only for unknown heights with a footprint on Earth.
pub(super) fn decide(flag: Option<VerticalDatum>, source: &ingest::Input, label: &str) -> Decision {
    let (clue, georef, size) = match source {
        ingest::Input::Rows(r) => (
            r.datum_clue(),
            r.info().georef.clone(),
            (r.info().width, r.info().height),
        ),
        ingest::Input::Synthetic(_) => (None, None, (0, 0)),
    };
    decide_for(flag, clue, label, georef.as_ref(), size, geoid)
}

/// [`decide`] with the input's facts and the geoid lookup passed in (for tests).
fn decide_for(
    flag: Option<VerticalDatum>,
    clue: Option<DatumClue>,
    label: &str,
    georef: Option<&GeoRef>,
    (width, height): (u32, u32),
    geoid: impl FnOnce() -> Option<crate::geoid::Geoid>,
) -> Decision {
    let stated = clue
        .as_ref()
        .and_then(|c| c.datum.map(|d| (d, c.why.as_str())));
    if let Some(datum) = flag {
        match stated {
            Some((d, why)) if d != datum => tracing::warn!(
                "{label}: --vertical-datum {} overrides the input's own {} ({why})",
                datum.name(),
                d.name()
            ),
            _ => tracing::info!(
                "{label}: vertical datum {} (--vertical-datum)",
                datum.name()
            ),
        }
        return Decision {
            datum,
            warning: None,
        };
    }
    if let Some((datum, why)) = stated {
        tracing::info!("{label}: vertical datum {} ({why})", datum.name());
        return Decision {
            datum,
            warning: None,
        };
    }
    let warning = georef
        .and_then(|g| footprint(g, width, height))
        .map(|points| {
            let why = clue.map_or_else(|| "the input states none".to_string(), |c| c.why);
            unknown_warning(label, &why, &error_text(&points, geoid()))
        });
    Decision {
        datum: VerticalDatum::Unknown,
        warning,
    }
}

/// The grid the server finds (`--geoid` aside: `$TESSERA_GEOID`, then proj-data's
/// `egm96_15.gtx`), when it opens.
fn geoid() -> Option<crate::geoid::Geoid> {
    let path = crate::geoid::find(None)?;
    crate::geoid::Geoid::open(&path)
        .inspect_err(|e| tracing::debug!("no geoid for the datum warning: {e:#}"))
        .ok()
}

/// WGS 84 longitude/latitude of a `GRID`×`GRID` lattice of samples over the raster,
/// corners included, or `None` when it is not a footprint on Earth: no CRS the
/// projection library knows, another body's ellipsoid, or points that do not transform.
fn footprint(georef: &GeoRef, width: u32, height: u32) -> Option<Vec<[f64; 2]>> {
    let crs = Crs::of(georef)?;
    if !crs.is_earth() || width == 0 || height == 0 {
        return None;
    }
    let at = |i: u32, n: u32| f64::from(i) * f64::from(n - 1) / f64::from(GRID - 1);
    let mut points = Vec::new();
    for j in 0..GRID {
        for i in 0..GRID {
            let [x, y] = georef.sample_centre(at(i, width), at(j, height));
            let [lon, lat] = crs.to_lon_lat(x, y).ok()?;
            if !(lon.is_finite() && lat.is_finite() && lat.abs() <= 90.0) {
                return None;
            }
            points.push([lon, lat]);
        }
    }
    Some(points)
}

/// How far off ellipsoidal serving puts heights above mean sea level: the EGM96
/// undulation N over `points` (served h = H where the true h is H + N).
fn error_text(points: &[[f64; 2]], geoid: Option<crate::geoid::Geoid>) -> String {
    let range = geoid.and_then(|g| {
        let n: Vec<f64> = points
            .iter()
            .map(|&[lon, lat]| g.undulation(lon, lat))
            .filter(|n| n.is_finite())
            .collect();
        let lo = n.iter().copied().reduce(f64::min)?;
        let hi = n.iter().copied().reduce(f64::max)?;
        Some((lo, hi))
    });
    let Some((lo, hi)) = range else {
        return "up to ~100 m off (no EGM96 geoid grid was found to say how far here: install \
                proj-data or set TESSERA_GEOID)"
            .into();
    };
    let span = |a: f64, b: f64| {
        if (b - a).abs() < 0.05 {
            format!("{a:.1} m")
        } else {
            format!("{a:.1}..{b:.1} m")
        }
    };
    let off = if lo >= 0.0 {
        format!("{} too low", span(lo, hi))
    } else if hi <= 0.0 {
        format!("{} too high", span(-hi, -lo))
    } else {
        format!("between {lo:.1} and {hi:+.1} m off")
    };
    format!("{off} (the EGM96 geoid undulation over the dataset)")
}

fn unknown_warning(label: &str, why: &str, error: &str) -> String {
    format!(
        "{label}: the heights' vertical datum is unknown ({why}): Cesium terrain will serve them \
         as heights above the WGS 84 ellipsoid, so if they are above mean sea level the terrain \
         sits {error}; say what they are with --vertical-datum egm96 (sea-level heights: SRTM, \
         ASTER, ALOS, and national DEMs to within a few metres), --vertical-datum egm2008 \
         (Copernicus DEM) or --vertical-datum ellipsoid"
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::RasterType;

    fn wgs84(lon0: f64, lat0: f64, step: f64) -> GeoRef {
        GeoRef {
            epsg: Some(4326),
            crs_name: None,
            proj: None,
            wkt: None,
            geotransform: [lon0, step, 0.0, lat0, 0.0, -step],
            raster_type: RasterType::PixelIsArea,
        }
    }

    fn clue(datum: Option<VerticalDatum>, why: &str) -> DatumClue {
        DatumClue {
            datum,
            why: why.into(),
        }
    }

    /// A grid of constant undulation `n` over the whole Earth.
    fn flat_geoid(n: f32) -> crate::geoid::Geoid {
        let mut b = Vec::new();
        for v in [-90.0f64, -180.0, 90.0, 90.0] {
            b.extend(v.to_be_bytes());
        }
        b.extend(3i32.to_be_bytes());
        b.extend(4i32.to_be_bytes());
        for _ in 0..12 {
            b.extend(n.to_be_bytes());
        }
        crate::geoid::Geoid::from_bytes("flat", &b).unwrap()
    }

    #[test]
    fn a_stated_datum_is_recorded_without_a_warning() {
        let g = wgs84(8.0, 47.0, 0.01);
        let d = decide_for(
            None,
            Some(clue(Some(VerticalDatum::Egm96), "x")),
            "a.tif",
            Some(&g),
            (100, 100),
            || panic!("no geoid needed"),
        );
        assert_eq!(d.datum, VerticalDatum::Egm96);
        assert!(d.warning.is_none());
    }

    #[test]
    fn the_flag_overrides_what_the_input_states() {
        let g = wgs84(8.0, 47.0, 0.01);
        for stated in [
            None,
            Some(clue(Some(VerticalDatum::Egm96), "x")),
            Some(clue(None, "y")),
        ] {
            let d = decide_for(
                Some(VerticalDatum::Ellipsoid),
                stated,
                "a.tif",
                Some(&g),
                (100, 100),
                || panic!("no geoid needed"),
            );
            assert_eq!(d.datum, VerticalDatum::Ellipsoid);
            assert!(d.warning.is_none());
        }
    }

    #[test]
    fn unknown_heights_on_earth_get_a_warning_with_the_error() {
        let g = wgs84(8.0, 47.0, 0.01);
        let d = decide_for(None, None, "a.tif", Some(&g), (100, 100), || {
            Some(flat_geoid(48.25))
        });
        assert_eq!(d.datum, VerticalDatum::Unknown);
        let w = d.warning.expect("a warning");
        assert!(
            w.starts_with("a.tif: the heights' vertical datum is unknown (the input states none)"),
            "{w}"
        );
        assert!(
            w.contains("48.2 m too low") || w.contains("48.3 m too low"),
            "{w}"
        );
        assert!(w.contains("--vertical-datum egm96"), "{w}");

        // What the input named instead is passed on; no grid: the bound.
        let d = decide_for(
            None,
            Some(clue(
                None,
                "GeoTIFF VerticalCSTypeGeoKey 5703 (NAVD88 height)",
            )),
            "b.tif",
            Some(&g),
            (100, 100),
            || None,
        );
        let w = d.warning.expect("a warning");
        assert!(
            w.contains("(GeoTIFF VerticalCSTypeGeoKey 5703 (NAVD88 height))"),
            "{w}"
        );
        assert!(w.contains("up to ~100 m off"), "{w}");

        // Negative undulations make the terrain too high.
        assert!(error_text(&[[0.0, 0.0]], Some(flat_geoid(-30.0))).starts_with("30.0 m too high"),);
    }

    #[test]
    fn no_warning_without_a_footprint_on_earth() {
        let moon = GeoRef {
            epsg: None,
            proj: Some("+proj=longlat +R=1737400 +no_defs".into()),
            ..wgs84(8.0, 47.0, 0.01)
        };
        let unknown_crs = GeoRef {
            epsg: None,
            ..wgs84(8.0, 47.0, 0.01)
        };
        for g in [Some(&moon), Some(&unknown_crs), None] {
            let d = decide_for(None, None, "m.png", g, (100, 100), || {
                panic!("no geoid needed")
            });
            assert_eq!(d.datum, VerticalDatum::Unknown);
            assert!(d.warning.is_none(), "{g:?}");
        }
    }
}
