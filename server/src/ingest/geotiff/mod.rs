//! GeoTIFF input: single-band int16, uint16 or float32 rasters, striped or tiled,
//! uncompressed or compressed with LZW, deflate or PackBits (with the horizontal or
//! floating-point predictor), read out of core.
//!
//! Only one strip, or one row of tiles (tile height × image width), is decoded at a
//! time: [`GeoTiff::read_rows`] serves rows from that band and decodes the next band
//! when it runs out. Everything that the reader does not support is rejected in
//! [`GeoTiff::open`] with a one-line message naming the problem, so a bad input fails
//! before any work is done.
//!
//! Georeferencing is normalised to GDAL's convention ([`GeoRef`](tessera_shared::GeoRef)): the geotransform
//! names the corner of pixel (0, 0), and for `PixelIsPoint` rasters the tiepoint is
//! shifted half a pixel north-west, as GDAL does. Only north-up rasters without
//! rotation are georeferenced: a `ModelTransformationTag` with rotation or shear
//! terms, or ground control points without a pixel scale, are ignored with a
//! warning (the raster is still read, without georeferencing), because the tile
//! pyramid and [`GeoRef::extent`](tessera_shared::GeoRef::extent) assume an axis-aligned grid.
//!
//! The `GDAL_NODATA` tag is reported as [`SourceInfo::nodata`]; samples are returned
//! unchanged. The heights' vertical datum comes from the vertical GeoKeys, GDAL's
//! DTED metadata or a known product's file name (`vertical`).

mod georef;
mod layout;
mod product_name;
#[cfg(test)]
mod test_tiff;
#[cfg(test)]
mod tests;
mod user_crs;
mod vertical;

use super::{DatumClue, RowSource, SampleType, SourceInfo};
use anyhow::{Context, bail};
use georef::read_georef;
use layout::{Compression, Layout};
use std::fmt;
use std::io::{BufReader, ErrorKind, Read, Seek, SeekFrom};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;
use tiff::decoder::{ChunkType, Decoder, DecodingResult};
use tiff::tags::Tag;
use tiff::{TiffError, TiffFormatError};

/// The `tiff` crate's default limit on one decoded chunk (`Limits::decoding_buffer_size`).
const MAX_CHUNK_BYTES: u64 = 256 * 1024 * 1024;

/// Longest ASCII tag value read (GeoAsciiParams may hold a whole ESRI WKT string).
const MAX_ASCII_TAG: usize = 1 << 16;

/// What a GeoTIFF is read from: a buffered file, or any seekable reader
/// ([`GeoTiff::from_reader`], e.g. bytes in memory for the fuzz targets).
pub trait TiffInput: Read + Seek + Send {}
impl<T: Read + Seek + Send> TiffInput for T {}

type Reader = Box<dyn TiffInput>;

/// What fetches a file's chunks ahead of the decoder when the file is read by range
/// (an object in a store, `super::remote`): told each band's chunk byte ranges before
/// they are decoded.
pub trait ChunkFetch: Send + fmt::Debug {
    /// Fetches `chunks` (byte ranges in the file), replacing the previous band's.
    fn band(&self, chunks: &[std::ops::Range<u64>]) -> std::io::Result<()>;
    /// Starts fetching `chunks` (the next band's) without waiting for them.
    fn ahead(&self, chunks: &[std::ops::Range<u64>]);
    /// Bytes held besides the band (header windows), for the memory plan.
    fn window_bytes(&self) -> u64;
}

