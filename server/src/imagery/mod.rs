//! Imagery pyramids (DECISIONS.md "Imagery pyramids"; Yang §3: "grid LOD and texture LOD
//! corresponding each other"): `build DEM --imagery IMAGE [--bands 3,2,1]` writes,
//! beside the DEM's pyramid `NAME.tess`, `NAME.tessimg` — the same levels, tiles,
//! Morton layout and presence, each record the JPEG of one tile's ground
//! (`tessera_shared::imagery`, FORMAT.md "Imagery pyramids").
//!
//! - **Texel density.** Every level's tiles have `n × n` texels, `n = T · 2^k` with
//!   `k = ⌈log2(DEM spacing / image pixel)⌉` (both in the DEM CRS's units, the image's
//!   measured at its centre through the projection), clamped to
//!   [`MIN_TEXELS`]..=[`MAX_BUILD_TEXELS`]: the finest level keeps every image pixel
//!   (a texel at most as large as a pixel) without going past a GPU slot's budget.
//!   Olinda: 90 m DEM, 28.5 m Landsat, `k = 2`, 4 texels per cell.
//! - **Finest tiles** are sampled from the image ([`drape`]); **coarser tiles** are the
//!   2×2 box average of their children's texels (a mip chain), a child's quadrant
//!   sampled from the image where the geometry has no child.
//! - **Nothing partial.** The image, its bands and its CRS are checked before the DEM
//!   is built ([`Prepared::open`]); the file is written by the DEM's
//!   [`PyramidWriter`] (temporary file, verified, renamed into place), and a failure
//!   after the DEM's file is in place removes it ([`build_beside`]).

pub mod drape;
pub mod source;
pub mod stretch;

use crate::builder::interrupt::Interrupt;
use crate::builder::writer::PyramidWriter;
use crate::crs::Crs;
use anyhow::{Context, anyhow, bail};
use drape::Drape;
use source::SourceImage;
use std::path::{Path, PathBuf};
use stretch::Stretch;
use tessera_shared::format::IndexEntry;
use tessera_shared::imagery::{ImageEncoding, ImageryMetadata, MIN_TEXELS};
use tessera_shared::{Pyramid, TileGeometry, TileId};

/// The largest texel count per tile side a build chooses (1024² RGBA is 4 MiB a slot).
pub const MAX_BUILD_TEXELS: u32 = 1024;
/// JPEG quality of the records.
pub const JPEG_QUALITY: u8 = 90;
/// The extension of an imagery pyramid beside its DEM's `.tess`.
pub const EXTENSION: &str = "tessimg";

/// The imagery pyramid's path for a DEM pyramid's: `NAME.tess` → `NAME.tessimg`.
pub fn sibling_path(dem: &Path) -> PathBuf {
    dem.with_extension(EXTENSION)
}

/// Texels per tile side for tiles of `tile_size` cells of `dem_spacing`, from an
/// image of `pixel` (same units): `T · 2^⌈log2(dem_spacing / pixel)⌉`, clamped.
pub fn texels_per_tile(tile_size: u32, dem_spacing: f64, pixel: f64) -> u32 {
    let ratio = dem_spacing / pixel;
    // A hair of tolerance so that an image of exactly a quarter of the spacing is k = 2.
    let k = if ratio.is_finite() && ratio > 0.0 {
        (ratio.log2() - 1e-6).ceil() as i32
    } else {
        0
    };
    let n = f64::from(tile_size) * 2f64.powi(k);
    n.clamp(f64::from(MIN_TEXELS), f64::from(MAX_BUILD_TEXELS)) as u32
}

