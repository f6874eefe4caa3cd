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
//! Georeferencing is normalised to GDAL's convention ([`GeoRef`]): the geotransform
//! names the corner of pixel (0, 0), and for `PixelIsPoint` rasters the tiepoint is
//! shifted half a pixel north-west, as GDAL does. Only north-up rasters without
//! rotation are georeferenced: a `ModelTransformationTag` with rotation or shear
//! terms, or ground control points without a pixel scale, are ignored with a
//! warning (the raster is still read, without georeferencing), because the tile
//! pyramid and [`GeoRef::extent`] assume an axis-aligned grid.
//!
//! The `GDAL_NODATA` tag is reported as [`SourceInfo::nodata`]; samples are returned
//! unchanged.

use super::{RowSource, SampleType, SourceInfo};
use anyhow::{Context, bail};
use std::fmt;
use std::fs::File;
use std::io::{BufReader, ErrorKind, Read, Seek, SeekFrom};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;
use tessera_shared::{GeoRef, RasterType};
use tiff::decoder::{ChunkType, Decoder, DecodingResult};
use tiff::tags::Tag;
use tiff::{TiffError, TiffFormatError};

/// The `tiff` crate's default limit on one decoded chunk (`Limits::decoding_buffer_size`).
const MAX_CHUNK_BYTES: u64 = 256 * 1024 * 1024;

/// Longest ASCII tag value read (GeoAsciiParams may hold a whole ESRI WKT string).
const MAX_ASCII_TAG: usize = 1 << 16;

// GeoKey ids (GeoTIFF 1.0 §6.2).
const GT_MODEL_TYPE: u16 = 1024;
const GT_RASTER_TYPE: u16 = 1025;
const GT_CITATION: u16 = 1026;
const GEOGRAPHIC_TYPE: u16 = 2048;
const GEOG_CITATION: u16 = 2049;
const PROJECTED_CS_TYPE: u16 = 3072;
const PCS_CITATION: u16 = 3073;
/// The `TIFFTagLocation` of key values stored in GeoAsciiParamsTag.
const GEO_ASCII_PARAMS: u16 = 34737;
/// GeoKey value meaning "user-defined" (no EPSG code).
const USER_DEFINED: u16 = 32767;

/// A TIFF compression the reader accepts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Compression {
    None,
    Lzw,
    Deflate,
    PackBits,
}

impl Compression {
    fn from_code(code: u16) -> anyhow::Result<Self> {
        Ok(match code {
            1 => Self::None,
            5 => Self::Lzw,
            8 | 32946 => Self::Deflate,
            32773 => Self::PackBits,
            _ => bail!(
                "unsupported TIFF compression {} ({code}); supported: none, deflate, LZW, PackBits",
                compression_name(code)
            ),
        })
    }

    const fn name(self) -> &'static str {
        match self {
            Self::None => "uncompressed",
            Self::Lzw => "LZW",
            Self::Deflate => "deflate",
            Self::PackBits => "PackBits",
        }
    }

    /// The best ratio of decoded to stored bytes the compression can reach, so a
    /// header's claimed size can be checked against the bytes the file really holds.
    const fn max_ratio(self) -> u64 {
        match self {
            Self::None => 1,
            // A 2-byte run header and byte expand to at most 128 bytes.
            Self::PackBits => 64,
            // A 258-byte match per code of as little as ~2 bits.
            Self::Deflate => 1032,
            // 12-bit codes whose strings grow by one byte per code until the table
            // (4096 entries) is cleared: ~7.4 MB from ~5.7 KB of codes, about 1300:1.
            Self::Lzw => 1400,
        }
    }
}

/// Names of the TIFF compression codes one meets in the wild, for error messages.
fn compression_name(code: u16) -> &'static str {
    match code {
        1 => "none",
        2 => "CCITT RLE",
        3 => "CCITT Group 3 fax",
        4 => "CCITT Group 4 fax",
        5 => "LZW",
        6 => "old-style JPEG",
        7 => "JPEG",
        8 | 32946 => "deflate",
        9 | 10 | 34661 => "JBIG",
        32773 => "PackBits",
        34676 | 34677 => "SGI LogLuv",
        34712 => "JPEG 2000",
        34887 => "LERC",
        34925 => "LZMA",
        50000 => "Zstandard",
        50001 => "WebP",
        50002 | 52546 => "JPEG XL",
        _ => "unknown",
    }
}

/// How the samples are cut into separately compressed chunks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Layout {
    Strips {
        rows_per_strip: u32,
    },
    Tiles {
        tile_width: u32,
        tile_height: u32,
        tiles_across: u32,
    },
}

impl Layout {
    /// Rows decoded together: one strip, or one row of tiles.
    const fn band_height(self) -> u32 {
        match self {
            Self::Strips { rows_per_strip } => rows_per_strip,
            Self::Tiles { tile_height, .. } => tile_height,
        }
    }

    const fn chunk_kind(self) -> &'static str {
        match self {
            Self::Strips { .. } => "strip",
            Self::Tiles { .. } => "tile",
        }
    }
}

/// What a GeoTIFF is read from: a buffered file, or any seekable reader
/// ([`GeoTiff::from_reader`], e.g. bytes in memory for the fuzz targets).
pub trait TiffInput: Read + Seek + Send {}
impl<T: Read + Seek + Send> TiffInput for T {}

type Reader = Box<dyn TiffInput>;