/// A GeoTIFF read as rows, one strip or row of tiles at a time.
pub struct GeoTiff {
    info: SourceInfo,
    decoder: Decoder<Reader>,
    layout: Layout,
    compression: Compression,
    /// Compressed size of every chunk; 0 marks a sparse (absent) chunk.
    chunk_bytes: Vec<u64>,
    /// Where every chunk starts in the file.
    chunk_offsets: Vec<u64>,
    /// For a file read by range from a store: fetches each band's chunks before they
    /// are decoded (`super::remote`).
    prefetch: Option<Box<dyn ChunkFetch>>,
    /// The decoded band: rows `band_start .. band_start + band_rows`, `width` samples each.
    band: Vec<f32>,
    band_start: u32,
    band_rows: u32,
    /// The next row `read_rows` returns.
    next_row: u32,
    /// The columns read ([`RowSource::set_window`]; empty: all): a tiled file decodes
    /// only the tiles over them.
    columns: Vec<std::ops::Range<u32>>,
    /// No band starting at or after this row is fetched ahead.
    until: u32,
    /// Set when decoding failed: the decoder's state is then unknown.
    failed: bool,
    /// What the file (or its name) says about the heights' vertical datum.
    datum: Option<DatumClue>,
}

impl fmt::Debug for GeoTiff {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("GeoTiff")
            .field("info", &self.info)
            .field("layout", &self.layout)
            .field("compression", &self.compression)
            .field("chunks", &self.chunk_bytes.len())
            .field("band_start", &self.band_start)
            .field("band_rows", &self.band_rows)
            .field("next_row", &self.next_row)
            .field("failed", &self.failed)
            .field("datum", &self.datum)
            .finish_non_exhaustive()
    }
}

/// Turns an error of the `tiff` crate while reading the header into a clear message.
fn header_error(err: &TiffError) -> anyhow::Error {
    match err {
        TiffError::IoError(e) if e.kind() == ErrorKind::UnexpectedEof => anyhow::anyhow!(
            "truncated TIFF: the header or image directory ends past the end of the file"
        ),
        TiffError::FormatError(
            TiffFormatError::TiffSignatureNotFound | TiffFormatError::TiffSignatureInvalid,
        ) => anyhow::anyhow!("not a TIFF file (bad signature)"),
        _ => anyhow::anyhow!("cannot read the TIFF image directory: {err}"),
    }
}

/// The sample type from `BitsPerSample` and `SampleFormat`, or an error naming it.
fn sample_type(bits: u16, format: u16) -> anyhow::Result<SampleType> {
    Ok(match (bits, format) {
        (16, 2) => SampleType::Int16,
        (16, 1) => SampleType::UInt16,
        (32, 3) => SampleType::Float32,
        _ => {
            let name = match format {
                1 => format!("uint{bits}"),
                2 => format!("int{bits}"),
                3 => format!("float{bits}"),
                4 => format!("untyped {bits}-bit"),
                5 => format!("complex int{bits}"),
                6 => format!("complex float{bits}"),
                _ => format!("{bits}-bit SampleFormat {format}"),
            };
            bail!("unsupported sample type {name}; supported: int16, uint16, float32")
        }
    })
}

/// Parses a `GDAL_NODATA` string: text, possibly padded with whitespace or NULs.
fn parse_nodata(raw: &str) -> Option<f64> {
    let text = raw.trim_matches(|c: char| c == '\0' || c.is_whitespace());
    if text.is_empty() {
        return None;
    }
    let parsed = text.parse::<f64>().ok();
    if parsed.is_none() {
        tracing::warn!("ignoring unparsable GDAL_NODATA value {text:?}");
    }
    parsed
}

/// The georeferencing of any open TIFF, multi-band ones included (the imagery
/// pyramid's source, `crate::imagery::source`), in GDAL's corner convention.
pub fn georef_of(decoder: &mut Decoder<Box<dyn TiffInput>>) -> Option<tessera_shared::GeoRef> {
    read_georef(decoder)
}

/// Reads an ASCII (or byte) tag as text, without the crate's strict NUL handling.
fn ascii_tag(decoder: &mut Decoder<Reader>, tag: Tag) -> anyhow::Result<Option<String>> {
    text_tag(decoder, tag, MAX_ASCII_TAG)
}

