//! Imagery pyramids (DECISIONS.md "Imagery pyramids"): the texture hierarchy of
//! Yang §3, "grid LOD and texture LOD corresponding each other".
//!
//! An imagery pyramid is a sibling file of a DEM pyramid (`NAME.tessimg` beside
//! `NAME.tess`, DECISIONS "Imagery pyramids") in the same container (FORMAT.md
//! "Imagery pyramids"): the same header, level table and dense Morton indices, with
//! the magic `TESSIMG\0` and header flag [`crate::format::FILE_IMAGERY`], so that
//! every reader of DEM pyramids refuses it instead of misreading it. It has exactly
//! the DEM's levels, tiles and presence: the imagery of tile `(L, m)` is record `m`
//! of level `L`, one image of `texels × texels` RGB texels covering the same ground
//! as the DEM tile's `T × T` cells, so a client fetches, pools and draws a tile's
//! imagery with its geometry. Records are baseline JPEG.

use crate::metadata::{ContentHashError, Metadata};
use serde::{Deserialize, Serialize};

/// How imagery records are encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ImageEncoding {
    /// Baseline JPEG, 8-bit RGB (`image/jpeg`).
    Jpeg,
}

impl ImageEncoding {
    pub const fn media_type(self) -> &'static str {
        match self {
            Self::Jpeg => "image/jpeg",
        }
    }
}

/// The largest texel count per tile side a build writes (and a reader accepts):
/// 2048² RGBA is 16 MiB per GPU slot, already more than a client wants.
pub const MAX_TEXELS: u32 = 2048;
/// The smallest: below this a JPEG's 8×8 blocks are most of the tile.
pub const MIN_TEXELS: u32 = 16;

/// What an imagery pyramid's header holds in place of a DEM's [`Metadata`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageryMetadata {
    /// The DEM pyramid's metadata exactly as its file stores it, content hash
    /// included: it fixes the tile geometry and names the DEM this imagery drapes.
    pub dem: Metadata,
    /// Texels per tile side, the same at every level. Texel `(u, v)` of a tile is
    /// centred at tile sample coordinates `((u + ½)·T/texels, (v + ½)·T/texels)`
    /// (north row first), so UV `(i/T, j/T)` is sample `(i, j)`.
    pub texels: u32,
    pub encoding: ImageEncoding,
    /// The source bands (1-based) that became R, G and B.
    pub bands: [u16; 3],
    /// Per output channel, the source values mapped to 0 and 255 (linear between,
    /// clamped outside): the 2–98 percentile stretch, or `[0, 255]` for 8-bit data.
    pub stretch: [[f64; 2]; 3],
    /// Ground size of a finest-level texel in the DEM CRS's units, `[x, y]`.
    pub texel_size: [f64; 2],
    /// The source image: file name, size, bands, CRS.
    pub source: String,
    pub generator: String,
    /// XXH3-64 of this metadata with an empty hash and every record's checksum, as
    /// for DEM pyramids (FORMAT.md): the imagery's identity for ETags and caches.
    pub content_hash: String,
}

impl ImageryMetadata {
    /// Checks the numbers a reader relies on.
    pub fn check(&self) -> Result<(), ImageryMetadataError> {
        if !(MIN_TEXELS..=MAX_TEXELS).contains(&self.texels) {
            return Err(ImageryMetadataError::Texels {
                texels: self.texels,
            });
        }
        self.dem
            .check_content_hash()
            .map_err(ImageryMetadataError::DemContentHash)?;
        let own = Metadata {
            content_hash: self.content_hash.clone(),
            ..self.dem.clone()
        };
        Ok(own.check_content_hash()?)
    }
}

/// The imagery metadata of format version 2 files: the DEM's metadata in its version 2
/// shape, the rest as today.
pub(crate) mod v2 {
    use super::ImageEncoding;
    use serde::{Deserialize, Serialize};

    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    pub struct ImageryMetadata {
        pub dem: crate::metadata::v2::Metadata,
        pub texels: u32,
        pub encoding: ImageEncoding,
        pub bands: [u16; 3],
        pub stretch: [[f64; 2]; 3],
        pub texel_size: [f64; 2],
        pub source: String,
        pub generator: String,
        pub content_hash: String,
    }

    impl From<ImageryMetadata> for super::ImageryMetadata {
        fn from(m: ImageryMetadata) -> Self {
            Self {
                dem: m.dem.into(),
                texels: m.texels,
                encoding: m.encoding,
                bands: m.bands,
                stretch: m.stretch,
                texel_size: m.texel_size,
                source: m.source,
                generator: m.generator,
                content_hash: m.content_hash,
            }
        }
    }

    /// Back to the old shape, to hash a version 2 file's metadata as it was written.
    impl From<&super::ImageryMetadata> for ImageryMetadata {
        fn from(m: &super::ImageryMetadata) -> Self {
            Self {
                dem: (&m.dem).into(),
                texels: m.texels,
                encoding: m.encoding,
                bands: m.bands,
                stretch: m.stretch,
                texel_size: m.texel_size,
                source: m.source.clone(),
                generator: m.generator.clone(),
                content_hash: m.content_hash.clone(),
            }
        }
    }
}

