//! Georeferencing given on the command line (`build --crs`, `--bounds`: a 16-bit PNG has
//! no georeferencing of its own, so a sidecar or these flags give it): a [`RowSource`]
//! whose rows are its input's and whose [`GeoRef`] is the one the flags assign. Nothing
//! is resampled: `--crs` relabels the coordinates, `--bounds` places the pixels
//! (reprojection is `--to`, which then starts from this georeferencing).

use super::{RowSource, SourceInfo};
use crate::crs::Crs;
use anyhow::{anyhow, bail};
use tessera_shared::{GeoRef, RasterType};

/// The outer edges of a raster's pixels (pixel-is-area) in its CRS's units, as
/// `--bounds W,S,E,N` gives them: GDAL's `-a_ullr ulx uly lrx lry` in W,S,E,N order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    pub west: f64,
    pub south: f64,
    pub east: f64,
    pub north: f64,
}

impl Bounds {
    /// Checked bounds: finite, `west < east`, `south < north`.
    pub fn new(west: f64, south: f64, east: f64, north: f64) -> anyhow::Result<Self> {
        for (name, v) in [
            ("west", west),
            ("south", south),
            ("east", east),
            ("north", north),
        ] {
            if !v.is_finite() {
                bail!("{name} is {v}, not a finite number");
            }
        }
        if west >= east {
            bail!("west {west} is not less than east {east}");
        }
        if south >= north {
            bail!("south {south} is not less than north {north}");
        }
        Ok(Self {
            west,
            south,
            east,
            north,
        })
    }

    /// GDAL's geotransform for a `width × height` raster filling these bounds:
    /// `[W, (E − W)/width, 0, N, 0, −(N − S)/height]`.
    pub fn geotransform(&self, width: u32, height: u32) -> [f64; 6] {
        [
            self.west,
            (self.east - self.west) / f64::from(width),
            0.0,
            self.north,
            0.0,
            -(self.north - self.south) / f64::from(height),
        ]
    }
}

impl std::str::FromStr for Bounds {
    type Err = anyhow::Error;

    /// `W,S,E,N`: four numbers separated by commas (spaces around them allowed).
    fn from_str(s: &str) -> anyhow::Result<Self> {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        let [w, so, e, n] = parts.as_slice() else {
            bail!(
                "want 4 numbers W,S,E,N separated by commas, got {} ({s:?})",
                parts.len()
            );
        };
        let num = |name: &str, v: &str| -> anyhow::Result<f64> {
            v.parse()
                .map_err(|_| anyhow!("{name} {v:?} is not a number (want W,S,E,N)"))
        };
        Self::new(
            num("west", w)?,
            num("south", so)?,
            num("east", e)?,
            num("north", n)?,
        )
    }
}

/// A row source with the georeferencing `--crs`/`--bounds` gave it.
#[derive(Debug)]
pub struct Assigned {
    inner: Box<dyn RowSource>,
    info: SourceInfo,
}

impl RowSource for Assigned {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn read_rows(&mut self, out: &mut [f32]) -> anyhow::Result<()> {
        self.inner.read_rows(out)
    }

    fn skip_rows(&mut self, n: u32) -> anyhow::Result<()> {
        self.inner.skip_rows(n)
    }

    fn set_window(&mut self, columns: &[std::ops::Range<u32>], until: u32) -> anyhow::Result<()> {
        self.inner.set_window(columns, until)
    }

    fn input_windows(&self) -> Vec<(std::path::PathBuf, [u32; 4])> {
        self.inner.input_windows()
    }

    fn buffer_bytes(&self) -> u64 {
        self.inner.buffer_bytes()
    }

    fn vertical_datum(&self) -> Option<tessera_shared::VerticalDatum> {
        self.inner.vertical_datum()
    }

    fn datum_clue(&self) -> Option<super::DatumClue> {
        self.inner.datum_clue()
    }
}

/// How a GeoRef's CRS reads in messages, or `None` when it names none.
fn crs_text(g: &GeoRef) -> Option<String> {
    g.crs()
        .or_else(|| g.crs_name.clone())
        .or_else(|| g.proj.clone())
}

/// Gives `rows` the georeferencing `crs` and `bounds` ask for (`None` for both: `rows`
/// unchanged). `crs` replaces the input's own CRS, `bounds` its geotransform, each
/// with a warning naming what it overrides; the errors say what is missing: `--bounds`
/// with no CRS (the input's or `crs`), `crs` with no geotransform (the input's or
/// `bounds`). `label` names the input in warnings (the caller adds it to errors).
pub fn assign(
    rows: Box<dyn RowSource>,
    crs: Option<&Crs>,
    bounds: Option<Bounds>,
    label: &str,
) -> anyhow::Result<Box<dyn RowSource>> {
    if crs.is_none() && bounds.is_none() {
        return Ok(rows);
    }
    let mut info = rows.info().clone();
    info.georef = Some(georef(
        info.georef.as_ref(),
        crs,
        bounds,
        info.width,
        info.height,
        label,
    )?);
    Ok(Box::new(Assigned { inner: rows, info }))
}

