//! The pyramid file format, version 3 (see `FORMAT.md` for the byte-level description;
//! version 1 and 2 files still read: their metadata has its own shape, and version 1
//! records no mask).
//!
//! ```text
//! header (64 B) · metadata (bincode 2) · level table (40 B per level)
//!   · per level a dense index in Morton order (32 B per Morton code)
//!   · tile records, level by level (finest first), each level contiguous in Morton order
//! ```
//! Because every level's records are contiguous and in Morton order, a Morton range
//! of one level is one byte range of the file (docs/ARCHITECTURE.md#the-file).

use crate::imagery::{ImageryMetadata, ImageryMetadataError};
use crate::metadata::Metadata;
use xxhash_rust::xxh3::Xxh3;

pub const MAGIC: [u8; 8] = *b"TESSPYR\0";
/// The magic of an imagery pyramid ([`crate::imagery`]): the same container, so that a
/// DEM reader refuses it by its first bytes.
pub const IMAGERY_MAGIC: [u8; 8] = *b"TESSIMG\0";
/// Header flag: the file is an imagery pyramid (its magic is [`IMAGERY_MAGIC`], its
/// metadata an [`ImageryMetadata`], its records images). Set exactly when the magic
/// says so; [`FileHeader::to_bytes`] writes the magic from it. Bit 16, not 0: the low
/// bits stay reserved (and refused by `verify`) in DEM pyramids.
pub const FILE_IMAGERY: u32 = 1 << 16;
/// The version this build writes (3: the metadata lists the sources).
pub const VERSION: u32 = 3;
/// The oldest version this build reads.
pub const OLDEST_READABLE: u32 = 1;

/// Index entry flag: the record's mask marks some cells as not terrain.
pub const FLAG_PARTIAL: u32 = 1;
pub const HEADER_LEN: usize = 64;
pub const LEVEL_ENTRY_LEN: usize = 40;
pub const INDEX_ENTRY_LEN: usize = 32;

/// Checksum of a tile record (and of the header region): XXH3-64.
pub fn checksum(bytes: &[u8]) -> u64 {
    xxhash_rust::xxh3::xxh3_64(bytes)
}

/// Metadata is a few KiB; the limit stops a lying length prefix from allocating more than
/// this while decoding (nothing allocated on a header's word alone:
/// docs/ARCHITECTURE.md#bad-input-is-an-error).
const METADATA_LIMIT: usize = 1 << 20;

fn bincode_config() -> impl bincode::config::Config {
    bincode::config::standard()
        .with_little_endian()
        .with_variable_int_encoding()
        .with_limit::<METADATA_LIMIT>()
}

/// Metadata as stored in the header.
pub fn encode_metadata(meta: &Metadata) -> Vec<u8> {
    bincode::serde::encode_to_vec(meta, bincode_config())
        .expect("metadata always serializes: it has no maps or unsized types")
}

/// Why a metadata record does not decode.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum MetadataError {
    #[error("metadata is truncated ({additional} more bytes expected)")]
    Truncated { additional: usize },
    #[error("metadata claims more than {METADATA_LIMIT} bytes")]
    TooLong,
    #[error("a metadata text field is not valid UTF-8")]
    Utf8,
    #[error("the metadata bytes are not a valid metadata record")]
    Invalid,
    #[error("metadata has {count} trailing bytes")]
    TrailingBytes { count: usize },
    /// An imagery pyramid's metadata decoded, but its numbers are refused.
    #[error(transparent)]
    Imagery(#[from] ImageryMetadataError),
}

/// Metadata as the current version writes it.
pub fn decode_metadata(bytes: &[u8]) -> Result<Metadata, MetadataError> {
    decode_metadata_of(bytes, VERSION)
}

/// Metadata of a `version` file (versions 1 and 2 have fewer fields).
pub fn decode_metadata_of(bytes: &[u8], version: u32) -> Result<Metadata, MetadataError> {
    match version {
        1 => decode_exact::<crate::metadata::v1::Metadata>(bytes).map(Metadata::from),
        2 => decode_exact::<crate::metadata::v2::Metadata>(bytes).map(Metadata::from),
        _ => decode_exact(bytes),
    }
}

/// An imagery pyramid's metadata as stored in its header.
pub fn encode_imagery_metadata(meta: &ImageryMetadata) -> Vec<u8> {
    bincode::serde::encode_to_vec(meta, bincode_config())
        .expect("metadata always serializes: it has no maps or unsized types")
}