/// [`ascii_tag`] with its own limit on the bytes read.
fn text_tag(
    decoder: &mut Decoder<Reader>,
    tag: Tag,
    limit: usize,
) -> anyhow::Result<Option<String>> {
    let mut ifd = decoder.image_ifd();
    let Some(entry) = ifd.find_entry(tag) else {
        return Ok(None);
    };
    let len = usize::try_from(entry.count())
        .unwrap_or(usize::MAX)
        .min(limit);
    let mut buf = vec![0u8; len];
    let got = ifd
        .find_tag_bytes(tag, &mut buf, 0)
        .with_context(|| format!("cannot read TIFF tag {}", tag.to_u16()))?
        .unwrap_or(0);
    buf.truncate(got.min(len));
    Ok(Some(String::from_utf8_lossy(&buf).into_owned()))
}

/// Reads an optional unsigned tag, with the tag named in the error.
fn tag_u16(decoder: &mut Decoder<Reader>, tag: Tag, name: &str) -> anyhow::Result<Option<u16>> {
    decoder
        .find_tag_unsigned_vec::<u16>(tag)
        .map(|v| v.and_then(|v| v.first().copied()))
        .with_context(|| format!("bad TIFF tag {name}"))
}

impl GeoTiff {
    /// Opens a GeoTIFF and checks that it can be read, without decoding any samples.
    /// A file that states no vertical datum gets the one its name implies, if it is
    /// the name of a product whose datum is documented (`product_name`).
    pub fn open(path: &Path) -> anyhow::Result<Self> {
        let (file, _) = super::open_regular(path)?;
        let mut tiff = Self::from_reader(BufReader::with_capacity(1 << 16, file))?;
        if tiff.datum.is_none() {
            tiff.datum = product_name::datum_of(path);
        }
        Ok(tiff)
    }

