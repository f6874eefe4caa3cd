//! Entry points of the coverage-guided fuzz targets (`fuzz/fuzz_targets/`), one per
//! parser, kept here so that the fuzz targets and the corpus replay test
//! (`tests/fuzz_corpus.rs`) run exactly the same code. [`TARGETS`] names them; the
//! two parsers of `tessera-shared` have their entries in [`tessera_shared::fuzzing`].
//!
//! Each entry takes arbitrary bytes, drives its parser to the end (every row of a
//! DEM, every range of a request) and returns the parser's verdict. An entry never
//! allocates in proportion to what the bytes claim (rows are read a bounded number of
//! samples at a time); whatever is allocated, the parser allocated. Entries must never
//! panic; for the valid seeds of `fuzz/corpus/` they return `Ok`. A few also check
//! what an accepted result promises (ranges sorted, inside the level, within limits).

use crate::http::range::{self, RangeRequest};
use crate::ingest::RowSource;
use crate::ingest::geotiff::GeoTiff;
use crate::ingest::hgt::Hgt;
use crate::ingest::png16::Png16;
use anyhow::bail;
use std::io::Cursor;
use tessera_shared::bootstrap::BootstrapError;
use tessera_shared::range_query::{self, RangeLimits, RangeQueryError};
use tessera_shared::reader::ReadError;
use tessera_shared::tile::MAX_LEVEL;
use tessera_shared::wire::WireError;
use tessera_shared::{Level, fuzzing as shared};

/// An entry point: the parser's verdict on some bytes.
pub type Entry = fn(&[u8]) -> Result<(), Rejected>;