/// `--bands` as 0-based source bands for R, G and B: three 1-based numbers, or one
/// (grey). Without it: bands 1, 2, 3 of a 3+ band image, band 1 as grey of one band.
pub fn parse_bands(spec: Option<&str>, bands: usize) -> anyhow::Result<[usize; 3]> {
    let picked: Vec<usize> = match spec {
        None if bands >= 3 => vec![1, 2, 3],
        None if bands == 1 => vec![1],
        None => bail!("the image has {bands} bands: say which are R,G,B with --bands"),
        Some(s) => s
            .split(',')
            .map(|b| {
                b.trim()
                    .parse::<usize>()
                    .map_err(|_| anyhow!("--bands {s:?}: {b:?} is not a band number"))
            })
            .collect::<Result<_, _>>()?,
    };
    for &b in &picked {
        if b == 0 || b > bands {
            bail!(
                "--bands {}: band {b} is out of range (the image has bands 1..={bands})",
                spec.unwrap_or("")
            );
        }
    }
    match picked[..] {
        [g] => Ok([g - 1; 3]),
        [r, g, b] => Ok([r - 1, g - 1, b - 1]),
        _ => bail!(
            "--bands {}: give three bands (R,G,B) or one (grey)",
            spec.unwrap_or("")
        ),
    }
}

/// An image checked and read, before any output exists.
#[derive(Debug)]
pub struct Prepared {
    image: SourceImage,
    bands: [usize; 3],
    stretch: Stretch,
}

impl Prepared {
    /// Reads `path` and checks `--bands` against it. Errors name the file.
    pub fn open(path: &Path, bands: Option<&str>) -> anyhow::Result<Self> {
        let named = || format!("imagery {}", path.display());
        let image = SourceImage::open(path).with_context(named)?;
        image.check_north_up().with_context(named)?;
        let bands = parse_bands(bands, image.bands).with_context(named)?;
        let stretch = Stretch::of(&image, bands);
        Ok(Self {
            image,
            bands,
            stretch,
        })
    }

    pub fn image(&self) -> &SourceImage {
        &self.image
    }
}

/// What an imagery build wrote.
#[derive(Debug)]
pub struct ImageryReport {
    pub path: PathBuf,
    pub metadata: ImageryMetadata,
    pub records: u64,
    pub file_bytes: u64,
}

/// Builds the imagery pyramid of the finished DEM pyramid `dem` into
/// [`sibling_path`]; on failure removes `dem` too, so that a failed
/// `build --imagery` leaves no output.
pub fn build_beside(
    prepared: &Prepared,
    dem: &Path,
    interrupt: &Interrupt,
) -> anyhow::Result<ImageryReport> {
    let out = sibling_path(dem);
    build(prepared, dem, &out, interrupt).inspect_err(|_| {
        if let Err(e) = std::fs::remove_file(dem) {
            tracing::warn!(file = %dem.display(), error = %e, "cannot remove the DEM pyramid of a failed imagery build");
        }
    })
}

