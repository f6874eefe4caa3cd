//! Heights converted between vertical datums at ingest (`build --to-vertical`;
//! DECISIONS.md "Vertical datums at ingest"): a [`RowSource`] that adds, to every
//! sample, the difference between the two datums' surfaces at that sample, as PROJ
//! computes it with compound CRSs — WGS 84 with EGM96 heights (`EPSG:4326+5773`),
//! with EGM2008 heights (`EPSG:4326+3855`), or ellipsoidal (`EPSG:4979`) — through
//! the geoid grids PROJ finds (`proj-data` ships EGM96's `egm96_15.gtx`). That is what
//! `cs2cs EPSG:4326+5773 EPSG:4979` does, sample for sample.
//!
//! Each sample's position is its centre in the input's CRS, carried to WGS 84 (one
//! PROJ call per row), then through the vertical transformation (another).

use super::{DatumClue, RowSource, SampleType, SourceInfo};
use crate::crs::Crs;
use anyhow::{Context, anyhow, bail};
use tessera_shared::{GeoRef, VerticalDatum};

/// The compound CRS PROJ converts a datum's heights with (WGS 84 horizontally).
fn compound(datum: VerticalDatum) -> Option<&'static str> {
    match datum {
        VerticalDatum::Egm96 => Some("EPSG:4326+5773"),
        VerticalDatum::Egm2008 => Some("EPSG:4326+3855"),
        VerticalDatum::Ellipsoid => Some("EPSG:4979"),
        VerticalDatum::Unknown => None,
    }
}

/// The grid PROJ needs for a datum's heights, and where to get it, for the error
/// when it is missing.
fn grid_hint(datum: VerticalDatum) -> &'static str {
    match datum {
        VerticalDatum::Egm96 => {
            "EGM96 needs egm96_15.gtx (Debian/Ubuntu: apt-get install proj-data)"
        }
        VerticalDatum::Egm2008 => {
            "EGM2008 needs us_nga_egm08_25.tif, which Debian's proj-data does not ship: \
             download https://cdn.proj.org/us_nga_egm08_25.tif into /usr/share/proj or \
             ~/.local/share/proj (or set PROJ_DATA)"
        }
        _ => "",
    }
}

/// A source whose heights are moved from one vertical datum to another.
pub struct VerticalShift {
    inner: Box<dyn RowSource>,
    info: SourceInfo,
    from: VerticalDatum,
    to: VerticalDatum,
    horizontal: Crs,
    source_vertical: Crs,
    target_vertical: Crs,
    wgs84: Crs,
    /// Raw units per metre: the shift in metres over `--scale`.
    per_metre: f64,
    /// Raw values that mean no-data, left as they are.
    nodata: Vec<f32>,
    row: u32,
    points: Vec<[f64; 3]>,
    /// The columns read ([`RowSource::set_window`]): only they are converted.
    columns: Vec<std::ops::Range<u32>>,
}

impl std::fmt::Debug for VerticalShift {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VerticalShift")
            .field("from", &self.from)
            .field("to", &self.to)
            .field("inner", &self.inner)
            .finish_non_exhaustive()
    }
}

impl VerticalShift {
    /// Wraps `inner` (heights in `from`, raw values `scale` metres each, `nodata`
    /// raw values besides its own no-data left alone) so that its heights are in `to`. Checked before any sample is read: the input is
    /// georeferenced in a CRS PROJ knows, both datums are known, and PROJ has the
    /// grids (one transformation at the input's centre must succeed).
    pub fn new(
        inner: Box<dyn RowSource>,
        from: VerticalDatum,
        to: VerticalDatum,
        scale: f64,
        nodata: &[f32],
    ) -> anyhow::Result<Self> {
        let info = inner.info().clone();
        let mut nodata = nodata.to_vec();
        nodata.extend(info.nodata.map(|v| v as f32));
        let georef: &GeoRef = info
            .georef
            .as_ref()
            .ok_or_else(|| anyhow!("--to-vertical needs a georeferenced input"))?;
        let horizontal = Crs::of(georef).ok_or_else(|| {
            anyhow!("--to-vertical needs the input's CRS, which PROJ does not know")
        })?;
        let def = |d: VerticalDatum| {
            compound(d).ok_or_else(|| {
                anyhow!(
                    "the heights' vertical datum is unknown, so they cannot be converted to \
                     {}: say what they are with --vertical-datum",
                    to.name()
                )
            })
        };
        let source_vertical = Crs::from_definition(def(from)?)?;
        let target_vertical = Crs::from_definition(def(to)?)?;
        let mut me = Self {
            inner,
            info: SourceInfo {
                sample_type: SampleType::Float32,
                description: format!(
                    "{}, heights {} → {}",
                    info.description,
                    from.name(),
                    to.name()
                ),
                ..info.clone()
            },
            from,
            to,
            horizontal,
            source_vertical,
            target_vertical,
            wgs84: Crs::from_epsg(4326)?,
            per_metre: 1.0 / scale,
            nodata,
            row: 0,
            points: Vec::new(),
            columns: Vec::new(),
        };
        // One point at the centre: a missing grid is an error now, not NaN heights later.
        let centre = me.shifts_at(info.height / 2, info.width / 2..info.width / 2 + 1);
        match centre {
            Ok(()) if me.points[0][2].is_finite() => Ok(me),
            _ => {
                let hint = [from, to]
                    .into_iter()
                    .map(grid_hint)
                    .filter(|h| !h.is_empty())
                    .collect::<Vec<_>>()
                    .join("; ");
                bail!(
                    "PROJ cannot convert heights from {} to {} here ({}){}",
                    from.name(),
                    to.name(),
                    centre
                        .err()
                        .map_or_else(|| "no result".into(), |e| format!("{e:#}")),
                    if hint.is_empty() {
                        String::new()
                    } else {
                        format!(": {hint}")
                    }
                );
            }
        }
    }