/// Why an entry point refused its bytes: the parser's own error.
#[derive(Debug, thiserror::Error)]
pub enum Rejected {
    /// A DEM reader or the VRT parser (their errors carry context, said in full).
    #[error("{0:#}")]
    Ingest(anyhow::Error),
    #[error(transparent)]
    Pyramid(#[from] ReadError),
    #[error(transparent)]
    Wire(#[from] WireError),
    #[error(transparent)]
    Bootstrap(#[from] BootstrapError),
    #[error(transparent)]
    Ranges(#[from] RangeQueryError),
    /// No bytes at all, where the first picks something.
    #[error("empty input")]
    Empty,
    /// A `Range` header that is not a byte range: the whole representation is sent.
    #[error("not a byte-range header: ignored")]
    RangeIgnored,
}

/// Every fuzz target by name (`fuzz/fuzz_targets/NAME.rs`, `fuzz/corpus/NAME/`).
pub const TARGETS: &[(&str, Entry)] = &[
    ("geotiff", |d| geotiff(d).map_err(Rejected::Ingest)),
    ("png16", |d| png16(d).map_err(Rejected::Ingest)),
    ("hgt", |d| hgt(d).map_err(Rejected::Ingest)),
    ("pyramid", |d| Ok(shared::pyramid(d).map(drop)?)),
    ("wire", |d| Ok(shared::wire(d).map(drop)?)),
    ("bootstrap", |d| Ok(shared::bootstrap(d).map(drop)?)),
    ("ranges", |d| ranges(d).map(drop)),
    ("http_range", |d| http_range(d).map(drop)),
    ("vrt", |d| vrt(d).map_err(Rejected::Ingest)),
];

/// A GDAL VRT's XML, parsed as `build` parses it (sources are only named, never
/// opened: the base folder does not exist).
pub fn vrt(data: &[u8]) -> anyhow::Result<()> {
    let text = std::str::from_utf8(data)?;
    crate::ingest::vrt::Vrt::parse(text, std::path::Path::new("/nonexistent-fuzz-base"))?;
    Ok(())
}

/// The most samples a DEM entry asks of its reader at once (4 MiB of `f32`).
const ROW_BUDGET: usize = 1 << 20;

/// Reads every row of a DEM, as many whole rows at a time as fit in [`ROW_BUDGET`]
/// samples. A row wider than that is refused rather than allocated.
fn read_all(src: &mut dyn RowSource) -> anyhow::Result<()> {
    let (width, height) = (src.info().width as usize, src.info().height as usize);
    if width == 0 || height == 0 {
        bail!("empty raster {width}×{height}");
    }
    if width > ROW_BUDGET {
        bail!("rows of {width} samples are wider than the fuzz entry reads");
    }
    let per_read = (ROW_BUDGET / width).min(height);
    let mut buf = vec![0.0f32; per_read * width];
    let mut left = height;
    while left > 0 {
        let n = left.min(per_read);
        src.read_rows(&mut buf[..n * width])?;
        left -= n;
    }
    // One row more must be an error, not a panic.
    if src.read_rows(&mut buf[..width]).is_ok() {
        bail!("reading past the last row succeeded");
    }
    Ok(())
}

/// A GeoTIFF in memory, opened and read to the last row.
pub fn geotiff(data: &[u8]) -> anyhow::Result<()> {
    let mut src = GeoTiff::from_reader(Cursor::new(data.to_vec()))?;
    read_all(&mut src)
}

/// A 16-bit grayscale PNG in memory, opened and read to the last row.
pub fn png16(data: &[u8]) -> anyhow::Result<()> {
    let mut src = Png16::from_reader(Cursor::new(data.to_vec()))?;
    read_all(&mut src)
}

/// An SRTM tile: `NAME\n` (the file stem, e.g. `N44W072`; optional, up to 16 bytes),
/// a mode byte, then sample bytes. The mode (mod 4) says what the reader is told and
/// given: 0 the bytes as they are, with their true length; 1 a 1201² tile's length
/// (2884802 bytes) and the sample bytes repeated to fill it (a whole valid tile from a
/// small input); 2 and 3 the length of a 1201² or 3601² tile but only the sample bytes
/// (a truncated download).
pub fn hgt(data: &[u8]) -> anyhow::Result<()> {
    const SRTM3: u64 = 2_884_802;
    const SRTM1: u64 = 25_934_402;
    let (name, rest) = match data.iter().take(17).position(|&b| b == b'\n') {
        Some(i) => (
            String::from_utf8_lossy(&data[..i]).into_owned(),
            &data[i + 1..],
        ),
        None => ("N44W072".to_owned(), data),
    };
    let Some((&mode, body)) = rest.split_first() else {
        bail!("no mode byte");
    };
    let body = body.to_vec();
    let mut src = match mode % 4 {
        0 => Hgt::from_reader(&name, body.len() as u64, Cursor::new(body))?,
        1 => Hgt::from_reader(&name, SRTM3, Repeat::new(&body, SRTM3))?,
        2 => Hgt::from_reader(&name, SRTM3, Cursor::new(body))?,
        _ => Hgt::from_reader(&name, SRTM1, Cursor::new(body))?,
    };
    read_all(&mut src)
}

/// `bytes` repeated until `len` bytes have been read.
struct Repeat {
    bytes: Vec<u8>,
    at: usize,
    left: u64,
}

impl Repeat {
    fn new(bytes: &[u8], len: u64) -> Self {
        let left = if bytes.is_empty() { 0 } else { len };
        // A short pattern is laid out a few times over, so that reads copy in large
        // pieces (the copy is at most ~8 KiB, whatever `len` claims).
        let times = 4096usize.div_ceil(bytes.len().max(1));
        Self {
            bytes: bytes.repeat(times),
            at: 0,
            left,
        }
    }
}

impl std::io::Read for Repeat {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let mut n = 0;
        while n < buf.len() && self.left > 0 {
            let take = (self.bytes.len() - self.at)
                .min(buf.len() - n)
                .min(usize::try_from(self.left).unwrap_or(usize::MAX));
            buf[n..n + take].copy_from_slice(&self.bytes[self.at..self.at + take]);
            (n, self.at, self.left) = (
                n + take,
                (self.at + take) % self.bytes.len(),
                self.left - take as u64,
            );
        }
        Ok(n)
    }
}

/// The production limits of `serve` (`--max-ranges`, `--max-tiles` defaults).
const LIMITS: RangeLimits = RangeLimits {
    max_ranges: 256,
    max_tiles: 4096,
};

/// `ranges=` of a tile request: the first byte picks the level (mod 25), the rest is
/// the parameter's (already percent-decoded) value. Checks that accepted ranges are
/// sorted, disjoint, inside the level and within the limits. Returns their number.
pub fn ranges(data: &[u8]) -> Result<usize, Rejected> {
    let Some((&l, spec)) = data.split_first() else {
        return Err(Rejected::Empty);
    };
    let level = Level::new(l % (MAX_LEVEL + 1)).expect("a level up to MAX_LEVEL");
    let spec = String::from_utf8_lossy(spec);
    let ranges = range_query::parse(Some(&spec), level, LIMITS)?;
    assert!(!ranges.is_empty() && ranges.len() <= LIMITS.max_ranges);
    assert!(ranges.iter().map(|r| r.len()).sum::<u64>() <= LIMITS.max_tiles);
    assert!(
        ranges
            .last()
            .is_some_and(|r| r.end().get() < level.tile_slots())
    );
    assert!(ranges.windows(2).all(|w| w[0].end() < w[1].start()));
    Ok(ranges.len())
}

/// An HTTP `Range` header: the first 8 bytes are the representation's size (little
/// endian; fewer bytes mean size 0), the rest the header value. Checks that every
/// range of a partial answer lies inside the representation. A header that is
/// ignored (the whole representation is sent) is an `Err`.
pub fn http_range(data: &[u8]) -> Result<RangeRequest, Rejected> {
    let (size, header) = data.split_at(data.len().min(8));
    let mut raw = [0u8; 8];
    raw[..size.len()].copy_from_slice(size);
    let size = u64::from_le_bytes(raw);
    let header = String::from_utf8_lossy(header);
    let answer = range::parse(&header, size);
    match &answer {
        RangeRequest::Full => return Err(Rejected::RangeIgnored),
        RangeRequest::Partial(v) => {
            assert!(!v.is_empty() && v.len() <= range::MAX_RANGES);
            assert!(v.iter().all(|r| r.start <= r.end && r.end < size));
        }
        RangeRequest::Unsatisfiable | RangeRequest::TooMany(_) => {}
    }
    Ok(answer)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_target_has_a_distinct_name() {
        let mut names: Vec<_> = TARGETS.iter().map(|t| t.0).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), TARGETS.len());
    }

    #[test]
    fn short_inputs_are_errors() {
        for (name, entry) in TARGETS {
            assert!(entry(b"").is_err(), "{name}");
        }
        assert_eq!(ranges(b"\x030-3,7").map_err(drop), Ok(2));
        assert!(http_range(b"\xe8\x03\0\0\0\0\0\0bytes=0-9").is_ok());
    }
}