/// Builds the imagery pyramid of the DEM pyramid `dem` into `out`.
pub fn build(
    prepared: &Prepared,
    dem: &Path,
    out: &Path,
    interrupt: &Interrupt,
) -> anyhow::Result<ImageryReport> {
    let image_name = || format!("imagery {}", prepared.image.path.display());
    let pyramid = Pyramid::open_file(dem).with_context(|| dem.display().to_string())?;
    let dem_meta = pyramid.metadata().clone();
    let georef = dem_meta.georef.clone().ok_or_else(|| {
        anyhow!(
            "{}: the DEM has no georeferencing to drape imagery on",
            dem.display()
        )
    })?;
    let dem_crs = Crs::of(&georef).ok_or_else(|| {
        anyhow!(
            "{}: the DEM's CRS ({}) is not known to the projection library; give it with --crs",
            dem.display(),
            georef.crs_name.as_deref().unwrap_or("unnamed")
        )
    })?;
    let drape = Drape::new(
        &prepared.image,
        georef.clone(),
        dem_crs,
        prepared.bands,
        prepared.stretch,
    );
    if !drape.overlaps(dem_meta.width, dem_meta.height) {
        bail!(
            "{}: the image does not overlap the DEM's ground",
            image_name()
        );
    }
    let geometry = *pyramid.geometry();
    let gt = georef.geotransform;
    let dem_spacing = f64::midpoint(gt[1].abs(), gt[5].abs());
    let pixel = drape.image_pixel_in_dem_units().ok_or_else(|| {
        anyhow!(
            "{}: its centre does not project into the DEM's CRS",
            image_name()
        )
    })?;
    let texels = texels_per_tile(
        geometry.tile_size(),
        dem_spacing,
        f64::midpoint(pixel[0], pixel[1]),
    );
    let scale = f64::from(geometry.tile_size()) / f64::from(texels);
    let mut meta = ImageryMetadata {
        dem: dem_meta,
        texels,
        encoding: ImageEncoding::Jpeg,
        bands: prepared.bands.map(|b| b as u16 + 1),
        stretch: prepared.stretch.ranges,
        texel_size: [gt[1].abs() * scale, gt[5].abs() * scale],
        source: format!(
            "{} ({})",
            prepared
                .image
                .path
                .file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
            prepared.image.description
        ),
        generator: format!("tessera-server {}", env!("CARGO_PKG_VERSION")),
        content_hash: "0000000000000000".into(),
    };
    let reserve = tessera_shared::format::encode_imagery_metadata(&meta).len() as u64 + 1024;
    let writer = PyramidWriter::create(out, geometry, reserve)?;
    let mut walk = Walk {
        pyramid: &pyramid,
        geometry: &geometry,
        drape: &drape,
        n: texels as usize,
        writer,
        interrupt,
        records: 0,
        inside: 0,
    };
    let root = TileId::new(tessera_shared::Level::new(0).expect("level 0"), 0, 0).expect("root");
    walk.tile(root)?;
    if walk.inside == 0 {
        bail!(
            "{}: no texel of the DEM's tiles falls inside the image",
            image_name()
        );
    }
    let records = walk.records;
    meta.content_hash.clear();
    let (meta, file_bytes) = walk.writer.finish(meta, interrupt, |_| {})?;
    Ok(ImageryReport {
        path: out.to_path_buf(),
        metadata: meta,
        records,
        file_bytes,
    })
}

/// The post-order walk of the quadtree (children before their parent, so each
/// level's records come in Morton order, as the writer needs).
struct Walk<'a> {
    pyramid: &'a Pyramid<tessera_shared::FileSource>,
    geometry: &'a TileGeometry,
    drape: &'a Drape<'a>,
    n: usize,
    writer: PyramidWriter,
    interrupt: &'a Interrupt,
    records: u64,
    inside: u64,
}

impl Walk<'_> {
    /// The texels of `tile` (which the geometry has), after writing its record and
    /// its subtree's when the DEM has them.
    fn tile(&mut self, tile: TileId) -> anyhow::Result<Vec<u8>> {
        let n = self.n;
        let (x0, y0) = self.geometry.origin(tile);
        let span =
            (self.geometry.spacing(tile.level()) * u64::from(self.geometry.tile_size())) as f64;
        let rgb = if tile.level() == self.geometry.finest() {
            self.interrupt.check()?;
            let (rgb, inside) = self.drape.texels(x0 as f64, y0 as f64, span, n);
            self.inside += inside as u64;
            rgb
        } else {
            let children = tile
                .children()
                .expect("a level above the finest has children");
            let mut rgb = vec![0u8; n * n * 3];
            let half = n / 2;
            for (q, child) in children.into_iter().enumerate() {
                let quad = if self.geometry.is_present(child) {
                    downsample(&self.tile(child)?, n)
                } else {
                    let (cx, cy) = self.geometry.origin(child);
                    self.drape.texels(cx as f64, cy as f64, span / 2.0, half).0
                };
                let (qx, qy) = ((q % 2) * half, (q / 2) * half);
                for row in 0..half {
                    let dst = ((qy + row) * n + qx) * 3;
                    rgb[dst..dst + half * 3]
                        .copy_from_slice(&quad[row * half * 3..(row + 1) * half * 3]);
                }
            }
            rgb
        };
        if let Some(entry) = self.pyramid.entry(tile) {
            let jpeg = encode_jpeg(&rgb, n)?;
            let summary = IndexEntry {
                flags: entry.flags,
                ..IndexEntry::default()
            };
            self.writer
                .push(tile.level(), tile.morton(), &jpeg, summary)?;
            self.records += 1;
        }
        Ok(rgb)
    }
}