    /// Leaves in `points[k][2]` the shift in metres (target height − source height)
    /// at the centre of sample `cols.start + k` of row `row`.
    fn shifts_at(&mut self, row: u32, cols: std::ops::Range<u32>) -> anyhow::Result<()> {
        let georef = self.info.georef.as_ref().expect("checked in new");
        self.points.clear();
        self.points.extend(cols.map(|c| {
            let [x, y] = georef.sample_centre(f64::from(c), f64::from(row));
            [x, y, 0.0]
        }));
        self.horizontal
            .transform_points(&self.wgs84, &mut self.points)
            .context("sample positions to WGS 84")?;
        self.source_vertical
            .transform_points_exactly(&self.target_vertical, &mut self.points)
    }
}

impl RowSource for VerticalShift {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn read_rows(&mut self, out: &mut [f32]) -> anyhow::Result<()> {
        self.inner.read_rows(out)?;
        let w = self.info.width as usize;
        let mut columns = std::mem::take(&mut self.columns);
        let whole = columns.is_empty();
        if whole {
            columns.push(0..self.info.width);
        }
        let spans = &columns[..];
        for line in out.chunks_exact_mut(w) {
            for span in spans {
                self.shifts_at(self.row, span.clone()).with_context(|| {
                    format!(
                        "converting row {} from {} to {}",
                        self.row,
                        self.from.name(),
                        self.to.name()
                    )
                })?;
                let part = &mut line[span.start as usize..span.end as usize];
                for (v, p) in part.iter_mut().zip(&self.points) {
                    // No-data stays as it is; a sample PROJ cannot place becomes NaN
                    // (no-data too).
                    if !self.nodata.contains(v) {
                        *v = (f64::from(*v) + p[2] * self.per_metre) as f32;
                    }
                }
            }
            self.row += 1;
        }
        if !whole {
            self.columns = columns;
        }
        Ok(())
    }

    fn skip_rows(&mut self, n: u32) -> anyhow::Result<()> {
        self.inner.skip_rows(n)?;
        self.row += n;
        Ok(())
    }

    fn set_window(&mut self, columns: &[std::ops::Range<u32>], until: u32) -> anyhow::Result<()> {
        self.inner.set_window(columns, until)?;
        self.columns = columns.to_vec();
        Ok(())
    }

    fn input_windows(&self) -> Vec<(std::path::PathBuf, [u32; 4])> {
        self.inner.input_windows()
    }

    fn buffer_bytes(&self) -> u64 {
        self.inner.buffer_bytes() + u64::from(self.info.width) * (24 + 8 + 4)
    }

    fn vertical_datum(&self) -> Option<VerticalDatum> {
        Some(self.to)
    }

    fn datum_clue(&self) -> Option<DatumClue> {
        Some(DatumClue {
            datum: Some(self.to),
            why: format!("converted from {} with --to-vertical", self.from.name()),
        })
    }
}

/// What the build was told about heights' vertical datums: for every input
/// (`--vertical-datum DATUM`), for inputs whose file name matches a pattern
/// (`--vertical-datum 'PATTERN=DATUM'`), and the datum to convert them all to
/// (`--to-vertical`).
#[derive(Clone, Debug, Default)]
pub struct VerticalOptions {
    pub all: Option<VerticalDatum>,
    /// `(pattern, datum)`: the first pattern that matches an input's file name (or its
    /// whole path) gives its datum, before `all`.
    pub per_input: Vec<(glob::Pattern, VerticalDatum)>,
    pub to: Option<VerticalDatum>,
    /// Metres per raw unit (`--scale`), to convert shifts in metres to raw units.
    pub scale: f64,
}