/// An imagery pyramid's metadata, checked ([`ImageryMetadata::check`]).
pub fn decode_imagery_metadata(bytes: &[u8]) -> Result<ImageryMetadata, MetadataError> {
    decode_imagery_metadata_of(bytes, VERSION)
}

/// [`decode_imagery_metadata`] of a `version` file (version 2 embeds the DEM's
/// metadata in its version 2 shape).
pub fn decode_imagery_metadata_of(
    bytes: &[u8],
    version: u32,
) -> Result<ImageryMetadata, MetadataError> {
    let meta: ImageryMetadata = if version <= 2 {
        decode_exact::<crate::imagery::v2::ImageryMetadata>(bytes)?.into()
    } else {
        decode_exact(bytes)?
    };
    meta.check()?;
    Ok(meta)
}

fn decode_exact<T: serde::de::DeserializeOwned>(bytes: &[u8]) -> Result<T, MetadataError> {
    use bincode::error::DecodeError;
    let (meta, used): (T, usize) = bincode::serde::decode_from_slice(bytes, bincode_config())
        .map_err(|e| match e {
            DecodeError::UnexpectedEnd { additional } => MetadataError::Truncated { additional },
            DecodeError::LimitExceeded => MetadataError::TooLong,
            DecodeError::Utf8 { .. } => MetadataError::Utf8,
            _ => MetadataError::Invalid,
        })?;
    if used != bytes.len() {
        return Err(MetadataError::TrailingBytes {
            count: bytes.len() - used,
        });
    }
    Ok(meta)
}

/// The dataset's content hash: metadata (with an empty hash) and every record checksum
/// in file order.
pub fn content_hash<'a>(
    meta: &Metadata,
    version: u32,
    record_checksums: impl Iterator<Item = &'a u64>,
) -> String {
    let mut h = ContentHasher::of_version(meta, version);
    for c in record_checksums {
        h.record(*c);
    }
    h.finish()
}

/// [`content_hash`] fed one record checksum at a time (levels ascending, Morton order),
/// for writers and checkers that never hold the whole index.
#[derive(Clone)]
pub struct ContentHasher(Xxh3);

impl std::fmt::Debug for ContentHasher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ContentHasher").finish_non_exhaustive()
    }
}

impl ContentHasher {
    /// For a file of the current version.
    pub fn new(meta: &Metadata) -> Self {
        Self::of_version(meta, VERSION)
    }

    /// For a `version` file: the metadata is hashed in the shape that version
    /// stores, so old files keep their identity.
    pub fn of_version(meta: &Metadata, version: u32) -> Self {
        let mut unhashed = meta.clone();
        unhashed.content_hash.clear();
        let bytes = match version {
            1 => bincode::serde::encode_to_vec(
                crate::metadata::v1::Metadata::from(&unhashed),
                bincode_config(),
            ),
            2 => bincode::serde::encode_to_vec(
                crate::metadata::v2::Metadata::from(&unhashed),
                bincode_config(),
            ),
            _ => Ok(encode_metadata(&unhashed)),
        }
        .expect("metadata always serializes");
        let mut h = Xxh3::new();
        h.update(&bytes);
        Self(h)
    }

    /// For an imagery pyramid: its metadata with an empty hash, then its records'
    /// checksums, exactly as for a DEM pyramid.
    pub fn imagery(meta: &ImageryMetadata) -> Self {
        Self::imagery_of_version(meta, VERSION)
    }

    /// [`ContentHasher::imagery`] for a `version` file: the metadata in the shape that
    /// version stores.
    pub fn imagery_of_version(meta: &ImageryMetadata, version: u32) -> Self {
        let mut unhashed = meta.clone();
        unhashed.content_hash.clear();
        let bytes = if version <= 2 {
            bincode::serde::encode_to_vec(
                crate::imagery::v2::ImageryMetadata::from(&unhashed),
                bincode_config(),
            )
            .expect("metadata always serializes")
        } else {
            encode_imagery_metadata(&unhashed)
        };
        let mut h = Xxh3::new();
        h.update(&bytes);
        Self(h)
    }

    pub fn record(&mut self, checksum: u64) {
        self.0.update(&checksum.to_le_bytes());
    }

    pub fn finish(&self) -> String {
        format!("{:016x}", self.0.digest())
    }
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}