/// A GeoTIFF read as rows, one strip or row of tiles at a time.
pub struct GeoTiff {
    info: SourceInfo,
    decoder: Decoder<Reader>,
    layout: Layout,
    compression: Compression,
    /// Compressed size of every chunk; 0 marks a sparse (absent) chunk.
    chunk_bytes: Vec<u64>,
    /// The decoded band: rows `band_start .. band_start + band_rows`, `width` samples each.
    band: Vec<f32>,
    band_start: u32,
    band_rows: u32,
    /// The next row `read_rows` returns.
    next_row: u32,
    /// Set when decoding failed: the decoder's state is then unknown.
    failed: bool,
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

/// Reads an ASCII (or byte) tag as text, without the crate's strict NUL handling.
fn ascii_tag(decoder: &mut Decoder<Reader>, tag: Tag) -> anyhow::Result<Option<String>> {
    let mut ifd = decoder.image_ifd();
    let Some(entry) = ifd.find_entry(tag) else {
        return Ok(None);
    };
    let len = usize::try_from(entry.count())
        .unwrap_or(usize::MAX)
        .min(MAX_ASCII_TAG);
    let mut buf = vec![0u8; len];
    let got = ifd
        .find_tag_bytes(tag, &mut buf, 0)
        .with_context(|| format!("cannot read TIFF tag {}", tag.to_u16()))?
        .unwrap_or(0);
    buf.truncate(got.min(len));
    Ok(Some(String::from_utf8_lossy(&buf).into_owned()))
}

/// The GeoKeys the reader uses.
#[derive(Debug, Default)]
struct GeoKeys {
    model_type: Option<u16>,
    raster_type: Option<u16>,
    geographic_type: Option<u16>,
    projected_type: Option<u16>,
    gt_citation: Option<String>,
    geog_citation: Option<String>,
    pcs_citation: Option<String>,
}

impl GeoKeys {
    /// Parses GeoKeyDirectoryTag: a header `[version, revision, minor, nkeys]`, then
    /// `nkeys` entries `[KeyID, TIFFTagLocation, Count, Value]`. Location 0 means the
    /// value is the short itself; location 34737 names `Count` characters of the ASCII
    /// parameters starting at `Value`.
    fn parse(dir: &[u16], ascii: Option<&str>) -> Self {
        let mut keys = Self::default();
        let Some(&[_, _, _, nkeys]) = dir.get(..4) else {
            tracing::warn!("ignoring a GeoKeyDirectoryTag of only {} values", dir.len());
            return keys;
        };
        for (i, entry) in dir[4..].chunks(4).take(usize::from(nkeys)).enumerate() {
            let &[id, location, count, value] = entry else {
                tracing::warn!("GeoKeyDirectoryTag is cut short after {i} of {nkeys} keys");
                break;
            };
            let text = || {
                let start = usize::from(value);
                let end = start + usize::from(count);
                ascii?.get(start..end.min(ascii?.len())).map(str::to_owned)
            };
            match (id, location) {
                (GT_MODEL_TYPE, 0) => keys.model_type = Some(value),
                (GT_RASTER_TYPE, 0) => keys.raster_type = Some(value),
                (GEOGRAPHIC_TYPE, 0) => keys.geographic_type = Some(value),
                (PROJECTED_CS_TYPE, 0) => keys.projected_type = Some(value),
                (GT_CITATION, GEO_ASCII_PARAMS) => keys.gt_citation = text(),
                (GEOG_CITATION, GEO_ASCII_PARAMS) => keys.geog_citation = text(),
                (PCS_CITATION, GEO_ASCII_PARAMS) => keys.pcs_citation = text(),
                _ => {}
            }
        }
        keys
    }

    /// The EPSG code of the horizontal CRS: the projected CRS for projected models, the
    /// geographic CRS for geographic ones. 0 (undefined) and 32767 (user-defined) give none.
    fn epsg(&self) -> Option<u32> {
        let code = |c: Option<u16>| c.filter(|&c| c != 0 && c != USER_DEFINED).map(u32::from);
        match self.model_type {
            Some(1) => code(self.projected_type),
            Some(2) => code(self.geographic_type),
            None => code(self.projected_type).or_else(|| code(self.geographic_type)),
            Some(_) => None,
        }
    }

    /// A readable CRS name from the citation keys, when one is given.
    fn crs_name(&self) -> Option<String> {
        let candidates = if self.model_type == Some(2) {
            [&self.geog_citation, &self.gt_citation, &self.pcs_citation]
        } else {
            [&self.gt_citation, &self.pcs_citation, &self.geog_citation]
        };
        candidates
            .into_iter()
            .find_map(|c| clean_citation(c.as_deref()?))
    }

