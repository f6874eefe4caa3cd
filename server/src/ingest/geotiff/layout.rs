//! How a TIFF's samples are stored: the compressions the reader accepts and the
//! chunk layout (strips or tiles) it decodes one band at a time.

use anyhow::bail;

/// A TIFF compression the reader accepts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Compression {
    None,
    Lzw,
    Deflate,
    PackBits,
}

impl Compression {
    pub(super) fn from_code(code: u16) -> anyhow::Result<Self> {
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

    pub(super) const fn name(self) -> &'static str {
        match self {
            Self::None => "uncompressed",
            Self::Lzw => "LZW",
            Self::Deflate => "deflate",
            Self::PackBits => "PackBits",
        }
    }

    /// The best ratio of decoded to stored bytes the compression can reach, so a
    /// header's claimed size can be checked against the bytes the file really holds.
    pub(super) const fn max_ratio(self) -> u64 {
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
pub(super) enum Layout {
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
    pub(super) const fn band_height(self) -> u32 {
        match self {
            Self::Strips { rows_per_strip } => rows_per_strip,
            Self::Tiles { tile_height, .. } => tile_height,
        }
    }

    pub(super) const fn chunk_kind(self) -> &'static str {
        match self {
            Self::Strips { .. } => "strip",
            Self::Tiles { .. } => "tile",
        }
    }
}