/// The GeoRef of a `width × height` raster whose own is `own`, with `crs` and
/// `bounds` applied (see [`assign`]).
pub fn georef(
    own: Option<&GeoRef>,
    crs: Option<&Crs>,
    bounds: Option<Bounds>,
    width: u32,
    height: u32,
    label: &str,
) -> anyhow::Result<GeoRef> {
    let own_crs = own.and_then(crs_text);
    let (geotransform, raster_type) = match (bounds, own) {
        (Some(b), own) => {
            if let Some(g) = own {
                tracing::warn!(
                    input = label,
                    "--bounds {},{},{},{} overrides the input's own geotransform {:?}",
                    b.west,
                    b.south,
                    b.east,
                    b.north,
                    g.geotransform
                );
            }
            (b.geotransform(width, height), RasterType::PixelIsArea)
        }
        (None, Some(g)) => (g.geotransform, g.raster_type),
        (None, None) => bail!(
            "--crs needs a geotransform, and this input has none (a PNG carries no \
             georeferencing): give --bounds W,S,E,N too"
        ),
    };
    let out = match (crs, own) {
        (Some(c), _) => {
            if let Some(old) = &own_crs {
                let same = c.epsg().is_some() && c.epsg() == own.and_then(|g| g.epsg);
                if !same {
                    tracing::warn!(
                        input = label,
                        "--crs {} overrides the input's own CRS {old}",
                        c.epsg()
                            .map_or_else(|| c.proj_string().to_string(), |e| format!("EPSG:{e}"))
                    );
                }
            }
            let mut g = GeoRef {
                epsg: c.epsg(),
                crs_name: None,
                proj: None,
                wkt: None,
                geotransform,
                raster_type,
            };
            c.describe(&mut g);
            g
        }
        (None, Some(g)) if own_crs.is_some() => GeoRef {
            geotransform,
            raster_type,
            ..g.clone()
        },
        (None, _) => bail!(
            "--bounds needs a CRS, and this input has none: give --crs EPSG:CODE or a PROJ \
             string (e.g. '+proj=longlat +R=1737400 +no_defs' for the Moon)"
        ),
    };
    // Latitudes past the poles are a mistake (swapped axes, degrees for metres).
    let geographic = crs.map_or_else(
        || Crs::of(&out).is_some_and(|c| c.is_geographic()),
        Crs::is_geographic,
    );
    if geographic && bounds.is_some() {
        let [_, south, _, north] = out.extent(width, height);
        if south < -90.0 || north > 90.0 {
            bail!(
                "--bounds: latitudes {south}..{north} go past the poles of the geographic CRS \
                 (want −90 ≤ S < N ≤ 90; the order is W,S,E,N)"
            );
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::RasterType;

    const MOON: &str = "+proj=longlat +R=1737400 +no_defs";

    fn tiff_georef() -> GeoRef {
        GeoRef {
            epsg: Some(32632),
            crs_name: Some("WGS 84 / UTM zone 32N".into()),
            proj: None,
            wkt: None,
            geotransform: [400_000.0, 10.0, 0.0, 5_200_000.0, 0.0, -10.0],
            raster_type: RasterType::PixelIsPoint,
        }
    }

    #[test]
    fn bounds_parse_and_say_what_is_wrong() {
        let b: Bounds = "51, 8.9921875,67,24.9921875".parse().unwrap();
        assert_eq!(
            b,
            Bounds {
                west: 51.0,
                south: 8.992_187_5,
                east: 67.0,
                north: 24.992_187_5
            }
        );
        let neg: Bounds = "-10,-5.5,10,5.5".parse().unwrap();
        assert_eq!((neg.west, neg.south), (-10.0, -5.5));
        let err = |s: &str| s.parse::<Bounds>().unwrap_err().to_string();
        assert!(err("1,2,3").contains("want 4 numbers"), "{}", err("1,2,3"));
        assert!(err("1,2,3,4,5").contains("got 5"), "{}", err("1,2,3,4,5"));
        assert!(err("1,x,3,4").contains("south \"x\""), "{}", err("1,x,3,4"));
        assert!(
            err("1,NaN,3,4").contains("south is NaN"),
            "{}",
            err("1,NaN,3,4")
        );
        assert!(
            err("inf,0,3,4").contains("west is inf"),
            "{}",
            err("inf,0,3,4")
        );
        assert!(err("3,0,3,4").contains("west 3 is not less than east 3"));
        assert!(err("0,5,3,4").contains("south 5 is not less than north 4"));
    }

    #[test]
    fn bounds_are_the_outer_pixel_edges() {
        let b = Bounds::new(51.0, 8.992_187_5, 67.0, 24.992_187_5).unwrap();
        let step = 1.0 / 256.0;
        assert_eq!(
            b.geotransform(4096, 4096),
            [51.0, step, 0.0, 24.992_187_5, 0.0, -step]
        );
        let g = georef(
            None,
            Some(&Crs::parse(MOON).unwrap()),
            Some(b),
            4096,
            4096,
            "t",
        )
        .unwrap();
        assert_eq!(
            g.extent(4096, 4096),
            [51.0, 8.992_187_5, 67.0, 24.992_187_5]
        );
        assert_eq!(g.raster_type, RasterType::PixelIsArea);
        // PROJ's own spelling of the definition, and a WKT GDAL and QGIS read.
        assert_eq!(g.proj.as_deref(), Some(&*format!("{MOON} +type=crs")));
        assert_eq!(g.epsg, None);
        assert!(
            g.wkt.as_deref().is_some_and(|w| w.contains("1737400")),
            "{:?}",
            g.wkt
        );
    }

    #[test]
    fn crs_replaces_the_inputs_own_and_keeps_its_grid() {
        let own = tiff_georef();
        let utm33 = Crs::parse("EPSG:32633").unwrap();
        let g = georef(Some(&own), Some(&utm33), None, 100, 100, "t").unwrap();
        assert_eq!(g.epsg, Some(32633));
        assert_eq!(g.crs_name.as_deref(), Some("WGS 84 / UTM zone 33N"));
        assert!(g.proj.as_deref().unwrap().contains("+zone=33"));
        assert!(g.wkt.is_some());
        assert_eq!(g.geotransform, own.geotransform);
        assert_eq!(g.raster_type, RasterType::PixelIsPoint);
    }

    #[test]
    fn bounds_replace_the_inputs_own_grid_and_keep_its_crs() {
        let own = tiff_georef();
        let b = Bounds::new(0.0, 0.0, 1000.0, 500.0).unwrap();
        let g = georef(Some(&own), None, Some(b), 100, 50, "t").unwrap();
        assert_eq!(g.geotransform, [0.0, 10.0, 0.0, 500.0, 0.0, -10.0]);
        assert_eq!(g.raster_type, RasterType::PixelIsArea);
        assert_eq!((g.epsg, g.crs_name), (own.epsg, own.crs_name));
    }

    #[test]
    fn missing_halves_are_errors_that_say_what_to_add() {
        let b = Bounds::new(0.0, 0.0, 1.0, 1.0).unwrap();
        let e = georef(None, None, Some(b), 10, 10, "t")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--bounds needs a CRS") && e.contains("--crs"),
            "{e}"
        );
        // A geotransform without any CRS is no CRS either.
        let bare = GeoRef {
            epsg: None,
            crs_name: None,
            ..tiff_georef()
        };
        let e = georef(Some(&bare), None, Some(b), 10, 10, "t")
            .unwrap_err()
            .to_string();
        assert!(e.contains("--bounds needs a CRS"), "{e}");
        let moon = Crs::parse(MOON).unwrap();
        let e = georef(None, Some(&moon), None, 10, 10, "t")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--crs needs a geotransform") && e.contains("--bounds"),
            "{e}"
        );
        // But a bare geotransform takes a CRS.
        let g = georef(Some(&bare), Some(&moon), None, 10, 10, "t").unwrap();
        assert_eq!(g.proj.as_deref(), Some(&*format!("{MOON} +type=crs")));
    }

    #[test]
    fn geographic_bounds_stay_between_the_poles() {
        let wgs84 = Crs::parse("EPSG:4326").unwrap();
        let b = Bounds::new(500_000.0, 4_000_000.0, 510_000.0, 4_010_000.0).unwrap();
        let e = georef(None, Some(&wgs84), Some(b), 10, 10, "t")
            .unwrap_err()
            .to_string();
        assert!(e.contains("past the poles"), "{e}");
        // Metres are fine in a projected CRS.
        let utm = Crs::parse("EPSG:32632").unwrap();
        assert!(georef(None, Some(&utm), Some(b), 10, 10, "t").is_ok());
    }
}