    fn raster_type(&self) -> RasterType {
        match self.raster_type {
            Some(2) => RasterType::PixelIsPoint,
            Some(1) | None => RasterType::PixelIsArea,
            Some(other) => {
                tracing::warn!("unknown GTRasterTypeGeoKey {other}; assuming PixelIsArea");
                RasterType::PixelIsArea
            }
        }
    }
}

/// Tidies a citation: drops the `|` terminators, ESRI's `PCS Name = ` prefixes, long
/// WKT strings and placeholders such as "unknown".
fn clean_citation(raw: &str) -> Option<String> {
    let first = raw
        .split('|')
        .next()
        .unwrap_or("")
        .trim_matches(|c: char| c == '\0' || c.is_whitespace());
    let name = first
        .strip_prefix("PCS Name = ")
        .or_else(|| first.strip_prefix("GCS Name = "))
        .unwrap_or(first)
        .trim();
    let useless = name.is_empty()
        || name.len() > 200
        || name.eq_ignore_ascii_case("unknown")
        || name.eq_ignore_ascii_case("unnamed")
        || name.starts_with("ESRI PE String");
    (!useless).then(|| name.to_owned())
}

/// Reads a tag holding doubles; a malformed value is a warning and counts as absent,
/// so bad georeferencing never stops the samples from being read.
fn f64_tag(decoder: &mut Decoder<Reader>, tag: Tag, name: &str) -> Option<Vec<f64>> {
    match decoder
        .find_tag(tag)
        .and_then(|v| v.map(tiff::decoder::ifd::Value::into_f64_vec).transpose())
    {
        Ok(v) => v,
        Err(e) => {
            tracing::warn!("ignoring unreadable {name}: {e}");
            None
        }
    }
}

/// The geotransform for the corner of pixel (0, 0) as the file states it (before any
/// PixelIsPoint shift), or `None` when the file has no usable north-up georeferencing.
fn raw_geotransform(decoder: &mut Decoder<Reader>) -> Option<[f64; 6]> {
    let transform = f64_tag(
        decoder,
        Tag::ModelTransformationTag,
        "ModelTransformationTag",
    );
    let scale = f64_tag(decoder, Tag::ModelPixelScaleTag, "ModelPixelScaleTag");
    let tiepoints = f64_tag(decoder, Tag::ModelTiepointTag, "ModelTiepointTag");
    let gt = if let Some(m) = transform {
        if m.len() < 16 {
            tracing::warn!(
                "ignoring georeferencing: ModelTransformationTag has {} values, not 16",
                m.len()
            );
            return None;
        }
        if m[1] != 0.0 || m[4] != 0.0 {
            tracing::warn!(
                "ignoring georeferencing: the ModelTransformationTag rotates or shears the raster \
                 (terms {} and {}); only north-up rasters are supported",
                m[1],
                m[4]
            );
            return None;
        }
        [m[3], m[0], m[1], m[7], m[4], m[5]]
    } else {
        match (scale, tiepoints) {
            (Some(s), Some(t)) if s.len() >= 2 && t.len() >= 6 => {
                if t.len() > 6 {
                    tracing::warn!(
                        "ModelTiepointTag holds {} tiepoints; using the first with the pixel scale",
                        t.len() / 6
                    );
                }
                let (sx, sy) = (s[0], s[1]);
                [t[3] - t[0] * sx, sx, 0.0, t[4] + t[1] * sy, 0.0, -sy]
            }
            (None, Some(t)) if t.len() >= 6 => {
                tracing::warn!(
                    "ignoring georeferencing: {} ground control points without a pixel scale \
                     are not supported",
                    t.len() / 6
                );
                return None;
            }
            (None, None) => return None,
            _ => {
                tracing::warn!(
                    "ignoring georeferencing: ModelPixelScaleTag and ModelTiepointTag are incomplete"
                );
                return None;
            }
        }
    };
    if gt.iter().any(|v| !v.is_finite()) || gt[1] == 0.0 || gt[5] == 0.0 {
        tracing::warn!("ignoring georeferencing: degenerate geotransform {gt:?}");
        return None;
    }
    Some(gt)
}

/// Reads the GeoTIFF tags into a [`GeoRef`] (GDAL's corner convention).
fn read_georef(decoder: &mut Decoder<Reader>) -> Option<GeoRef> {
    let dir = match decoder
        .find_tag(Tag::GeoKeyDirectoryTag)
        .and_then(|v| v.map(tiff::decoder::ifd::Value::into_u16_vec).transpose())
    {
        Ok(d) => d,
        Err(e) => {
            tracing::warn!("ignoring unreadable GeoKeyDirectoryTag: {e}");
            None
        }
    };
    let ascii = match ascii_tag(decoder, Tag::GeoAsciiParamsTag) {
        Ok(a) => a,
        Err(e) => {
            tracing::warn!("ignoring unreadable GeoAsciiParamsTag: {e:#}");
            None
        }
    };
    let keys = dir
        .as_deref()
        .map(|d| GeoKeys::parse(d, ascii.as_deref()))
        .unwrap_or_default();
    let Some(mut gt) = raw_geotransform(decoder) else {
        if dir.is_some() {
            tracing::warn!(
                "the GeoTIFF names a CRS but has no usable geotransform; ignoring its georeferencing"
            );
        }
        return None;
    };
    let raster_type = keys.raster_type();
    if raster_type == RasterType::PixelIsPoint {
        // The tiepoint is the centre of the first sample: move to its corner, as GDAL does.
        gt[0] -= 0.5 * gt[1] + 0.5 * gt[2];
        gt[3] -= 0.5 * gt[4] + 0.5 * gt[5];
    }
    Some(GeoRef {
        epsg: keys.epsg(),
        crs_name: keys.crs_name(),
        geotransform: gt,
        raster_type,
    })
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
    pub fn open(path: &Path) -> anyhow::Result<Self> {
        let file = File::open(path).context("cannot open file")?;
        Self::from_reader(BufReader::with_capacity(1 << 16, file))
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
            band: Vec::new(),
            band_start: 0,
            band_rows: 0,
            next_row: 0,
            failed: false,
        })
    }

    /// Decodes band `index` (strip `index`, or the `index`-th row of tiles) into `self.band`.
    fn load_band(&mut self, index: u32) -> anyhow::Result<()> {
        let width = self.info.width;
        let band_height = self.layout.band_height();
        let start = index * band_height;
        let rows = band_height.min(self.info.height - start);
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
                    self.decode_chunk(index * tiles_across + across, x0, w, start, rows)?;
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

    fn buffer_bytes(&self) -> u64 {
        // One band of decoded rows (f32), plus one chunk decoded and stored.
        let band = u64::from(self.layout.band_height()) * u64::from(self.info.width) * 4;
        let largest = self.chunk_bytes.iter().copied().max().unwrap_or(0);
        let chunk_w = match self.layout {
            Layout::Strips { .. } => self.info.width,
            Layout::Tiles { tile_width, .. } => tile_width,
        };
        let chunk = u64::from(chunk_w) * u64::from(self.layout.band_height()) * 4;
        band + chunk + largest
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
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;
    use std::sync::atomic::{AtomicU32, Ordering};
    use tessera_shared::testdata;
    use tiff::encoder::compression::{CompressionAlgorithm, Deflate, Lzw, Packbits};

    // ---- helpers -------------------------------------------------------------

    /// A file in the system temp directory, removed on drop.
    struct TempFile(PathBuf);

    impl TempFile {
        fn new(name: &str, bytes: &[u8]) -> Self {
            static COUNTER: AtomicU32 = AtomicU32::new(0);
            let path = std::env::temp_dir().join(format!(
                "tessera-geotiff-test-{}-{}-{name}",
                std::process::id(),
                COUNTER.fetch_add(1, Ordering::Relaxed)
            ));
            std::fs::write(&path, bytes).expect("write temp file");
            Self(path)
        }
    }

    impl Drop for TempFile {
        fn drop(&mut self) {
            let _ = std::fs::remove_file(&self.0);
        }
    }

    /// Reads every row, `chunk` rows at a time (then the remainder).
    fn read_all(src: &mut GeoTiff, chunk: u32) -> Vec<f32> {
        let (w, h) = (src.info().width as usize, src.info().height as usize);
        let mut all = vec![0.0; w * h];
        for part in all.chunks_mut(chunk as usize * w) {
            src.read_rows(part).expect("read_rows");
            // Out of core: never more than one strip or row of tiles is held decoded.
            assert!(src.band.len() <= src.layout.band_height() as usize * w);
        }
        all
    }

    /// FNV-1a over the bit patterns of the samples.
    fn checksum(samples: &[f32]) -> u64 {
        samples.iter().fold(0xcbf2_9ce4_8422_2325, |h, v| {
            (h ^ u64::from(v.to_bits())).wrapping_mul(0x0100_0000_01b3)
        })
    }

    /// What a real file's samples look like: (min, max) over valid samples and the
    /// number of no-data samples (equal to the no-data value as f32, or NaN).
    fn stats(samples: &[f32], nodata: Option<f64>) -> (f64, f64, u64) {
        let nd = nodata.map(|v| v as f32);
        let (mut lo, mut hi, mut missing) = (f32::INFINITY, f32::NEG_INFINITY, 0);
        for &v in samples {
            if v.is_nan() || Some(v) == nd {
                missing += 1;
            } else {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        (f64::from(lo), f64::from(hi), missing)
    }

    fn close(got: f64, want: f64, tol: f64) -> bool {
        (got - want).abs() <= tol * want.abs().max(1.0)
    }

    fn assert_same(got: &[f64], want: &[f64]) {
        assert!(
            got.len() == want.len() && got.iter().zip(want).all(|(g, w)| close(*g, *w, 1e-12)),
            "{got:?} vs {want:?}"
        );
    }

    /// What a real-file test expects beyond the shared facts.
    struct Expect {
        sample_type: SampleType,
        nodata: f64,
        raster_type: RasterType,
        /// Pixel size (x, |y|) and the corner of pixel (0, 0), from the README.
        pixel: f64,
        corner: (f64, f64),
        description: &'static str,
        tolerance: f64,
    }

    /// Opens a README DEM, reads it 7 rows at a time and checks it against the facts.
    fn check_real(name: &str, e: &Expect) -> Option<Vec<f32>> {
        let path = testdata::dem_or_skip(name)?;
        let f = testdata::facts(name);
        let mut src = GeoTiff::open(&path).expect("open");
        let info = src.info().clone();
        println!(
            "{name}: {} nodata {:?} georef {:?}",
            info.description, info.nodata, info.georef
        );
        assert_eq!((info.width, info.height), (f.width, f.height));
        assert_eq!(info.sample_type, e.sample_type);
        assert!(
            info.description.contains(e.description),
            "{:?} lacks {:?}",
            info.description,
            e.description
        );
        let nodata = info.nodata.expect("GDAL_NODATA");
        assert!(close(nodata, e.nodata, 1e-6), "nodata {nodata}");
        let g = info.georef.expect("georeferenced");
        assert_eq!(g.epsg, f.epsg);
        assert_eq!(g.raster_type, e.raster_type);
        let gt = g.geotransform;
        assert!(
            close(gt[1], e.pixel, 1e-9) && close(-gt[5], e.pixel, 1e-9),
            "{gt:?}"
        );
        assert!(gt[2] == 0.0 && gt[4] == 0.0, "{gt:?}");
        assert!(
            close(gt[0], e.corner.0, 1e-9) && close(gt[3], e.corner.1, 1e-9),
            "{gt:?}"
        );
        if let Some(want) = f.extent {
            for (got, want) in g.extent(f.width, f.height).iter().zip(want) {
                assert!(close(*got, want, 1e-9), "extent {got} vs {want}");
            }
        }

        let samples = read_all(&mut src, 7);
        let (lo, hi, missing) = stats(&samples, info.nodata);
        println!("{name}: min {lo} max {hi} nodata samples {missing}");
        assert!((lo - f.min).abs() <= e.tolerance, "min {lo} vs {}", f.min);
        assert!((hi - f.max).abs() <= e.tolerance, "max {hi} vs {}", f.max);
        assert_eq!(missing, f.nodata_count);
        // Every row has been read: one more is an error.
        let w = f.width as usize;
        assert!(src.read_rows(&mut vec![0.0; w]).is_err());
        Some(samples)
    }

    // ---- real files ----------------------------------------------------------

    #[test]
    fn reads_n46e008_pixel_is_point_with_voids() {
        let arc3 = 1.0 / 1200.0;
        check_real(
            "N46E008.tif",
            &Expect {
                sample_type: SampleType::Int16,
                nodata: -32767.0,
                raster_type: RasterType::PixelIsPoint,
                pixel: arc3,
                // The tiepoint (8 E, 47 N) is the first sample's centre.
                corner: (8.0 - arc3 / 2.0, 47.0 + arc3 / 2.0),
                description: "GeoTIFF int16, uncompressed, 1201 rows in strips of 3",
                tolerance: 0.0,
            },
        );
    }

    #[test]
    fn reads_luxembourg_lzw_strips() {
        check_real(
            "luxembourg_elev.tif",
            &Expect {
                sample_type: SampleType::Int16,
                nodata: -32768.0,
                raster_type: RasterType::PixelIsArea,
                pixel: 1.0 / 120.0,
                corner: (5.741_666_666_666_666, 50.191_666_666_666_66),
                description: "GeoTIFF int16, LZW, 90 rows in strips of 43",
                tolerance: 0.0,
            },
        );
    }

    #[test]
    fn reads_aletsch_float32_lv95() {
        let Some(path) = testdata::dem_or_skip("aletsch.tif") else {
            return;
        };
        check_real(
            "aletsch.tif",
            &Expect {
                sample_type: SampleType::Float32,
                nodata: -9999.0,
                raster_type: RasterType::PixelIsArea,
                pixel: 200.0,
                corner: (2_601_100.0, 1_184_500.0),
                description: "GeoTIFF float32, uncompressed, 310 rows in strips of 5",
                // The README rounds this range to 0.1 m (502.0..4216.3).
                tolerance: 0.05,
            },
        );
        let src = GeoTiff::open(&path).expect("open");
        let crs = src.info().georef.as_ref().and_then(|g| g.crs_name.clone());
        assert_eq!(crs.as_deref(), Some("CH1903+ / LV95"));
    }

    #[test]
    fn reads_lidar_float32_tiles() {
        check_real(
            "lidar_dem_1m.tif",
            &Expect {
                sample_type: SampleType::Float32,
                // Written by an ESRI tool as "-3.4028229999999999e+038".
                nodata: -3.402_823e38,
                raster_type: RasterType::PixelIsArea,
                pixel: 1.0,
                corner: (429_252.313_370_022, 5_150_885.424_942_633),
                description: "GeoTIFF float32, uncompressed, tiled 128×128",
                tolerance: 0.01,
            },
        );
    }

    #[test]
    fn reads_bigtujunga_int16_tiles() {
        check_real(
            "bigtujunga.tif",
            &Expect {
                sample_type: SampleType::Int16,
                nodata: 32767.0,
                raster_type: RasterType::PixelIsArea,
                pixel: 30.0,
                corner: (376_313.655_454_263_5, 3_807_917.827_628_375_5),
                description: "GeoTIFF int16, uncompressed, tiled 128×128",
                tolerance: 0.0,
            },
        );
    }

    #[test]
    fn chunk_size_does_not_change_the_samples() {
        for name in ["bigtujunga.tif", "lidar_dem_1m.tif", "N46E008.tif"] {
            let Some(path) = testdata::dem_or_skip(name) else {
                continue;
            };
            let sums: Vec<u64> = [1, 64, 5, 1000]
                .iter()
                .map(|&chunk| checksum(&read_all(&mut GeoTiff::open(&path).expect("open"), chunk)))
                .collect();
            assert!(sums.iter().all(|&s| s == sums[0]), "{name}: {sums:x?}");
        }
    }

    #[test]
    fn jpeg_compression_is_rejected_in_open() {
        let Some(path) = testdata::dem_or_skip("luxembourg_elev.tif") else {
            return;
        };
        let mut bytes = std::fs::read(path).expect("read");
        assert_eq!(
            &bytes[..4],
            b"II*\0",
            "the test patches a little-endian TIFF"
        );
        let u16_at = |b: &[u8], at: usize| u16::from_le_bytes([b[at], b[at + 1]]);
        let ifd = u32::from_le_bytes(bytes[4..8].try_into().expect("4 bytes")) as usize;
        let entry = (0..usize::from(u16_at(&bytes, ifd)))
            .map(|i| ifd + 2 + 12 * i)
            .find(|&at| u16_at(&bytes, at) == 259)
            .expect("a Compression entry");
        assert_eq!(u16_at(&bytes, entry + 2), 3, "Compression is a SHORT");
        bytes[entry + 8..entry + 10].copy_from_slice(&7u16.to_le_bytes());
        let file = TempFile::new("jpeg.tif", &bytes);
        let err = GeoTiff::open(&file.0)
            .expect_err("JPEG must be rejected")
            .to_string();
        assert!(
            err.contains("compression") && err.contains("JPEG (7)"),
            "{err}"
        );
    }

    #[test]
    fn truncated_tiled_file_is_an_error_not_a_panic() {
        let Some(path) = testdata::dem_or_skip("bigtujunga.tif") else {
            return;
        };
        let bytes = std::fs::read(path).expect("read");
        let file = TempFile::new("truncated.tif", &bytes[..bytes.len() * 6 / 10]);
        match GeoTiff::open(&file.0) {
            Err(e) => {
                let e = e.to_string();
                assert!(e.starts_with("truncated TIFF"), "{e}");
            }
            Ok(mut src) => {
                let w = src.info().width as usize;
                let mut buf = vec![0.0; w * 7];
                let failed = (0..src.info().height / 7).any(|_| src.read_rows(&mut buf).is_err());
                assert!(failed, "all rows of a truncated file were read");
            }
        }
    }

    // ---- synthetic files -----------------------------------------------------

    /// A little-endian TIFF written by hand, so that every layout, compression and
    /// predictor the reader supports (and some it does not) can be produced.
    struct Spec {
        width: u32,
        height: u32,
        bits: u16,
        format: u16,
        bands: u16,
        /// `(tile_width, tile_height)`; strips when `None`.
        tiles: Option<(u32, u32)>,
        rows_per_strip: u32,
        compression: u16,
        predictor: u16,
        /// Extra tags: `(tag, type, count, value bytes)`.
        extra: Vec<(u16, u16, u32, Vec<u8>)>,
        /// Sample values, row-major, `bands` per pixel.
        values: Vec<f64>,
        /// Replaces every chunk's stored byte count (a header that lies).
        byte_counts: Option<u32>,
    }

    impl Spec {
        fn new(width: u32, height: u32, sample: SampleType, values: Vec<f64>) -> Self {
            let (bits, format) = match sample {
                SampleType::Int16 => (16, 2),
                SampleType::UInt16 => (16, 1),
                SampleType::Float32 => (32, 3),
            };
            Self {
                width,
                height,
                bits,
                format,
                bands: 1,
                tiles: None,
                rows_per_strip: 5,
                compression: 1,
                predictor: 1,
                extra: Vec::new(),
                values,
                byte_counts: None,
            }
        }

        fn ascii(mut self, tag: u16, text: &str) -> Self {
            let mut b = text.as_bytes().to_vec();
            b.push(0);
            self.extra.push((tag, 2, b.len() as u32, b));
            self
        }

        fn shorts(mut self, tag: u16, v: &[u16]) -> Self {
            let b = v.iter().flat_map(|x| x.to_le_bytes()).collect();
            self.extra.push((tag, 3, v.len() as u32, b));
            self
        }

        fn doubles(mut self, tag: u16, v: &[f64]) -> Self {
            let b = v.iter().flat_map(|x| x.to_le_bytes()).collect();
            self.extra.push((tag, 12, v.len() as u32, b));
            self
        }

        /// One sample's little-endian bytes.
        fn sample_bytes(&self, v: f64) -> Vec<u8> {
            match (self.bits, self.format) {
                (8, 1) => vec![v as u8],
                (16, 1) => (v as u16).to_le_bytes().to_vec(),
                (16, 2) => (v as i16).to_le_bytes().to_vec(),
                (32, 3) => (v as f32).to_le_bytes().to_vec(),
                (64, 3) => v.to_le_bytes().to_vec(),
                other => panic!("test writer cannot encode {other:?}"),
            }
        }

        /// Applies the predictor to one row of `n` samples of `size` bytes.
        fn predict(&self, row: &mut [u8]) {
            let size = usize::from(self.bits / 8);
            let stride = usize::from(self.bands);
            match self.predictor {
                2 => {
                    let n = row.len() / size;
                    for i in (stride..n).rev() {
                        let (a, b) = (i * size, (i - stride) * size);
                        match size {
                            2 => {
                                let v = u16::from_le_bytes([row[a], row[a + 1]])
                                    .wrapping_sub(u16::from_le_bytes([row[b], row[b + 1]]));
                                row[a..a + 2].copy_from_slice(&v.to_le_bytes());
                            }
                            4 => {
                                let get = |r: &[u8], at: usize| {
                                    u32::from_le_bytes(r[at..at + 4].try_into().expect("4"))
                                };
                                let v = get(row, a).wrapping_sub(get(row, b));
                                row[a..a + 4].copy_from_slice(&v.to_le_bytes());
                            }
                            _ => row[a] = row[a].wrapping_sub(row[b]),
                        }
                    }
                }
                3 => {
                    // Byte planes, most significant first, then byte differences.
                    let n = row.len() / size;
                    let mut planes = vec![0u8; row.len()];
                    for i in 0..n {
                        for byte in 0..size {
                            planes[byte * n + i] = row[i * size + (size - 1 - byte)];
                        }
                    }
                    for j in (stride..planes.len()).rev() {
                        planes[j] = planes[j].wrapping_sub(planes[j - stride]);
                    }
                    row.copy_from_slice(&planes);
                }
                _ => {}
            }
        }

        fn compress(&self, raw: &[u8]) -> Vec<u8> {
            let mut out = Vec::new();
            match self.compression {
                5 => Lzw.write_to(&mut out, raw),
                8 | 32946 => Deflate::default().write_to(&mut out, raw),
                32773 => Packbits.write_to(&mut out, raw),
                _ => {
                    out.extend_from_slice(raw);
                    Ok(0)
                }
            }
            .expect("compress");
            out
        }

        /// The encoded chunks, row-major; tiles are padded with zeros.
        fn chunks(&self) -> Vec<Vec<u8>> {
            let (w, h, bands) = (self.width, self.height, u32::from(self.bands));
            let sample = |x: u32, y: u32, b: u32| {
                if x < w && y < h {
                    self.values[((y * w + x) * bands + b) as usize]
                } else {
                    0.0
                }
            };
            let mut rects = Vec::new();
            if let Some((tw, th)) = self.tiles {
                for ty in 0..h.div_ceil(th) {
                    for tx in 0..w.div_ceil(tw) {
                        rects.push((tx * tw, ty * th, tw, th));
                    }
                }
            } else {
                let rps = self.rows_per_strip;
                for s in 0..h.div_ceil(rps) {
                    rects.push((0, s * rps, w, rps.min(h - s * rps)));
                }
            }
            rects
                .into_iter()
                .map(|(x0, y0, cw, ch)| {
                    let mut raw = Vec::new();
                    for y in y0..y0 + ch {
                        let mut row: Vec<u8> = (x0..x0 + cw)
                            .flat_map(|x| (0..bands).map(move |b| (x, b)))
                            .flat_map(|(x, b)| self.sample_bytes(sample(x, y, b)))
                            .collect();
                        self.predict(&mut row);
                        raw.extend_from_slice(&row);
                    }
                    self.compress(&raw)
                })
                .collect()
        }

        fn encode(&self) -> Vec<u8> {
            let mut out = b"II*\0\0\0\0\0".to_vec();
            let chunks = self.chunks();
            let (mut offsets, mut counts) = (Vec::new(), Vec::new());
            for c in &chunks {
                offsets.push(out.len() as u32);
                counts.push(self.byte_counts.unwrap_or(c.len() as u32));
                out.extend_from_slice(c);
            }
            let longs = |v: &[u32]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
            let short = |v: u16| v.to_le_bytes().to_vec();
            let per_band =
                |v: u16| -> Vec<u8> { (0..self.bands).flat_map(|_| v.to_le_bytes()).collect() };
            let n = chunks.len() as u32;
            let bands = u32::from(self.bands);
            let mut tags: Vec<(u16, u16, u32, Vec<u8>)> = vec![
                (256, 4, 1, longs(&[self.width])),
                (257, 4, 1, longs(&[self.height])),
                (258, 3, bands, per_band(self.bits)),
                (259, 3, 1, short(self.compression)),
                (262, 3, 1, short(if self.bands == 3 { 2 } else { 1 })),
                (277, 3, 1, short(self.bands)),
                (284, 3, 1, short(1)),
                (339, 3, bands, per_band(self.format)),
            ];
            if self.predictor != 1 {
                tags.push((317, 3, 1, short(self.predictor)));
            }
            if let Some((tw, th)) = self.tiles {
                tags.push((322, 4, 1, longs(&[tw])));
                tags.push((323, 4, 1, longs(&[th])));
                tags.push((324, 4, n, longs(&offsets)));
                tags.push((325, 4, n, longs(&counts)));
            } else {
                tags.push((273, 4, n, longs(&offsets)));
                tags.push((278, 4, 1, longs(&[self.rows_per_strip])));
                tags.push((279, 4, n, longs(&counts)));
            }
            tags.extend(self.extra.iter().cloned());
            tags.sort_by_key(|t| t.0);
            // Values longer than 4 bytes go before the directory.
            let mut fields = Vec::new();
            for (tag, ty, count, value) in tags {
                let field = if value.len() <= 4 {
                    let mut v = value.clone();
                    v.resize(4, 0);
                    v
                } else {
                    if out.len() % 2 == 1 {
                        out.push(0);
                    }
                    let at = (out.len() as u32).to_le_bytes().to_vec();
                    out.extend_from_slice(&value);
                    at
                };
                fields.push((tag, ty, count, field));
            }
            if out.len() % 2 == 1 {
                out.push(0);
            }
            let ifd = out.len() as u32;
            out[4..8].copy_from_slice(&ifd.to_le_bytes());
            out.extend_from_slice(&(fields.len() as u16).to_le_bytes());
            for (tag, ty, count, field) in fields {
                out.extend_from_slice(&tag.to_le_bytes());
                out.extend_from_slice(&ty.to_le_bytes());
                out.extend_from_slice(&count.to_le_bytes());
                out.extend_from_slice(&field);
            }
            out.extend_from_slice(&0u32.to_le_bytes());
            out
        }

        fn write(&self, name: &str) -> TempFile {
            TempFile::new(name, &self.encode())
        }
    }

    /// A test surface that exercises signs, large steps and (for floats) fractions.
    fn surface(width: u32, height: u32, sample: SampleType) -> Vec<f64> {
        (0..height)
            .flat_map(|y| (0..width).map(move |x| (x, y)))
            .map(|(x, y)| {
                let v = f64::from(x * 37 + y * 101 % 4099) + f64::from((x ^ y) % 13) * 211.0;
                match sample {
                    SampleType::Int16 => v - 3000.0,
                    SampleType::UInt16 => v * 7.0,
                    SampleType::Float32 => (v - 1500.0) * 0.125 + 0.001 * f64::from(x),
                }
            })
            .collect()
    }

    /// Writes the GeoTIFF seeds of the fuzz target (`fuzz/corpus/geotiff/`): tiny
    /// files covering each layout, compression, predictor and the georeferencing
    /// tags. Run by hand when the writer changes:
    /// `cargo test -p tessera-server --lib write_fuzz_seeds -- --ignored`.
    #[test]
    #[ignore = "writes files into fuzz/corpus"]
    fn write_fuzz_seeds() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus/geotiff");
        std::fs::create_dir_all(&dir).expect("corpus dir");
        let (w, h) = (12, 9);
        let seeds: Vec<(&str, Spec)> = vec![
            (
                "seed-int16-strips",
                Spec::new(w, h, SampleType::Int16, surface(w, h, SampleType::Int16)),
            ),
            ("seed-uint16-lzw-pred2-tiled", {
                let mut s = Spec::new(w, h, SampleType::UInt16, surface(w, h, SampleType::UInt16));
                (s.compression, s.predictor, s.tiles) = (5, 2, Some((16, 16)));
                s
            }),
            ("seed-float32-deflate-pred3", {
                let mut s = Spec::new(
                    w,
                    h,
                    SampleType::Float32,
                    surface(w, h, SampleType::Float32),
                );
                (s.compression, s.predictor) = (8, 3);
                s
            }),
            ("seed-int16-packbits-tiled-geo", {
                let mut s = Spec::new(w, h, SampleType::Int16, surface(w, h, SampleType::Int16))
                    .doubles(33550, &[10.0, 20.0, 0.0])
                    .doubles(33922, &[0.0, 0.0, 0.0, 500_000.0, 4_000_000.0, 0.0])
                    .shorts(
                        34735,
                        &[1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 2, 3072, 0, 1, 32632],
                    )
                    .ascii(42113, "-32768");
                (s.compression, s.tiles) = (32773, Some((16, 16)));
                s
            }),
            ("seed-float32-lzw-transform-ascii", {
                let mut s = Spec::new(
                    w,
                    h,
                    SampleType::Float32,
                    surface(w, h, SampleType::Float32),
                )
                .doubles(
                    34264,
                    &[
                        2.0, 0.0, 0.0, 100.0, 0.0, -2.0, 0.0, 50.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                        0.0, 1.0,
                    ],
                )
                .shorts(34735, &[1, 1, 0, 2, 1024, 0, 1, 2, 2049, 34737, 7, 0])
                .ascii(34737, "WGS 84|");
                (s.compression, s.rows_per_strip) = (5, 4);
                s
            }),
        ];
        for (name, spec) in seeds {
            let bytes = spec.encode();
            GeoTiff::from_reader(std::io::Cursor::new(bytes.clone())).expect(name);
            std::fs::write(dir.join(name), bytes).expect("write seed");
        }
    }

    #[test]
    fn every_supported_encoding_reads_back_exactly() {
        let (w, h) = (37, 23);
        let mut cases = 0;
        for sample in [SampleType::Int16, SampleType::UInt16, SampleType::Float32] {
            let values = surface(w, h, sample);
            let want: Vec<f32> = values.iter().map(|&v| v as f32).collect();
            let predictors: &[u16] = if sample == SampleType::Float32 {
                &[1, 2, 3]
            } else {
                &[1, 2]
            };
            for compression in [1, 5, 8, 32946, 32773] {
                for &predictor in predictors {
                    for tiles in [None, Some((16, 16)), Some((32, 8))] {
                        let mut spec = Spec::new(w, h, sample, values.clone());
                        spec.compression = compression;
                        spec.predictor = predictor;
                        spec.tiles = tiles;
                        let file = spec.write("enc.tif");
                        let case = format!(
                            "{sample:?} compression {compression} predictor {predictor} tiles {tiles:?}"
                        );
                        let mut src =
                            GeoTiff::open(&file.0).unwrap_or_else(|e| panic!("{case}: {e:#}"));
                        assert_eq!(src.info().sample_type, sample, "{case}");
                        assert_eq!(src.info().georef, None, "{case}");
                        assert_eq!(src.info().nodata, None, "{case}");
                        for chunk in [3, 23] {
                            let got = read_all(&mut GeoTiff::open(&file.0).expect("open"), chunk);
                            assert!(got == want, "{case}, {chunk} rows at a time");
                        }
                        let got = read_all(&mut src, 1);
                        assert!(got == want, "{case}");
                        cases += 1;
                    }
                }
            }
        }
        assert_eq!(cases, 3 * 5 * 7);
    }

    #[test]
    fn descriptions_name_the_encoding() {
        let values = surface(20, 10, SampleType::Int16);
        let mut spec = Spec::new(20, 10, SampleType::Int16, values);
        spec.compression = 5;
        spec.predictor = 2;
        spec.tiles = Some((16, 16));
        let d = GeoTiff::open(&spec.write("d1.tif").0)
            .expect("open")
            .info()
            .description
            .clone();
        assert_eq!(d, "GeoTIFF int16, LZW + horizontal predictor, tiled 16×16");
        spec.tiles = None;
        spec.compression = 32946;
        spec.predictor = 1;
        spec.rows_per_strip = 100;
        let d = GeoTiff::open(&spec.write("d2.tif").0)
            .expect("open")
            .info()
            .description
            .clone();
        assert_eq!(d, "GeoTIFF int16, deflate, 10 rows in one strip");
    }

    #[test]
    fn georeferencing_follows_gdal() {
        let values = surface(10, 8, SampleType::Float32);
        let base = || Spec::new(10, 8, SampleType::Float32, values.clone());
        let open = |spec: Spec| {
            let file = spec.write("geo.tif");
            GeoTiff::open(&file.0).expect("open").info().clone()
        };

        // No georeferencing tags at all.
        assert_eq!(open(base()).georef, None);

        // Projected, PixelIsPoint: the corner is half a pixel north-west of the tiepoint.
        let info = open(
            base()
                .doubles(33550, &[10.0, 20.0, 0.0])
                .doubles(33922, &[0.0, 0.0, 0.0, 500_000.0, 4_000_000.0, 0.0])
                .shorts(
                    34735,
                    &[
                        1, 1, 0, 4, 1024, 0, 1, 1, 1025, 0, 1, 2, 1026, 34737, 22, 0, 3072, 0, 1,
                        32632,
                    ],
                )
                .ascii(34737, "WGS 84 / UTM zone 32N|")
                .ascii(42113, " -9999 "),
        );
        assert_eq!(info.nodata, Some(-9999.0));
        let g = info.georef.expect("georef");
        assert_eq!(g.epsg, Some(32632));
        assert_eq!(g.crs_name.as_deref(), Some("WGS 84 / UTM zone 32N"));
        assert_eq!(g.raster_type, RasterType::PixelIsPoint);
        assert_same(
            &g.geotransform,
            &[499_995.0, 10.0, 0.0, 4_000_010.0, 0.0, -20.0],
        );

        // A tiepoint at pixel (2, 3); geographic model, user-defined projected code ignored.
        let g = open(
            base()
                .doubles(33550, &[0.5, 0.25, 0.0])
                .doubles(33922, &[2.0, 3.0, 0.0, 10.0, 50.0, 0.0])
                .shorts(
                    34735,
                    &[
                        1, 1, 0, 3, 1024, 0, 1, 2, 2048, 0, 1, 4326, 3072, 0, 1, 32767,
                    ],
                ),
        )
        .georef
        .expect("georef");
        assert_eq!(g.epsg, Some(4326));
        assert_eq!(g.raster_type, RasterType::PixelIsArea);
        assert_same(&g.geotransform, &[9.0, 0.5, 0.0, 50.75, 0.0, -0.25]);
        assert_same(&g.extent(10, 8), &[9.0, 48.75, 14.0, 50.75]);

        // User-defined projected CRS: no EPSG code.
        let g = open(
            base()
                .doubles(33550, &[1.0, 1.0, 0.0])
                .doubles(33922, &[0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
                .shorts(34735, &[1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, 32767]),
        )
        .georef
        .expect("georef");
        assert_eq!(g.epsg, None);

        // A north-up ModelTransformationTag.
        let m = [
            2.0, 0.0, 0.0, 100.0, 0.0, -3.0, 0.0, 200.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        ];
        let g = open(base().doubles(34264, &m)).georef.expect("georef");
        assert_same(&g.geotransform, &[100.0, 2.0, 0.0, 200.0, 0.0, -3.0]);
        assert_eq!(g.epsg, None);

        // A rotated one is ignored (with a warning); the samples are still readable.
        let mut rotated = m;
        rotated[1] = 0.5;
        assert_eq!(open(base().doubles(34264, &rotated)).georef, None);
    }

    #[test]
    fn a_geotiff_is_a_sendable_row_source() {
        fn boxed<T: RowSource + fmt::Debug + 'static>() -> Option<Box<dyn RowSource>> {
            None::<Box<T>>.map(|b| b as Box<dyn RowSource>)
        }
        assert!(boxed::<GeoTiff>().is_none());
    }

    #[test]
    fn gdal_nodata_strings_parse_as_text() {
        assert_eq!(parse_nodata("-32767\0"), Some(-32767.0));
        assert_eq!(parse_nodata("32767"), Some(32767.0));
        assert_eq!(parse_nodata(" -9999 \0\0"), Some(-9999.0));
        assert_eq!(parse_nodata("-3.402823e+38"), Some(-3.402_823e38));
        assert_eq!(
            parse_nodata("-3.4028229999999999e+038"),
            Some(-3.402_823e38)
        );
        assert!(parse_nodata("nan").is_some_and(f64::is_nan));
        assert_eq!(parse_nodata(""), None);
        assert_eq!(parse_nodata("none"), None);
        // As the builder compares: the f32 of the nodata equals the f32 sample.
        assert_eq!(
            parse_nodata("-3.4028229999999999e+038").map(|v| v as f32),
            Some(-3.402_823e38_f32)
        );
    }

    #[test]
    fn unsupported_files_fail_in_open_with_a_clear_message() {
        let open_err = |spec: &Spec| {
            let file = spec.write("bad.tif");
            GeoTiff::open(&file.0)
                .expect_err("must be rejected")
                .to_string()
        };
        let int16 = || Spec::new(8, 4, SampleType::Int16, vec![1.0; 32]);

        let mut s = int16();
        s.compression = 34712;
        let e = open_err(&s);
        assert_eq!(
            e,
            "unsupported TIFF compression JPEG 2000 (34712); supported: none, deflate, LZW, PackBits"
        );

        let mut s = int16();
        s.bits = 8;
        s.format = 1;
        let e = open_err(&s);
        assert_eq!(
            e,
            "unsupported sample type uint8; supported: int16, uint16, float32"
        );

        let mut s = int16();
        s.bits = 64;
        s.format = 3;
        assert!(open_err(&s).contains("unsupported sample type float64"));

        let mut s = Spec::new(8, 4, SampleType::UInt16, vec![1.0; 96]);
        s.bands = 3;
        let e = open_err(&s);
        assert!(e.contains("3 bands") && e.contains("single-band"), "{e}");

        let mut s = int16();
        s.predictor = 3;
        assert!(open_err(&s).contains("floating-point predictor"));
    }

    /// Chunks whose stored bytes could not hold what the header says they decode to
    /// (here: uncompressed strips of 128 bytes said to be stored in 1 byte each) are
    /// refused in `open`, before any band is allocated for them.
    #[test]
    fn a_header_claiming_more_than_its_chunks_can_hold_is_implausible() {
        let mut s = Spec::new(64, 64, SampleType::UInt16, vec![7.0; 64 * 64]);
        s.rows_per_strip = 1;
        let honest = s.write("honest.tif");
        assert!(GeoTiff::open(&honest.0).is_ok());
        s.byte_counts = Some(1);
        let liar = s.write("liar.tif");
        let e = GeoTiff::open(&liar.0)
            .expect_err("must be rejected")
            .to_string();
        assert!(e.contains("implausible TIFF header"), "{e}");
        assert!(e.contains("64 strips"), "{e}");
    }

    #[test]
    fn decoding_errors_are_errors() {
        let (w, h) = (40, 30);
        let values = surface(w, h, SampleType::Int16);
        let mut spec = Spec::new(w, h, SampleType::Int16, values);
        spec.compression = 8;
        spec.tiles = Some((16, 16));
        let mut bytes = spec.encode();
        // Scramble the compressed data of the first tile (it starts at byte 8).
        for b in &mut bytes[10..40] {
            *b = 0xA5;
        }
        let file = TempFile::new("corrupt.tif", &bytes);
        let mut src = GeoTiff::open(&file.0).expect("the header is intact");
        let err = src
            .read_rows(&mut vec![0.0; w as usize])
            .expect_err("corrupt data");
        let msg = format!("{err:#}");
        assert!(msg.contains("tile 0") && msg.contains("deflate"), "{msg}");
        // The source stays failed.
        assert!(src.read_rows(&mut vec![0.0; w as usize]).is_err());

        // Past the end, and buffers that are not whole rows.
        spec.compression = 1;
        let file = spec.write("end.tif");
        let mut src = GeoTiff::open(&file.0).expect("open");
        assert!(src.read_rows(&mut vec![0.0; w as usize + 1]).is_err());
        assert!(
            src.read_rows(&mut vec![0.0; (w * (h + 1)) as usize])
                .is_err()
        );
        read_all(&mut src, 4);
        let err = src
            .read_rows(&mut vec![0.0; w as usize])
            .expect_err("past the end");
        assert!(err.to_string().contains("past the last row"), "{err}");
    }

    #[test]
    fn sparse_tiles_read_as_nodata() {
        let (w, h) = (20, 20);
        let values = surface(w, h, SampleType::Int16);
        let mut spec = Spec::new(w, h, SampleType::Int16, values.clone()).ascii(42113, "-32768");
        spec.tiles = Some((16, 16));
        let mut bytes = spec.encode();
        // Zero the byte count of tile 1 (the top-right one), as GDAL's SPARSE_OK writes it.
        let ifd = u32::from_le_bytes(bytes[4..8].try_into().expect("4")) as usize;
        let n = usize::from(u16::from_le_bytes([bytes[ifd], bytes[ifd + 1]]));
        let entry = (0..n)
            .map(|i| ifd + 2 + 12 * i)
            .find(|&at| u16::from_le_bytes([bytes[at], bytes[at + 1]]) == 325)
            .expect("TileByteCounts");
        let counts =
            u32::from_le_bytes(bytes[entry + 8..entry + 12].try_into().expect("4")) as usize;
        bytes[counts + 4..counts + 8].copy_from_slice(&0u32.to_le_bytes());
        let file = TempFile::new("sparse.tif", &bytes);
        let got = read_all(&mut GeoTiff::open(&file.0).expect("open"), 6);
        for (i, (&g, &v)) in got.iter().zip(&values).enumerate() {
            let (x, y) = (i as u32 % w, i as u32 / w);
            let want = if x >= 16 && y < 16 {
                -32768.0
            } else {
                v as f32
            };
            assert!(g.to_bits() == want.to_bits(), "({x}, {y}): {g} vs {want}");
        }
    }
}
