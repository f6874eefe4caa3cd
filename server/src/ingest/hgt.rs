//! SRTM `.hgt` tiles: raw big-endian int16, 1201² (3″) or 3601² (1″) samples,
//! row 0 at the north edge, void = −32768. The file name (e.g. `N44W072.hgt`)
//! names the south-west sample; samples are points on a WGS 84 grid.

use super::{RowSource, SampleType, SourceInfo};
use anyhow::{Context, bail};
use std::io::{BufReader, Read};
use std::path::Path;
use tessera_shared::{GeoRef, RasterType};

const VOID: f64 = -32768.0;

pub struct Hgt {
    info: SourceInfo,
    reader: Box<dyn Read + Send>,
    rows_read: u32,
}

impl std::fmt::Debug for Hgt {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Hgt")
            .field("info", &self.info)
            .field("rows_read", &self.rows_read)
            .finish_non_exhaustive()
    }
}

/// Latitude and longitude of the south-west sample from a name like `N44W072`.
fn parse_name(stem: &str) -> Option<(i32, i32)> {
    let s = stem.get(..7)?.to_ascii_uppercase();
    let lat: i32 = s.get(1..3)?.parse().ok()?;
    let lon: i32 = s.get(4..7)?.parse().ok()?;
    let lat = match &s[0..1] {
        "N" => lat,
        "S" => -lat,
        _ => return None,
    };
    let lon = match &s[3..4] {
        "E" => lon,
        "W" => -lon,
        _ => return None,
    };
    ((-90..90).contains(&lat) && (-180..180).contains(&lon)).then_some((lat, lon))
}

impl Hgt {
    pub fn open(path: &Path) -> anyhow::Result<Self> {
        let (file, meta) = super::open_regular(path)?;
        let len = meta.len();
        let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("");
        Self::from_reader(stem, len, BufReader::with_capacity(1 << 16, file))
    }

    /// Reads an SRTM tile of `len` bytes from `reader`; `stem` is its file name
    /// without the extension (e.g. `N44W072`), which names its corner. The side
    /// (1201 or 3601) follows from `len`.
    pub fn from_reader(
        stem: &str,
        len: u64,
        reader: impl Read + Send + 'static,
    ) -> anyhow::Result<Self> {
        let side: u32 = match len {
            2_884_802 => 1201,
            25_934_402 => 3601,
            _ => bail!(
                "SRTM .hgt file is {len} bytes; expected 2884802 (1201², 3″) or 25934402 (3601², 1″)"
            ),
        };
        let (lat, lon) = parse_name(stem).with_context(|| {
            format!("SRTM file name {stem:?} does not name its corner like N44W072")
        })?;
        let step = 1.0 / f64::from(side - 1);
        let georef = GeoRef {
            epsg: Some(4326),
            crs_name: Some("WGS 84".into()),
            proj: None,
            wkt: None,
            // Samples are points: shift the corner of pixel (0, 0) half a sample north-west.
            geotransform: [
                f64::from(lon) - step / 2.0,
                step,
                0.0,
                f64::from(lat + 1) + step / 2.0,
                0.0,
                -step,
            ],
            raster_type: RasterType::PixelIsPoint,
        };
        Ok(Self {
            info: SourceInfo {
                width: side,
                height: side,
                sample_type: SampleType::Int16,
                nodata: Some(VOID),
                georef: Some(georef),
                description: format!("SRTM .hgt {side}×{side} big-endian int16"),
            },
            reader: Box::new(reader),
            rows_read: 0,
        })
    }
}

impl RowSource for Hgt {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    /// SRTM heights are above the EGM96 geoid (SRTM Data Products Description).
    fn vertical_datum(&self) -> Option<tessera_shared::VerticalDatum> {
        Some(tessera_shared::VerticalDatum::Egm96)
    }

    fn datum_clue(&self) -> Option<super::DatumClue> {
        Some(super::DatumClue {
            datum: self.vertical_datum(),
            why: "SRTM .hgt heights are above the EGM96 geoid".into(),
        })
    }

    fn read_rows(&mut self, out: &mut [f32]) -> anyhow::Result<()> {
        let w = self.info.width as usize;
        let mut raw = vec![0u8; 2 * w];
        for row in out.chunks_exact_mut(w) {
            if self.rows_read >= self.info.height {
                bail!("read past the last row {}", self.info.height);
            }
            self.reader
                .read_exact(&mut raw)
                .with_context(|| format!("truncated .hgt at row {}", self.rows_read))?;
            for (o, c) in row.iter_mut().zip(raw.chunks_exact(2)) {
                *o = f32::from(i16::from_be_bytes([c[0], c[1]]));
            }
            self.rows_read += 1;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::testdata;

    #[test]
    fn names_give_the_south_west_corner() {
        assert_eq!(parse_name("N44W072"), Some((44, -72)));
        assert_eq!(parse_name("s12e130"), Some((-12, 130)));
        assert_eq!(parse_name("X44W072"), None);
        assert_eq!(parse_name("N4"), None);
    }

    #[test]
    fn reads_the_white_mountains_tile() {
        let name = "N44W072.hgt";
        let Some(path) = testdata::dem_or_skip(name) else {
            return;
        };
        let f = testdata::facts(name);
        let mut src = Hgt::open(&path).unwrap();
        let g = src.info().georef.clone().unwrap();
        assert_eq!(g.epsg, f.epsg);
        let want = f.extent.unwrap();
        for (got, want) in g.extent(f.width, f.height).iter().zip(want) {
            assert!((got - want).abs() < 1e-9, "{got} vs {want}");
        }
        let mut buf = vec![0.0; (f.width * f.height) as usize];
        src.read_rows(&mut buf).unwrap();
        let lo = buf.iter().copied().fold(f32::MAX, f32::min);
        let hi = buf.iter().copied().fold(f32::MIN, f32::max);
        assert_eq!((f64::from(lo), f64::from(hi)), (f.min, f.max));
        assert!(src.read_rows(&mut buf[..1201]).is_err());
    }
}