    /// Opens a GeoTIFF from any seekable reader (its length is found by seeking to
    /// the end); [`GeoTiff::open`] is this over a buffered file.
    pub fn from_reader(reader: impl TiffInput + 'static) -> anyhow::Result<Self> {
        let mut reader: Reader = Box::new(reader);
        let file_len = reader
            .seek(SeekFrom::End(0))
            .and_then(|len| reader.seek(SeekFrom::Start(0)).map(|_| len))
            .context("cannot read file size")?;
        let mut decoder = Decoder::new(reader).map_err(|e| header_error(&e))?;

        // Check the compression ourselves, so that the message is clear before decoding.
        let compression = Compression::from_code(
            tag_u16(&mut decoder, Tag::Compression, "Compression")?.unwrap_or(1),
        )?;

        let bands = tag_u16(&mut decoder, Tag::SamplesPerPixel, "SamplesPerPixel")?.unwrap_or(1);
        if bands != 1 {
            let planar = tag_u16(
                &mut decoder,
                Tag::PlanarConfiguration,
                "PlanarConfiguration",
            )?
            .unwrap_or(1);
            bail!(
                "unsupported TIFF with {bands} bands (SamplesPerPixel {bands}, PlanarConfiguration \
                 {planar}); only single-band rasters are supported"
            );
        }
        let bits = tag_u16(&mut decoder, Tag::BitsPerSample, "BitsPerSample")?.unwrap_or(1);
        let format = tag_u16(&mut decoder, Tag::SampleFormat, "SampleFormat")?.unwrap_or(1);
        let sample_type = sample_type(bits, format)?;

        match tag_u16(
            &mut decoder,
            Tag::PhotometricInterpretation,
            "PhotometricInterpretation",
        )? {
            Some(1) | None => {}
            Some(0) => bail!(
                "unsupported PhotometricInterpretation WhiteIsZero (0): the decoder would invert \
                 the heights; only BlackIsZero (1) grayscale rasters are supported"
            ),
            Some(3) => bail!(
                "unsupported palette (colour-mapped) TIFF; only grayscale (BlackIsZero) rasters are supported"
            ),
            Some(p) => bail!(
                "unsupported PhotometricInterpretation {p}; only grayscale (BlackIsZero) rasters are supported"
            ),
        }

        let predictor = tag_u16(&mut decoder, Tag::Predictor, "Predictor")?.unwrap_or(1);
        let predictor_name = match (predictor, sample_type) {
            (1, _) => "",
            (2, _) => " + horizontal predictor",
            (3, SampleType::Float32) => " + floating-point predictor",
            (3, t) => bail!(
                "TIFF uses the floating-point predictor (3) on {} samples; it only applies to floats",
                t.name()
            ),
            (p, _) => bail!(
                "unsupported TIFF predictor {p}; supported: none (1), horizontal (2), floating point (3)"
            ),
        };

        let (width, height) = decoder
            .dimensions()
            .context("cannot read the TIFF dimensions")?;
        let (chunk_w, chunk_h) = decoder.chunk_dimensions();
        let layout = match decoder.get_chunk_type() {
            ChunkType::Strip => Layout::Strips {
                rows_per_strip: chunk_h.min(height),
            },
            ChunkType::Tile => Layout::Tiles {
                tile_width: chunk_w,
                tile_height: chunk_h,
                tiles_across: width.div_ceil(chunk_w),
            },
        };
        let kind = layout.chunk_kind();
        let bytes_per_sample = u64::from(bits / 8);
        let chunk_bytes_decoded =
            u64::from(chunk_w) * u64::from(layout.band_height()) * bytes_per_sample;
        if chunk_bytes_decoded > MAX_CHUNK_BYTES {
            bail!(
                "TIFF {kind}s of {chunk_w}×{} samples take {} MiB each decoded, over the {} MiB \
                 limit; rewrite the file with smaller strips or tiles (e.g. gdal_translate -co TILED=YES)",
                layout.band_height(),
                chunk_bytes_decoded >> 20,
                MAX_CHUNK_BYTES >> 20
            );
        }

        // Where every chunk lies: a file cut short fails here, before any decoding.
        let (offsets_tag, counts_tag) = match layout {
            Layout::Strips { .. } => (Tag::StripOffsets, Tag::StripByteCounts),
            Layout::Tiles { .. } => (Tag::TileOffsets, Tag::TileByteCounts),
        };
        let offsets = decoder
            .get_tag_u64_vec(offsets_tag)
            .with_context(|| format!("cannot read the TIFF {kind} offsets"))?;
        let chunk_bytes = decoder
            .get_tag_u64_vec(counts_tag)
            .with_context(|| format!("cannot read the TIFF {kind} byte counts"))?;
        let expected = match layout {
            Layout::Strips { rows_per_strip } => height.div_ceil(rows_per_strip),
            Layout::Tiles {
                tile_height,
                tiles_across,
                ..
            } => height.div_ceil(tile_height) * tiles_across,
        } as usize;
        if offsets.len() != expected || chunk_bytes.len() != expected {
            bail!(
                "corrupt TIFF: {} {kind} offsets and {} byte counts for {expected} {kind}s",
                offsets.len(),
                chunk_bytes.len()
            );
        }
        let beyond: Vec<usize> = (0..expected)
            .filter(|&i| {
                chunk_bytes[i] > 0
                    && offsets[i]
                        .checked_add(chunk_bytes[i])
                        .is_none_or(|end| end > file_len)
            })
            .collect();
        if let Some(&first) = beyond.first() {
            bail!(
                "truncated TIFF: {kind} {first} of {expected} (bytes {}..{}) ends past the end of the \
                 file ({file_len} bytes); {} {kind}s are affected",
                offsets[first],
                offsets[first].saturating_add(chunk_bytes[first]),
                beyond.len()
            );
        }

        // Nothing is allocated for the claimed size until the data can hold it: the
        // stored chunks, at the compression's best ratio, must cover every non-empty
        // chunk but one (the last strip may be short). Empty chunks are sparse tiles.
        let stored: u64 = chunk_bytes.iter().fold(0u64, |a, &b| a.saturating_add(b));
        let non_empty = chunk_bytes.iter().filter(|&&b| b > 0).count() as u64;
        let claimed = non_empty
            .saturating_sub(1)
            .saturating_mul(chunk_bytes_decoded);
        if claimed > stored.saturating_mul(compression.max_ratio()) {
            bail!(
                "implausible TIFF header: {non_empty} {kind}s of {chunk_bytes_decoded} bytes \
                 each decoded, but they hold {stored} bytes, more than {} ({}:1) can expand to",
                compression.name(),
                compression.max_ratio()
            );
        }

        let nodata = match ascii_tag(&mut decoder, Tag::GdalNodata) {
            Ok(v) => v.as_deref().and_then(parse_nodata),
            Err(e) => {
                tracing::warn!("ignoring unreadable GDAL_NODATA tag: {e:#}");
                None
            }
        };
        let georef = read_georef(&mut decoder);
        let datum = vertical::from_tags(&mut decoder);

        let layout_text = match layout {
            Layout::Strips { rows_per_strip } if rows_per_strip >= height => {
                format!("{height} rows in one strip")
            }
            Layout::Strips { rows_per_strip } => {
                format!("{height} rows in strips of {rows_per_strip}")
            }
            Layout::Tiles {
                tile_width,
                tile_height,
                ..
            } => format!("tiled {tile_width}×{tile_height}"),
        };
        let description = format!(
            "GeoTIFF {}, {}{predictor_name}, {layout_text}",
            sample_type.name(),
            compression.name()
        );

        Ok(Self {
            info: SourceInfo {
                width,
                height,
                sample_type,
                nodata,
                georef,
                description,
            },
            decoder,
            layout,
            compression,
            chunk_bytes,
            chunk_offsets: offsets,
            prefetch: None,
            band: Vec::new(),
            band_start: 0,
            band_rows: 0,
            next_row: 0,
            columns: Vec::new(),
            until: u32::MAX,
            failed: false,
            datum,
        })
    }

