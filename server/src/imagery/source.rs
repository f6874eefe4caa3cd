//! The image an imagery pyramid is made from: a GeoTIFF of any band count (8- or
//! 16-bit unsigned, pixel-interleaved, any compression the `tiff` crate reads), or
//! a PNG/JPEG georeferenced by a world file and a `.prj` beside it.
//!
//! Unlike a DEM, the image is held whole in memory as its stored samples (u8 or u16):
//! imagery pyramids drape DEMs, and an image of the DEM's ground at a few times its
//! resolution is tens to hundreds of MB at most (DECISIONS "Imagery pyramids").

use crate::crs::Crs;
use anyhow::{Context, anyhow, bail};
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use tessera_shared::{GeoRef, RasterType};
use tiff::decoder::{Decoder, DecodingResult};
use tiff::tags::Tag;

/// Refuse images whose samples would take more than this (4 GiB).
const MAX_SAMPLE_BYTES: u64 = 4 << 30;

/// Stored samples, pixel-interleaved (`(y·width + x)·bands + band`).
#[derive(Debug)]
enum Samples {
    U8(Vec<u8>),
    U16(Vec<u16>),
}

/// A georeferenced multi-band image held in memory.
pub struct SourceImage {
    pub path: PathBuf,
    pub width: usize,
    pub height: usize,
    pub bands: usize,
    /// 8 or 16.
    pub bits: u8,
    samples: Samples,
    pub georef: GeoRef,
    pub crs: Crs,
    /// What the file is, for the pyramid's `source` field and messages.
    pub description: String,
}

impl std::fmt::Debug for SourceImage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SourceImage")
            .field("path", &self.path)
            .field("size", &(self.width, self.height, self.bands, self.bits))
            .field("crs", &self.crs)
            .finish_non_exhaustive()
    }
}

impl SourceImage {
    /// Reads the image and its georeferencing. Errors name the problem; callers add
    /// the file name.
    pub fn open(path: &Path) -> anyhow::Result<Self> {
        // A FIFO or a device would block or mislead the readers below: refused first.
        crate::ingest::open_regular(path)?;
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .unwrap_or_default();
        match ext.as_str() {
            "tif" | "tiff" => Self::open_tiff(path),
            "png" | "jpg" | "jpeg" => Self::open_plain(path),
            _ => bail!("unsupported image type {ext:?}: use a GeoTIFF (.tif), PNG or JPEG"),
        }
    }

    fn open_tiff(path: &Path) -> anyhow::Result<Self> {
        let file = File::open(path).context("cannot open")?;
        let reader: Box<dyn crate::ingest::geotiff::TiffInput> =
            Box::new(BufReader::with_capacity(1 << 16, file));
        let mut decoder = Decoder::new(reader).map_err(|e| anyhow!("not a readable TIFF: {e}"))?;
        // Per-sample tags (SampleFormat, BitsPerSample) hold one value per band: the
        // first stands for all (the decoder refuses mixed ones).
        let tag = |d: &mut Decoder<_>, t: Tag| -> anyhow::Result<Option<u16>> {
            d.find_tag(t)
                .and_then(|v| v.map(tiff::decoder::ifd::Value::into_u16_vec).transpose())
                .map(|v| v.and_then(|v| v.first().copied()))
                .map_err(|e| anyhow!("unreadable TIFF tag {t:?}: {e}"))
        };
        let bands = usize::from(tag(&mut decoder, Tag::SamplesPerPixel)?.unwrap_or(1));
        let planar = tag(&mut decoder, Tag::PlanarConfiguration)?.unwrap_or(1);
        if planar != 1 && bands > 1 {
            bail!(
                "band-interleaved TIFF (PlanarConfiguration {planar}); only pixel-interleaved \
                 multi-band images are read (gdal_translate -co INTERLEAVE=PIXEL)"
            );
        }
        let format = tag(&mut decoder, Tag::SampleFormat)?.unwrap_or(1);
        if format != 1 {
            bail!("TIFF SampleFormat {format}: only unsigned 8- or 16-bit imagery is read");
        }
        let georef = crate::ingest::geotiff::georef_of(&mut decoder)
            .ok_or_else(|| anyhow!("no georeferencing (no GeoTIFF geotransform)"))?;
        let (w, h) = decoder
            .dimensions()
            .context("cannot read the TIFF dimensions")?;
        check_size(w, h, bands)?;
        let decoded = decoder
            .read_image()
            .map_err(|e| anyhow!("cannot decode the TIFF: {e}"))?;
        let (samples, bits) = match decoded {
            DecodingResult::U8(v) => (Samples::U8(v), 8),
            DecodingResult::U16(v) => (Samples::U16(v), 16),
            _ => bail!("only unsigned 8- or 16-bit imagery is read"),
        };
        let len = match &samples {
            Samples::U8(v) => v.len(),
            Samples::U16(v) => v.len(),
        };
        if len != w as usize * h as usize * bands {
            bail!("decoded {len} samples, expected {w}×{h}×{bands}");
        }
        let crs = crs_of(&georef)?;
        Ok(Self {
            path: path.to_path_buf(),
            width: w as usize,
            height: h as usize,
            bands,
            bits,
            samples,
            description: format!(
                "GeoTIFF {w}×{h}, {bands} band(s) of uint{bits}, {}",
                crs_label(&georef, &crs)
            ),
            georef,
            crs,
        })
    }