impl VerticalOptions {
    /// The datum of the input at `path`: the user's (a pattern, then the flag for
    /// all inputs) over what the input states (`clue`).
    pub fn datum_for(&self, path: &std::path::Path, clue: Option<DatumClue>) -> Option<DatumClue> {
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
        let full = path.to_string_lossy();
        if let Some((p, d)) = self
            .per_input
            .iter()
            .find(|(p, _)| name.as_deref().is_some_and(|n| p.matches(n)) || p.matches(&full))
        {
            return Some(DatumClue {
                datum: Some(*d),
                why: format!("--vertical-datum '{}={}'", p.as_str(), d.name()),
            });
        }
        if let Some(d) = self.all {
            return Some(DatumClue {
                datum: Some(d),
                why: "--vertical-datum".into(),
            });
        }
        clue
    }

    /// Converts `reader` (the input at `name`, whose datum is `clue`) to `self.to` when
    /// it is in another datum; `nodata` raw values are left alone.
    pub fn convert(
        &self,
        reader: Box<dyn RowSource>,
        name: &str,
        clue: Option<&DatumClue>,
        nodata: &[f32],
    ) -> anyhow::Result<Box<dyn RowSource>> {
        let Some(to) = self.to else {
            return Ok(reader);
        };
        let from = clue.and_then(|c| c.datum).unwrap_or_default();
        if from == to {
            return Ok(reader);
        }
        if from == VerticalDatum::Unknown {
            bail!(
                "{name}: its heights' vertical datum is unknown ({}), so they cannot be \
                 converted to {}: give it with --vertical-datum (for this input only: \
                 --vertical-datum 'FILE=egm96')",
                clue.map_or("it states none", |c| c.why.as_str()),
                to.name()
            );
        }
        Ok(Box::new(
            VerticalShift::new(reader, from, to, self.scale, nodata)
                .with_context(|| name.to_string())?,
        ))
    }
}

/// Parses a `--vertical-datum` value: `DATUM` or `PATTERN=DATUM`.
pub fn parse_vertical_arg(s: &str) -> Result<(Option<glob::Pattern>, VerticalDatum), String> {
    let (pattern, datum) = match s.rsplit_once('=') {
        Some((p, d)) => (Some(p.trim()), d.trim()),
        None => (None, s.trim()),
    };
    let datum = match datum.to_ascii_lowercase().as_str() {
        "egm96" => VerticalDatum::Egm96,
        "egm2008" => VerticalDatum::Egm2008,
        "ellipsoid" => VerticalDatum::Ellipsoid,
        "unknown" => VerticalDatum::Unknown,
        other => {
            return Err(format!(
                "{other:?} is not a vertical datum (egm96, egm2008, ellipsoid or unknown)"
            ));
        }
    };
    let pattern = pattern
        .map(|p| {
            if p.is_empty() {
                return Err(format!("{s:?}: the file pattern before '=' is empty"));
            }
            glob::Pattern::new(p).map_err(|e| format!("{p:?} is not a file pattern: {e}"))
        })
        .transpose()?;
    Ok((pattern, datum))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vertical_datum_arguments_name_a_datum_and_maybe_files() {
        assert_eq!(
            parse_vertical_arg("egm96").unwrap(),
            (None, VerticalDatum::Egm96)
        );
        let (p, d) = parse_vertical_arg("swiss*.tif=ellipsoid").unwrap();
        assert!(p.unwrap().matches("swiss_dtm_2.tif") && d == VerticalDatum::Ellipsoid);
        assert!(parse_vertical_arg("navd88").unwrap_err().contains("navd88"));
        assert!(parse_vertical_arg("=egm96").unwrap_err().contains("empty"));
        assert!(
            parse_vertical_arg("[=egm96")
                .unwrap_err()
                .contains("not a file pattern")
        );
    }

    #[test]
    fn the_users_datum_for_an_input_wins_over_what_it_states() {
        let o = VerticalOptions {
            all: Some(VerticalDatum::Egm96),
            per_input: vec![(
                glob::Pattern::new("lidar*").unwrap(),
                VerticalDatum::Ellipsoid,
            )],
            to: None,
            scale: 1.0,
        };
        let stated = Some(DatumClue {
            datum: Some(VerticalDatum::Egm2008),
            why: "file name".into(),
        });
        let p = std::path::Path::new("/data/lidar_07.tif");
        assert_eq!(
            o.datum_for(p, stated.clone()).unwrap().datum,
            Some(VerticalDatum::Ellipsoid)
        );
        let q = std::path::Path::new("/data/srtm.tif");
        assert_eq!(
            o.datum_for(q, stated.clone()).unwrap().datum,
            Some(VerticalDatum::Egm96)
        );
        let none = VerticalOptions::default();
        assert_eq!(none.datum_for(q, stated.clone()), stated);
    }
}