/// The fixed 64-byte header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FileHeader {
    pub version: u32,
    pub flags: u32,
    pub meta_offset: u64,
    pub meta_len: u64,
    pub level_table_offset: u64,
    pub level_count: u32,
    pub index_entry_len: u32,
    pub records_offset: u64,
    /// XXH3-64 of header bytes `0..56` followed by the file from `meta_offset` to `records_offset`.
    pub checksum: u64,
}

impl FileHeader {
    pub fn to_bytes(&self) -> [u8; HEADER_LEN] {
        let mut b = [0u8; HEADER_LEN];
        let magic = if self.flags & FILE_IMAGERY == 0 {
            &MAGIC
        } else {
            &IMAGERY_MAGIC
        };
        b[0..8].copy_from_slice(magic);
        b[8..12].copy_from_slice(&self.version.to_le_bytes());
        b[12..16].copy_from_slice(&self.flags.to_le_bytes());
        b[16..24].copy_from_slice(&self.meta_offset.to_le_bytes());
        b[24..32].copy_from_slice(&self.meta_len.to_le_bytes());
        b[32..40].copy_from_slice(&self.level_table_offset.to_le_bytes());
        b[40..44].copy_from_slice(&self.level_count.to_le_bytes());
        b[44..48].copy_from_slice(&self.index_entry_len.to_le_bytes());
        b[48..56].copy_from_slice(&self.records_offset.to_le_bytes());
        b[56..64].copy_from_slice(&self.checksum.to_le_bytes());
        b
    }

    /// Parses the fixed header; checks magic and version (not yet the checksum).
    pub fn parse(b: &[u8]) -> Result<Self, HeaderError> {
        if b.len() < HEADER_LEN {
            return Err(HeaderError::Short { len: b.len() });
        }
        let imagery = match &b[0..8] {
            m if *m == MAGIC => false,
            m if *m == IMAGERY_MAGIC => true,
            _ => return Err(HeaderError::BadMagic),
        };
        // The magic and the flag say the same thing: a file that disagrees is damaged.
        if imagery != (u32_at(b, 12) & FILE_IMAGERY != 0) {
            return Err(HeaderError::FlagsContradictMagic);
        }
        let version = u32_at(b, 8);
        if !(OLDEST_READABLE..=VERSION).contains(&version) {
            return Err(HeaderError::UnsupportedVersion { version });
        }
        Ok(Self {
            version,
            flags: u32_at(b, 12),
            meta_offset: u64_at(b, 16),
            meta_len: u64_at(b, 24),
            level_table_offset: u64_at(b, 32),
            level_count: u32_at(b, 40),
            index_entry_len: u32_at(b, 44),
            records_offset: u64_at(b, 48),
            checksum: u64_at(b, 56),
        })
    }

    /// The checksum over this header (bytes 0..56) and the region after it.
    pub fn compute_checksum(&self, region: &[u8]) -> u64 {
        let mut h = Xxh3::new();
        h.update(&self.to_bytes()[..56]);
        h.update(region);
        h.digest()
    }
}

/// Why a file's fixed header is refused.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum HeaderError {
    #[error("file is {len} bytes, shorter than the {HEADER_LEN}-byte header")]
    Short { len: usize },
    #[error("not a Tessera pyramid (bad magic)")]
    BadMagic,
    #[error("header flags contradict the magic (damaged header)")]
    FlagsContradictMagic,
    #[error(
        "format version {version} is not supported (this build reads versions {OLDEST_READABLE} to {VERSION})"
    )]
    UnsupportedVersion { version: u32 },
}

/// Where one level's index and records are.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelEntry {
    pub level: u8,
    pub tiles_per_side: u32,
    pub index_offset: u64,
    pub index_entries: u64,
    pub records_offset: u64,
    pub records_len: u64,
}

impl LevelEntry {
    pub fn to_bytes(&self) -> [u8; LEVEL_ENTRY_LEN] {
        let mut b = [0u8; LEVEL_ENTRY_LEN];
        b[0] = self.level;
        b[4..8].copy_from_slice(&self.tiles_per_side.to_le_bytes());
        b[8..16].copy_from_slice(&self.index_offset.to_le_bytes());
        b[16..24].copy_from_slice(&self.index_entries.to_le_bytes());
        b[24..32].copy_from_slice(&self.records_offset.to_le_bytes());
        b[32..40].copy_from_slice(&self.records_len.to_le_bytes());
        b
    }