    /// Whether the samples are cut into tiles (a COG is), not strips.
    pub fn is_tiled(&self) -> bool {
        matches!(self.layout, Layout::Tiles { .. })
    }

    /// Reads each band's chunks through `prefetch` before decoding them: the reader
    /// of an object in a store, told which byte ranges come next.
    pub fn set_prefetch(&mut self, prefetch: Box<dyn ChunkFetch>) {
        self.prefetch = Some(prefetch);
    }

    /// The vertical datum a known product's file name implies, when the file states
    /// none ([`GeoTiff::open`] does this for local files).
    pub fn set_datum_from_name(&mut self, path: &Path) {
        if self.datum.is_none() {
            self.datum = product_name::datum_of(path);
        }
    }

    /// The byte ranges of band `index`'s chunks.
    /// Whether the tile `across` tiles from the west edge lies over a column read.
    fn column_wanted(&self, across: u32) -> bool {
        let Layout::Tiles { tile_width, .. } = self.layout else {
            return true;
        };
        let (x0, x1) = (across * tile_width, (across + 1) * tile_width);
        self.columns.is_empty() || self.columns.iter().any(|c| c.start < x1 && x0 < c.end)
    }

    fn band_ranges(&self, index: u32) -> Vec<std::ops::Range<u64>> {
        let chunks = match self.layout {
            Layout::Strips { .. } => index..index + 1,
            Layout::Tiles { tiles_across, .. } => index * tiles_across..(index + 1) * tiles_across,
        };
        let first = chunks.start;
        chunks
            .filter(|&i| self.column_wanted(i - first))
            .map(|i| {
                let (at, len) = (self.chunk_offsets[i as usize], self.chunk_bytes[i as usize]);
                at..at + len
            })
            .collect()
    }