/// `n × n` RGB texels halved to `n/2 × n/2` by 2×2 box averaging (rounded).
fn downsample(rgb: &[u8], n: usize) -> Vec<u8> {
    let h = n / 2;
    let mut out = vec![0u8; h * h * 3];
    for y in 0..h {
        for x in 0..h {
            for c in 0..3 {
                let at =
                    |dx: usize, dy: usize| u32::from(rgb[((2 * y + dy) * n + 2 * x + dx) * 3 + c]);
                out[(y * h + x) * 3 + c] =
                    ((at(0, 0) + at(1, 0) + at(0, 1) + at(1, 1) + 2) / 4) as u8;
            }
        }
    }
    out
}

/// One record: baseline JPEG of `n × n` RGB texels.
pub fn encode_jpeg(rgb: &[u8], n: usize) -> anyhow::Result<Vec<u8>> {
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, JPEG_QUALITY)
        .encode(rgb, n as u32, n as u32, image::ExtendedColorType::Rgb8)
        .context("cannot encode a JPEG record")?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texel_density_keeps_every_image_pixel_within_the_cap() {
        // Olinda: 90 m DEM, 28.5 m image: 3.16 image pixels per cell → 4 texels per cell.
        assert_eq!(texels_per_tile(64, 89.994, 28.5), 256);
        // Exactly 4 pixels per cell is k = 2, not 3.
        assert_eq!(texels_per_tile(64, 100.0, 25.0), 256);
        // The same resolution: one texel per cell.
        assert_eq!(texels_per_tile(256, 30.0, 30.0), 256);
        // A coarser image: fewer texels than cells, not below the minimum.
        assert_eq!(texels_per_tile(256, 30.0, 120.0), 64);
        assert_eq!(texels_per_tile(64, 1.0, 1000.0), MIN_TEXELS);
        // Default tiles over a fine image: capped.
        assert_eq!(texels_per_tile(512, 90.0, 10.0), MAX_BUILD_TEXELS);
    }

    #[test]
    fn bands_are_one_based_and_checked() {
        assert_eq!(parse_bands(Some("3,2,1"), 6).unwrap(), [2, 1, 0]);
        assert_eq!(parse_bands(Some("4"), 6).unwrap(), [3, 3, 3]);
        assert_eq!(parse_bands(None, 6).unwrap(), [0, 1, 2]);
        assert_eq!(parse_bands(None, 1).unwrap(), [0, 0, 0]);
        let e = parse_bands(Some("7,2,1"), 6).unwrap_err().to_string();
        assert!(
            e.contains("band 7 is out of range") && e.contains("1..=6"),
            "{e}"
        );
        assert!(parse_bands(Some("0,1,2"), 6).is_err());
        assert!(
            parse_bands(Some("1,2"), 6)
                .unwrap_err()
                .to_string()
                .contains("three")
        );
        assert!(parse_bands(Some("a,b,c"), 6).is_err());
        assert!(
            parse_bands(None, 2)
                .unwrap_err()
                .to_string()
                .contains("--bands")
        );
    }

    #[test]
    fn downsampling_averages_each_2x2_block() {
        // 4×4 texels, channel value = 10·x + y (+0, +1, +2 for G, B).
        let n = 4;
        let rgb: Vec<u8> = (0..n * n)
            .flat_map(|i| {
                let (x, y) = (i % n, i / n);
                let v = (10 * x + y) as u8;
                [v, v + 1, v + 2]
            })
            .collect();
        let half = downsample(&rgb, n);
        // Block (1, 0): x in {2, 3}, y in {0, 1}: mean 25.5 → 26 (rounded half up).
        assert_eq!(&half[3..6], &[26, 27, 28]);
        assert_eq!(&half[0..3], &[6, 7, 8]);
    }
}
