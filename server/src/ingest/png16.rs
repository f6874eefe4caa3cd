//! 16-bit grayscale PNG heightmaps, decoded row by row (never whole in memory).
//!
//! PNG has no georeferencing or no-data convention; vertical units come from the
//! `--scale`/`--offset` flags (e.g. `--offset -10000` for the moon mosaics).

use super::{RowSource, SampleType, SourceInfo};
use anyhow::{Context, bail};
use std::io::{BufRead, BufReader, Seek, SeekFrom};
use std::path::Path;

/// What a PNG is read from: a buffered file, or any buffered seekable reader
/// ([`Png16::from_reader`], e.g. bytes in memory for the fuzz targets).
pub trait PngInput: BufRead + Seek + Send {}
impl<T: BufRead + Seek + Send> PngInput for T {}

pub struct Png16 {
    info: SourceInfo,
    reader: png::Reader<Box<dyn PngInput>>,
    rows_read: u32,
}

impl std::fmt::Debug for Png16 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Png16")
            .field("info", &self.info)
            .field("rows_read", &self.rows_read)
            .finish_non_exhaustive()
    }
}

impl Png16 {
    pub fn open(path: &Path) -> anyhow::Result<Self> {
        let (file, _) = super::open_regular(path)?;
        Self::from_reader(BufReader::new(file))
    }

    /// Opens a PNG from any buffered seekable reader (its length is found by seeking
    /// to the end); [`Png16::open`] is this over a buffered file.
    pub fn from_reader(mut input: impl PngInput + 'static) -> anyhow::Result<Self> {
        let file_len = input
            .seek(SeekFrom::End(0))
            .and_then(|len| input.seek(SeekFrom::Start(0)).map(|_| len))
            .context("cannot read file size")?;
        let input: Box<dyn PngInput> = Box::new(input);
        let mut decoder = png::Decoder::new(input);
        // Keep samples as stored: no expansion, no stripping to 8 bits.
        decoder.set_transformations(png::Transformations::IDENTITY);
        // Chunk CRCs and the zlib Adler-32 are both checked: a flipped bit is an error,
        // never a pyramid (docs/ARCHITECTURE.md#nothing-partial). The png crate skips
        // Adler-32 by default.
        decoder.ignore_checksums(false);
        let reader = decoder
            .read_info()
            .map_err(|e| anyhow::anyhow!("not a readable PNG: {e}"))?;
        let i = reader.info();
        let (width, height) = (i.width, i.height);
        if i.color_type != png::ColorType::Grayscale || i.bit_depth != png::BitDepth::Sixteen {
            bail!(
                "PNG is {}-bit {:?}, not a 16-bit grayscale height map",
                i.bit_depth as u8,
                i.color_type
            );
        }
        if i.interlaced {
            bail!("interlaced (Adam7) PNGs are not supported; re-save it without interlacing");
        }
        check_plausible(width, height, file_len)?;
        Ok(Self {
            info: SourceInfo {
                width,
                height,
                sample_type: SampleType::UInt16,
                nodata: None,
                georef: None,
                description: format!("16-bit grayscale PNG {width}×{height}"),
            },
            reader,
            rows_read: 0,
        })
    }
}

impl RowSource for Png16 {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn buffer_bytes(&self) -> u64 {
        // The decoder's current and previous rows (for unfiltering) and its inflate
        // window and input buffer.
        2 * (u64::from(self.info.width) * 2 + 1) + (64 << 10)
    }

    fn read_rows(&mut self, out: &mut [f32]) -> anyhow::Result<()> {
        let w = self.info.width as usize;
        for row in out.chunks_exact_mut(w) {
            let r = self.rows_read;
            let data = self
                .reader
                .next_row()
                .map_err(|e| anyhow::anyhow!("corrupt or truncated PNG at row {r}: {e}"))?
                .with_context(|| {
                    format!("PNG ends after {r} rows, expected {}", self.info.height)
                })?;
            for (o, c) in row.iter_mut().zip(data.data().chunks_exact(2)) {
                *o = f32::from(u16::from_be_bytes([c[0], c[1]]));
            }
            self.rows_read += 1;
        }
        if self.rows_read == self.info.height && !out.is_empty() {
            // Read on to IEND so the last IDAT chunk's CRC and the zlib stream's
            // Adler-32 are checked too: the rows alone stop short of both.
            self.reader
                .finish()
                .map_err(|e| anyhow::anyhow!("corrupt PNG after its last row: {e}"))?;
        }
        Ok(())
    }
}

/// Deflate cannot compress better than about 1032:1 (a 258-byte match per ~2-bit
/// code), so a file of `file_len` bytes holds at most this many bytes of image data.
const DEFLATE_MAX_RATIO: u64 = 1032;

/// Refuses a header whose claimed size the file cannot possibly hold, before anything
/// is allocated or spooled for it (docs/ARCHITECTURE.md#bad-input-is-an-error).
fn check_plausible(width: u32, height: u32, file_len: u64) -> anyhow::Result<()> {
    // Each row is a filter byte and two bytes per sample.
    let claimed = u64::from(height) * (u64::from(width) * 2 + 1);
    let most = file_len.saturating_mul(DEFLATE_MAX_RATIO);
    if claimed > most {
        bail!(
            "implausible PNG header: it claims {width}×{height} samples ({claimed} bytes of \
             image data), but a {file_len}-byte file can hold at most {most} bytes \
             (deflate compresses at most {DEFLATE_MAX_RATIO}:1)"
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::testdata;

    #[test]
    fn reads_real_16_bit_pngs_with_their_stated_range() {
        for name in [
            "jacksboro_fault_dem.png",
            "topobathy.png",
            "sthelens_10m.png",
        ] {
            let Some(path) = testdata::dem_or_skip(name) else {
                continue;
            };
            let f = testdata::facts(name);
            let mut src = Png16::open(&path).unwrap();
            assert_eq!(
                (src.info().width, src.info().height),
                (f.width, f.height),
                "{name}"
            );
            let w = f.width as usize;
            let (mut lo, mut hi) = (f32::MAX, f32::MIN);
            // Odd chunk sizes: rows must come out in order whatever the request size.
            let mut left = f.height as usize;
            while left > 0 {
                let n = left.min(7);
                let mut buf = vec![0.0; n * w];
                src.read_rows(&mut buf).unwrap();
                for v in buf {
                    lo = lo.min(v);
                    hi = hi.max(v);
                }
                left -= n;
            }
            let to_m = |v: f32| f64::from(v) * f.scale + f.offset;
            assert!((to_m(lo) - f.min).abs() < 1e-6, "{name} min {}", to_m(lo));
            assert!((to_m(hi) - f.max).abs() < 1e-6, "{name} max {}", to_m(hi));
            let mut extra = vec![0.0; w];
            assert!(
                src.read_rows(&mut extra).is_err(),
                "{name}: read past the end"
            );
        }
    }

    #[test]
    fn rejects_an_8_bit_rgba_png() {
        let Some(path) = testdata::dem_or_skip("fuji.png") else {
            return;
        };
        let err = Png16::open(&path).unwrap_err().to_string();
        assert!(err.contains("not a 16-bit grayscale"), "{err}");
    }
}