    /// Decodes band `index` (strip `index`, or the `index`-th row of tiles) into `self.band`.
    fn load_band(&mut self, index: u32) -> anyhow::Result<()> {
        let width = self.info.width;
        let band_height = self.layout.band_height();
        let start = index * band_height;
        let rows = band_height.min(self.info.height - start);
        if let Some(p) = &self.prefetch {
            p.band(&self.band_ranges(index))?;
            let bands = self.info.height.div_ceil(band_height);
            if index + 1 < bands && (index + 1) * band_height < self.until {
                p.ahead(&self.band_ranges(index + 1));
            }
        }
        self.band.clear();
        self.band.resize(rows as usize * width as usize, 0.0);
        self.band_start = start;
        self.band_rows = 0;
        match self.layout {
            Layout::Strips { .. } => self.decode_chunk(index, 0, width, start, rows)?,
            Layout::Tiles {
                tile_width,
                tiles_across,
                ..
            } => {
                for across in 0..tiles_across {
                    let x0 = across * tile_width;
                    let w = tile_width.min(width - x0);
                    if self.column_wanted(across) {
                        self.decode_chunk(index * tiles_across + across, x0, w, start, rows)?;
                    } else {
                        for row in self.band.chunks_exact_mut(width as usize) {
                            row[x0 as usize..(x0 + w) as usize].fill(f32::NAN);
                        }
                    }
                }
            }
        }
        self.band_rows = rows;
        Ok(())
    }

    /// Decodes chunk `index`, holding `w × rows` samples at column `x0` of the band that
    /// starts at image row `row0`, into `self.band`.
    fn decode_chunk(
        &mut self,
        index: u32,
        x0: u32,
        w: u32,
        row0: u32,
        rows: u32,
    ) -> anyhow::Result<()> {
        let kind = self.layout.chunk_kind();
        let width = self.info.width as usize;
        let (x0, w, rows) = (x0 as usize, w as usize, rows as usize);
        let band = &mut self.band[..rows * width];
        if self.chunk_bytes[index as usize] == 0 {
            // A sparse chunk (GDAL's SPARSE_OK): nothing was written, so it reads as
            // no-data, or 0 without a no-data value, as GDAL reads it.
            let fill = self.info.nodata.map_or(0.0, |v| v as f32);
            for row in band.chunks_exact_mut(width) {
                row[x0..x0 + w].fill(fill);
            }
            return Ok(());
        }
        // Rows are decoded at the full chunk width (an edge tile's padding included), so
        // that the decoder reads each chunk in one go: reading the rows of a padded LZW
        // tile one by one trips the LZW stream reader of `tiff` 0.11 on the last row
        // ("no lzw end code found").
        let chunk_w = match self.layout {
            Layout::Strips { .. } => width,
            Layout::Tiles { tile_width, .. } => tile_width as usize,
        };
        let bytes_per_sample = if self.info.sample_type == SampleType::Float32 {
            4
        } else {
            2
        };
        let mut decoded = DecodingResult::U8(Vec::new());
        // The decoder is third-party code fed untrusted bytes: a panic inside it is
        // reported as an error for this file rather than taking the process down.
        let outcome = catch_unwind(AssertUnwindSafe(|| {
            self.decoder
                .read_chunk_to_buffer(&mut decoded, index, chunk_w * bytes_per_sample)
        }));
        let rows_text = format!("rows {row0}..{}", row0 as usize + rows);
        match outcome {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                let hint = if self.compression == Compression::None {
                    String::new()
                } else {
                    format!(" (corrupt {} data?)", self.compression.name())
                };
                bail!("cannot decode TIFF {kind} {index} ({rows_text}){hint}: {e}")
            }
            Err(_) => bail!(
                "the TIFF decoder failed on {kind} {index} ({rows_text}); the file is probably corrupt"
            ),
        }
        let want = chunk_w * rows;
        let ok = match decoded {
            DecodingResult::I16(v) => place(band, width, x0, w, &v, chunk_w, want, f32::from),
            DecodingResult::U16(v) => place(band, width, x0, w, &v, chunk_w, want, f32::from),
            DecodingResult::F32(v) => place(band, width, x0, w, &v, chunk_w, want, |x| x),
            _ => bail!("TIFF {kind} {index} decoded to an unexpected sample type"),
        };
        if !ok {
            bail!(
                "TIFF {kind} {index} decoded to the wrong number of samples (expected {chunk_w}×{rows})"
            );
        }
        Ok(())
    }
}