    /// PNG or JPEG: samples through the `image` crate, the geotransform from a world
    /// file (`.wld`, `.pgw`/`.pngw`, `.jgw`/`.jpgw`), the CRS from a `.prj` holding
    /// `EPSG:CODE`, a PROJ string, or WKT with an EPSG authority.
    fn open_plain(path: &Path) -> anyhow::Result<Self> {
        let gt = world_file(path)?;
        let prj = path.with_extension("prj");
        let text = std::fs::read_to_string(&prj).map_err(|_| {
            anyhow!(
                "no CRS: a PNG or JPEG needs {} (EPSG:CODE, a PROJ string or WKT)",
                prj.display()
            )
        })?;
        let crs = parse_prj(&text).with_context(|| prj.display().to_string())?;
        let img = image::ImageReader::open(path)
            .context("cannot open")?
            .with_guessed_format()
            .context("cannot read")?
            .decode()
            .map_err(|e| anyhow!("cannot decode the image: {e}"))?;
        let (w, h) = (img.width(), img.height());
        let (samples, bands, bits) = if img.color().has_color() {
            if img.color().bytes_per_pixel() > 4 {
                (Samples::U16(img.to_rgb16().into_raw()), 3, 16)
            } else {
                (Samples::U8(img.to_rgb8().into_raw()), 3, 8)
            }
        } else if img.color().bytes_per_pixel() > 1 && !img.color().has_alpha() {
            (Samples::U16(img.to_luma16().into_raw()), 1, 16)
        } else {
            (Samples::U8(img.to_luma8().into_raw()), 1, 8)
        };
        check_size(w, h, bands)?;
        let georef = GeoRef {
            epsg: crs.epsg(),
            crs_name: crs.name(),
            proj: Some(crs.proj_string().to_string()),
            wkt: None,
            geotransform: gt,
            raster_type: RasterType::PixelIsArea,
        };
        Ok(Self {
            path: path.to_path_buf(),
            width: w as usize,
            height: h as usize,
            bands,
            bits,
            samples,
            description: format!(
                "{w}×{h}, {bands} band(s) of uint{bits}, {}",
                crs_label(&georef, &crs)
            ),
            georef,
            crs,
        })
    }

    /// Sample of `band` (0-based) at pixel `(x, y)`.
    pub fn sample(&self, band: usize, x: usize, y: usize) -> f32 {
        let i = (y * self.width + x) * self.bands + band;
        match &self.samples {
            Samples::U8(v) => f32::from(v[i]),
            Samples::U16(v) => f32::from(v[i]),
        }
    }

    /// Every sample of `band` (0-based), as u16, for the stretch's histogram.
    pub fn band_values(&self, band: usize) -> Box<dyn Iterator<Item = u16> + '_> {
        match &self.samples {
            Samples::U8(v) => Box::new(v.iter().skip(band).step_by(self.bands).map(|&s| s.into())),
            Samples::U16(v) => Box::new(v.iter().skip(band).step_by(self.bands).copied()),
        }
    }

    /// Image pixel coordinates (corner convention: pixel `(0, 0)` spans `[0, 1)²`)
    /// of a point in the image's CRS. North-up grids only (checked by `open`'s callers
    /// through [`SourceImage::check_north_up`]).
    pub fn pixel_of(&self, x: f64, y: f64) -> [f64; 2] {
        let gt = &self.georef.geotransform;
        [(x - gt[0]) / gt[1], (y - gt[3]) / gt[5]]
    }

    pub fn check_north_up(&self) -> anyhow::Result<()> {
        let gt = &self.georef.geotransform;
        if gt[2] != 0.0 || gt[4] != 0.0 {
            bail!("rotated image grids are not supported (geotransform {gt:?})");
        }
        Ok(())
    }
}

fn check_size(w: u32, h: u32, bands: usize) -> anyhow::Result<()> {
    let bytes = u64::from(w) * u64::from(h) * bands as u64 * 2;
    if w == 0 || h == 0 || bands == 0 || bytes > MAX_SAMPLE_BYTES {
        bail!(
            "{w}×{h} pixels of {bands} band(s) is empty or more than {} GiB in memory",
            MAX_SAMPLE_BYTES >> 30
        );
    }
    Ok(())
}