/// Why an imagery pyramid's metadata is refused ([`ImageryMetadata::check`]).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ImageryMetadataError {
    #[error("imagery texels per tile {texels} outside {MIN_TEXELS}..={MAX_TEXELS}")]
    Texels { texels: u32 },
    /// The DEM's metadata inside carries a bad hash.
    #[error("the DEM's {0}")]
    DemContentHash(ContentHashError),
    /// The imagery's own hash is bad.
    #[error(transparent)]
    ContentHash(#[from] ContentHashError),
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta() -> ImageryMetadata {
        let mut dem = crate::fixtures::metadata(129, 129, 64);
        dem.content_hash = "0123456789abcdef".into();
        ImageryMetadata {
            dem,
            texels: 256,
            encoding: ImageEncoding::Jpeg,
            bands: [3, 2, 1],
            stretch: [[0.0, 255.0]; 3],
            texel_size: [22.5, 22.5],
            source: "L7_ETMs.tif".into(),
            generator: "test".into(),
            content_hash: "fedcba9876543210".into(),
        }
    }

    /// A version 2 imagery file's metadata (the DEM's in its version 2 shape) still
    /// decodes, and hashes in that shape: its content hash stays its identity.
    #[test]
    fn version_2_imagery_metadata_still_reads_and_hashes_as_written() {
        let m = meta();
        let old = v2::ImageryMetadata::from(&m);
        let bytes = bincode::serde::encode_to_vec(&old, bincode::config::standard()).unwrap();
        let read = crate::format::decode_imagery_metadata_of(&bytes, 2).unwrap();
        assert_eq!(read, m);
        // Read as version 3 the same bytes are cut short (no `sources`).
        assert!(crate::format::decode_imagery_metadata_of(&bytes, 3).is_err());
        let h2 = crate::format::ContentHasher::imagery_of_version(&m, 2).finish();
        let h3 = crate::format::ContentHasher::imagery_of_version(&m, 3).finish();
        let mut unhashed = old.clone();
        unhashed.content_hash.clear();
        let direct = xxhash_rust::xxh3::xxh3_64(
            &bincode::serde::encode_to_vec(&unhashed, bincode::config::standard()).unwrap(),
        );
        assert_eq!(h2, format!("{direct:016x}"));
        assert_ne!(h2, h3);
    }

    #[test]
    fn check_refuses_bad_texels_and_hashes() {
        assert!(meta().check().is_ok());
        let mut m = meta();
        m.texels = 4;
        assert!(m.check().unwrap_err().to_string().contains("texels"));
        let mut m = meta();
        m.dem.content_hash = "x\"".into();
        assert!(m.check().unwrap_err().to_string().contains("DEM"));
        let mut m = meta();
        m.content_hash.clear();
        assert!(m.check().is_err());
    }

    /// The magic follows the flag, and a header whose magic and flag disagree is
    /// refused: a DEM reader can never take an imagery file for a DEM.
    #[test]
    fn the_imagery_magic_and_flag_go_together() {
        use crate::format::{FILE_IMAGERY, FileHeader, IMAGERY_MAGIC, MAGIC};
        let h = FileHeader {
            version: crate::format::VERSION,
            flags: FILE_IMAGERY,
            meta_offset: 64,
            meta_len: 10,
            level_table_offset: 64,
            level_count: 1,
            index_entry_len: 32,
            records_offset: 4096,
            checksum: 7,
        };
        let mut b = h.to_bytes();
        assert_eq!(b[..8], IMAGERY_MAGIC);
        assert_eq!(FileHeader::parse(&b).unwrap(), h);
        b[..8].copy_from_slice(&MAGIC);
        assert!(
            FileHeader::parse(&b)
                .unwrap_err()
                .to_string()
                .contains("contradict")
        );
        let dem = FileHeader { flags: 0, ..h };
        let mut b = dem.to_bytes();
        assert_eq!(b[..8], MAGIC);
        b[..8].copy_from_slice(&IMAGERY_MAGIC);
        assert!(FileHeader::parse(&b).is_err());
    }

    #[test]
    fn metadata_round_trips_and_is_checked_on_decode() {
        let m = meta();
        let bytes = crate::format::encode_imagery_metadata(&m);
        assert_eq!(crate::format::decode_imagery_metadata(&bytes).unwrap(), m);
        let mut bad = meta();
        bad.texels = 1 << 20;
        let bytes = crate::format::encode_imagery_metadata(&bad);
        assert!(crate::format::decode_imagery_metadata(&bytes).is_err());
        // A DEM's metadata is not an imagery pyramid's.
        let dem = crate::format::encode_metadata(&m.dem);
        assert!(crate::format::decode_imagery_metadata(&dem).is_err());
    }

    #[test]
    fn info_links_the_imagery_stream() {
        let info = crate::api::ImageryInfo::new("olinda", &meta(), 99);
        assert_eq!(
            info.tiles,
            "/v1/datasets/olinda/imagery/levels/{level}/tiles?ranges={ranges}"
        );
        assert_eq!(info.media_type, "image/jpeg");
        assert_eq!((info.texels, info.bytes), (256, 99));
    }
}