/// Copies `w` samples from each `src_w`-sample row of `src` to column `x0` of the
/// `width`-sample rows of `band`, or returns false when `src` does not hold `want` samples.
#[allow(clippy::too_many_arguments)]
fn place<T: Copy>(
    band: &mut [f32],
    width: usize,
    x0: usize,
    w: usize,
    src: &[T],
    src_w: usize,
    want: usize,
    convert: impl Fn(T) -> f32,
) -> bool {
    if src.len() != want {
        return false;
    }
    for (dst, src) in band.chunks_exact_mut(width).zip(src.chunks_exact(src_w)) {
        for (d, &s) in dst[x0..x0 + w].iter_mut().zip(&src[..w]) {
            *d = convert(s);
        }
    }
    true
}

impl RowSource for GeoTiff {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn vertical_datum(&self) -> Option<tessera_shared::VerticalDatum> {
        self.datum.as_ref().and_then(|c| c.datum)
    }

    fn datum_clue(&self) -> Option<DatumClue> {
        self.datum.clone()
    }

    fn buffer_bytes(&self) -> u64 {
        // One band of decoded rows (f32), plus one chunk decoded and stored.
        let band = u64::from(self.layout.band_height()) * u64::from(self.info.width) * 4;
        let largest = self.chunk_bytes.iter().copied().max().unwrap_or(0);
        let chunk_w = match self.layout {
            Layout::Strips { .. } => self.info.width,
            Layout::Tiles { tile_width, .. } => tile_width,
        };
        let chunk = u64::from(chunk_w) * u64::from(self.layout.band_height()) * 4;
        // Read by range: the band's stored chunks, and the read-ahead windows.
        let fetched = self.prefetch.as_ref().map_or(0, |p| {
            let across = match self.layout {
                Layout::Strips { .. } => 1,
                Layout::Tiles { tiles_across, .. } => u64::from(tiles_across),
            };
            // This band's and the next's, fetched ahead.
            2 * across * largest + p.window_bytes()
        });
        band + chunk + largest + fetched
    }

    fn read_rows(&mut self, out: &mut [f32]) -> anyhow::Result<()> {
        let width = self.info.width as usize;
        if !out.len().is_multiple_of(width) {
            bail!(
                "read_rows needs whole rows of {width} samples, got a buffer of {}",
                out.len()
            );
        }
        let rows = out.len() / width;
        let end = u64::from(self.next_row) + rows as u64;
        if end > u64::from(self.info.height) {
            bail!(
                "read past the last row: rows {}..{end} asked of a raster of {} rows",
                self.next_row,
                self.info.height
            );
        }
        if self.failed {
            bail!("an earlier read of this TIFF failed");
        }
        let mut done = 0;
        while done < rows {
            let row = self.next_row;
            if (row < self.band_start || row >= self.band_start + self.band_rows)
                && let Err(e) = self.load_band(row / self.layout.band_height())
            {
                self.failed = true;
                return Err(e);
            }
            let n = ((self.band_start + self.band_rows - row) as usize).min(rows - done);
            let from = (row - self.band_start) as usize * width;
            out[done * width..(done + n) * width]
                .copy_from_slice(&self.band[from..from + n * width]);
            done += n;
            self.next_row += n as u32;
        }
        if self.next_row == self.info.height {
            // Finished: give the band's memory back.
            self.band = Vec::new();
            self.band_rows = 0;
        }
        Ok(())
    }

    fn skip_rows(&mut self, n: u32) -> anyhow::Result<()> {
        let end = u64::from(self.next_row) + u64::from(n);
        if end > u64::from(self.info.height) {
            bail!(
                "skipped past the last row: rows {}..{end} of a raster of {} rows",
                self.next_row,
                self.info.height
            );
        }
        // The band is decoded when a row of it is read, so skipped bands never are.
        self.next_row = end as u32;
        Ok(())
    }

    fn set_window(&mut self, columns: &[std::ops::Range<u32>], until: u32) -> anyhow::Result<()> {
        self.until = until;
        if self.columns != columns {
            self.columns = columns.to_vec();
            if matches!(self.layout, Layout::Tiles { .. }) {
                // The decoded band may lack tiles the new columns need.
                self.band_rows = 0;
            }
        }
        Ok(())
    }
}