fn crs_of(georef: &GeoRef) -> anyhow::Result<Crs> {
    Crs::of(georef).ok_or_else(|| {
        anyhow!(
            "no CRS the projection library knows ({}); an image must name its CRS",
            georef.crs_name.as_deref().unwrap_or("none given")
        )
    })
}

fn crs_label(georef: &GeoRef, crs: &Crs) -> String {
    georef
        .crs()
        .or_else(|| crs.name())
        .unwrap_or_else(|| crs.proj_string().to_string())
}

/// The six lines of a world file (x pixel size, rotation, rotation, y pixel size,
/// x and y of the *centre* of the top-left pixel) as a GDAL geotransform.
fn world_file(path: &Path) -> anyhow::Result<[f64; 6]> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    let short = match ext.to_ascii_lowercase().as_str() {
        "png" => "pgw",
        _ => "jgw",
    };
    let candidates = [
        path.with_extension("wld"),
        path.with_extension(short),
        path.with_extension(format!("{ext}w")),
    ];
    let Some((found, text)) = candidates
        .iter()
        .find_map(|p| std::fs::read_to_string(p).ok().map(|t| (p, t)))
    else {
        bail!(
            "no georeferencing: a PNG or JPEG needs a world file ({})",
            candidates
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        );
    };
    let v: Vec<f64> = text
        .split_whitespace()
        .map(str::parse)
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow!("{}: not six numbers", found.display()))?;
    let [a, d, b, e, c, f] = v[..] else {
        bail!("{}: not six numbers", found.display());
    };
    if a == 0.0 || e == 0.0 || !v.iter().all(|x| x.is_finite()) {
        bail!("{}: degenerate pixel size", found.display());
    }
    Ok([c - 0.5 * a - 0.5 * b, a, b, f - 0.5 * d - 0.5 * e, d, e])
}

/// A `.prj`: `EPSG:CODE`, a PROJ string, or WKT whose last EPSG authority (the
/// outermost CRS's, in WKT 1 and 2 alike) names it.
fn parse_prj(text: &str) -> anyhow::Result<Crs> {
    let t = text.trim();
    if t.starts_with("EPSG:") || t.starts_with("epsg:") || t.starts_with('+') {
        return Crs::parse(t);
    }
    let code = ["AUTHORITY[\"EPSG\",\"", "ID[\"EPSG\","]
        .iter()
        .filter_map(|key| {
            let at = t.rfind(key)? + key.len();
            let digits: String = t[at..].chars().take_while(char::is_ascii_digit).collect();
            Some((at, digits.parse::<u32>().ok()?))
        })
        .max_by_key(|&(at, _)| at)
        .map(|(_, c)| c)
        .ok_or_else(|| {
            anyhow!("no CRS: neither EPSG:CODE, a PROJ string, nor WKT with an EPSG code")
        })?;
    Crs::from_epsg(code)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn world_files_are_pixel_centres() {
        let dir = tempfile::tempdir().unwrap();
        let png = dir.path().join("a.png");
        std::fs::write(dir.path().join("a.pgw"), "10\n0\n0\n-10\n1005\n2995\n").unwrap();
        let gt = world_file(&png).unwrap();
        assert_eq!(gt, [1000.0, 10.0, 0.0, 3000.0, 0.0, -10.0]);
        std::fs::write(dir.path().join("a.pgw"), "10\n0\n0\n").unwrap();
        assert!(
            world_file(&png)
                .unwrap_err()
                .to_string()
                .contains("six numbers")
        );
    }

    #[test]
    fn prj_names_the_outermost_epsg_code() {
        let wkt = r#"PROJCS["SIRGAS 2000 / UTM zone 25S",GEOGCS["SIRGAS 2000",AUTHORITY["EPSG","4674"]],AUTHORITY["EPSG","31985"]]"#;
        assert_eq!(parse_prj(wkt).unwrap().epsg(), Some(31985));
        assert_eq!(parse_prj("EPSG:4326\n").unwrap().epsg(), Some(4326));
        assert!(parse_prj("LOCAL_CS[\"x\"]").is_err());
    }

    #[test]
    fn the_real_landsat_scene_reads_with_its_crs() {
        let Some(path) = tessera_shared::testdata::imagery_or_skip("L7_ETMs.tif") else {
            return;
        };
        let img = SourceImage::open(&path).unwrap();
        assert_eq!(
            (img.width, img.height, img.bands, img.bits),
            (349, 352, 6, 8)
        );
        assert_eq!(img.crs.epsg(), Some(31985));
        let gt = img.georef.geotransform;
        assert!((gt[0] - 288_776.25).abs() < 1e-3 && (gt[1] - 28.5).abs() < 1e-6);
        // A pixel centre maps back to its own pixel.
        let [x, y] = img.pixel_of(gt[0] + 10.5 * gt[1], gt[3] + 20.5 * gt[5]);
        assert!((x - 10.5).abs() < 1e-9 && (y - 20.5).abs() < 1e-9);
    }
}