    pub fn parse(b: &[u8]) -> Self {
        Self {
            level: b[0],
            tiles_per_side: u32_at(b, 4),
            index_offset: u64_at(b, 8),
            index_entries: u64_at(b, 16),
            records_offset: u64_at(b, 24),
            records_len: u64_at(b, 32),
        }
    }
}

/// One index slot: where a tile's record is, its checksum and its summary.
/// `length == 0` means the tile is absent (wholly outside the DEM).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct IndexEntry {
    /// Absolute file offset of the record.
    pub offset: u64,
    pub length: u32,
    /// Quantized min/max height of the tile's samples.
    pub min: u16,
    pub max: u16,
    /// XXH3-64 of the record bytes.
    pub checksum: u64,
    /// Largest error of the tile drawn at its own full resolution, in metres.
    pub full_res_error: f32,
    pub flags: u32,
}

impl IndexEntry {
    pub const fn is_present(&self) -> bool {
        self.length > 0
    }

    pub const fn end(&self) -> u64 {
        self.offset + self.length as u64
    }

    pub fn to_bytes(&self) -> [u8; INDEX_ENTRY_LEN] {
        let mut b = [0u8; INDEX_ENTRY_LEN];
        b[0..8].copy_from_slice(&self.offset.to_le_bytes());
        b[8..12].copy_from_slice(&self.length.to_le_bytes());
        b[12..14].copy_from_slice(&self.min.to_le_bytes());
        b[14..16].copy_from_slice(&self.max.to_le_bytes());
        b[16..24].copy_from_slice(&self.checksum.to_le_bytes());
        b[24..28].copy_from_slice(&self.full_res_error.to_le_bytes());
        b[28..32].copy_from_slice(&self.flags.to_le_bytes());
        b
    }

    pub fn parse(b: &[u8]) -> Self {
        Self {
            offset: u64_at(b, 0),
            length: u32_at(b, 8),
            min: u16::from_le_bytes([b[12], b[13]]),
            max: u16::from_le_bytes([b[14], b[15]]),
            checksum: u64_at(b, 16),
            full_res_error: f32::from_le_bytes([b[24], b[25], b[26], b[27]]),
            flags: u32_at(b, 28),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_records_round_trip() {
        let h = FileHeader {
            version: VERSION,
            flags: 0,
            meta_offset: 64,
            meta_len: 300,
            level_table_offset: 364,
            level_count: 3,
            index_entry_len: INDEX_ENTRY_LEN as u32,
            records_offset: 9999,
            checksum: 0xdead_beef,
        };
        assert_eq!(FileHeader::parse(&h.to_bytes()).unwrap(), h);
        let l = LevelEntry {
            level: 2,
            tiles_per_side: 4,
            index_offset: 1,
            index_entries: 16,
            records_offset: 77,
            records_len: 12345,
        };
        assert_eq!(LevelEntry::parse(&l.to_bytes()), l);
        let e = IndexEntry {
            offset: 5,
            length: 6,
            min: 7,
            max: 8,
            checksum: 9,
            full_res_error: 1.5,
            flags: 0,
        };
        assert_eq!(IndexEntry::parse(&e.to_bytes()), e);
    }

    /// A cut-short metadata record says so in words: no decoder debug text
    /// (`UnexpectedEnd { additional: 3 }`) reaches users.
    #[test]
    fn damaged_metadata_says_what_is_wrong_in_words() {
        let meta = crate::fixtures::metadata(600, 600, 64);
        let bytes = encode_metadata(&meta);
        let err = decode_metadata(&bytes[..bytes.len() - 3])
            .unwrap_err()
            .to_string();
        assert!(err.starts_with("metadata is truncated"), "{err}");
        assert!(
            !err.contains('{') && !err.contains("UnexpectedEnd"),
            "{err}"
        );
        let mut long = bytes.clone();
        long.push(0);
        assert!(
            decode_metadata(&long)
                .unwrap_err()
                .to_string()
                .contains("1 trailing bytes")
        );
    }

    #[test]
    fn bad_headers_say_why() {
        assert!(
            FileHeader::parse(b"short")
                .unwrap_err()
                .to_string()
                .contains("shorter")
        );
        let mut b = [0u8; 64];
        assert!(
            FileHeader::parse(&b)
                .unwrap_err()
                .to_string()
                .contains("bad magic")
        );
        b[0..8].copy_from_slice(&MAGIC);
        b[8] = 9;
        assert!(
            FileHeader::parse(&b)
                .unwrap_err()
                .to_string()
                .contains("version 9")
        );
    }
}
