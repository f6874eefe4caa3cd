//! A part file's layout (FORMAT.md "Part files"): its fixed header, the trailer
//! (fingerprint, counts, sections, metadata) and the frame before each record.

use super::{FRAME_LEN, HEADER_LEN, MAGIC, VERSION};
use crate::ingest::raster::DepthCounts;
use anyhow::ensure;
use std::ops::Range;
use tessera_shared::Metadata;
use tessera_shared::format::{self, IndexEntry};
use xxhash_rust::xxh3::Xxh3;

/// Where one run of bytes lies in a part file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct Section {
    pub(super) offset: u64,
    pub(super) len: u64,
    /// Records (a level's section) or roots (the roots' section).
    pub(super) count: u64,
}

/// A part file's fixed header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Header {
    pub(super) n: u32,
    pub(super) k: u32,
    pub(super) split: u8,
    pub(super) finest: u8,
    pub(super) trailer_offset: u64,
    pub(super) trailer_len: u64,
    pub(super) file_len: u64,
    pub(super) checksum: u64,
}

impl Header {
    pub(super) fn to_bytes(self) -> [u8; HEADER_LEN] {
        let mut b = [0u8; HEADER_LEN];
        b[0..8].copy_from_slice(&MAGIC);
        b[8..12].copy_from_slice(&VERSION.to_le_bytes());
        b[16..20].copy_from_slice(&self.n.to_le_bytes());
        b[20..24].copy_from_slice(&self.k.to_le_bytes());
        b[24] = self.split;
        b[25] = self.finest;
        b[32..40].copy_from_slice(&self.trailer_offset.to_le_bytes());
        b[40..48].copy_from_slice(&self.trailer_len.to_le_bytes());
        b[48..56].copy_from_slice(&self.file_len.to_le_bytes());
        b[56..64].copy_from_slice(&self.checksum.to_le_bytes());
        b
    }

    pub(super) fn parse(b: &[u8; HEADER_LEN]) -> anyhow::Result<Self> {
        ensure!(
            b[0..8] == MAGIC,
            "not a Tessera part file (its first bytes are not {:?})",
            String::from_utf8_lossy(&MAGIC)
        );
        let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().expect("4 bytes"));
        let u64_at = |o: usize| u64::from_le_bytes(b[o..o + 8].try_into().expect("8 bytes"));
        let version = u32_at(8);
        ensure!(
            version == VERSION,
            "part file version {version}; this tessera-server reads version {VERSION}"
        );
        Ok(Self {
            n: u32_at(16),
            k: u32_at(20),
            split: b[24],
            finest: b[25],
            trailer_offset: u64_at(32),
            trailer_len: u64_at(40),
            file_len: u64_at(48),
            checksum: u64_at(56),
        })
    }

    /// XXH3-64 of header bytes 0..56 followed by the trailer.
    pub(super) fn compute_checksum(&self, trailer: &[u8]) -> u64 {
        let mut h = Xxh3::new();
        h.update(&self.to_bytes()[..56]);
        h.update(trailer);
        h.digest()
    }
}

/// A part file's trailer: what assembling needs besides the records and roots.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Trailer {
    pub(super) fingerprint: [u8; 16],
    pub(super) tops: Range<u64>,
    pub(super) meta_reserve: u64,
    pub(super) spacings: u32,
    /// Range of the part's finest records' quantized heights (`u16::MAX, 0`: none).
    pub(super) min_q: u16,
    pub(super) max_q: u16,
    /// The part's share of the no-data samples (the sum of `depths`' filled counts).
    pub(super) nodata: u64,
    pub(super) depths: DepthCounts,
    /// One per level from the split level to the finest.
    pub(super) sections: Vec<Section>,
    pub(super) roots: Section,
    /// The pyramid's metadata but for its counts and content hash.
    pub(super) meta: Metadata,
}

impl Trailer {
    pub(super) fn to_bytes(&self, split: u8) -> Vec<u8> {
        let mut b = Vec::new();
        b.extend_from_slice(&self.fingerprint);
        b.extend_from_slice(&self.tops.start.to_le_bytes());
        b.extend_from_slice(&self.tops.end.to_le_bytes());
        b.extend_from_slice(&self.meta_reserve.to_le_bytes());
        b.extend_from_slice(&self.spacings.to_le_bytes());
        b.extend_from_slice(&self.min_q.to_le_bytes());
        b.extend_from_slice(&self.max_q.to_le_bytes());
        b.extend_from_slice(&self.nodata.to_le_bytes());
        for [v, f] in self.depths {
            b.extend_from_slice(&v.to_le_bytes());
            b.extend_from_slice(&f.to_le_bytes());
        }
        b.push(self.sections.len() as u8);
        for (i, s) in self.sections.iter().enumerate() {
            b.push(split + i as u8);
            for v in [s.offset, s.len, s.count] {
                b.extend_from_slice(&v.to_le_bytes());
            }
        }
        for v in [self.roots.offset, self.roots.len, self.roots.count] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        let meta = format::encode_metadata(&self.meta);
        b.extend_from_slice(&(meta.len() as u32).to_le_bytes());
        b.extend_from_slice(&meta);
        b
    }

    pub(super) fn parse(bytes: &[u8], split: u8) -> anyhow::Result<Self> {
        let mut r = Bytes(bytes);
        let fingerprint = r.take(16)?.try_into().expect("16 bytes");
        let tops = r.u64()?..r.u64()?;
        let meta_reserve = r.u64()?;
        let spacings = r.u32()?;
        let (min_q, max_q) = (r.u16()?, r.u16()?);
        let nodata = r.u64()?;
        let mut depths = [[0u64; 2]; 33];
        for d in &mut depths {
            *d = [r.u64()?, r.u64()?];
        }
        let count = r.take(1)?[0];
        let mut sections = Vec::new();
        for i in 0..count {
            let level = r.take(1)?[0];
            ensure!(
                level == split.wrapping_add(i),
                "its trailer lists level {level} where level {} belongs",
                split.wrapping_add(i)
            );
            sections.push(Section {
                offset: r.u64()?,
                len: r.u64()?,
                count: r.u64()?,
            });
        }
        let roots = Section {
            offset: r.u64()?,
            len: r.u64()?,
            count: r.u64()?,
        };
        let meta_len = r.u32()? as usize;
        let meta = format::decode_metadata(r.take(meta_len)?)
            .map_err(|e| anyhow::anyhow!("its metadata does not decode: {e}"))?;
        ensure!(r.0.is_empty(), "its trailer has {} extra bytes", r.0.len());
        Ok(Self {
            fingerprint,
            tops,
            meta_reserve,
            spacings,
            min_q,
            max_q,
            nodata,
            depths,
            sections,
            roots,
            meta,
        })
    }
}

/// A bounds-checked little-endian reader.
struct Bytes<'a>(&'a [u8]);

impl<'a> Bytes<'a> {
    fn take(&mut self, n: usize) -> anyhow::Result<&'a [u8]> {
        ensure!(self.0.len() >= n, "its trailer ends early");
        let (a, b) = self.0.split_at(n);
        self.0 = b;
        Ok(a)
    }
    fn u16(&mut self) -> anyhow::Result<u16> {
        Ok(u16::from_le_bytes(self.take(2)?.try_into()?))
    }
    fn u32(&mut self) -> anyhow::Result<u32> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into()?))
    }
    fn u64(&mut self) -> anyhow::Result<u64> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into()?))
    }
}

/// The frame before each record: its Morton code, length and index summary.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Frame {
    pub(super) m: u64,
    pub(super) length: u32,
    pub(super) min: u16,
    pub(super) max: u16,
    pub(super) checksum: u64,
    pub(super) full_res_error: f32,
    pub(super) flags: u32,
}

impl Frame {
    /// The pyramid index entry's layout (FORMAT.md), with the Morton code in the
    /// offset's place: one encoding for both.
    fn as_entry(self) -> IndexEntry {
        IndexEntry {
            offset: self.m,
            length: self.length,
            min: self.min,
            max: self.max,
            checksum: self.checksum,
            full_res_error: self.full_res_error,
            flags: self.flags,
        }
    }

    pub(super) fn to_bytes(self) -> [u8; FRAME_LEN] {
        self.as_entry().to_bytes()
    }

    pub(super) fn parse(b: &[u8; FRAME_LEN]) -> Self {
        let e = IndexEntry::parse(b);
        Self {
            m: e.offset,
            length: e.length,
            min: e.min,
            max: e.max,
            checksum: e.checksum,
            full_res_error: e.full_res_error,
            flags: e.flags,
        }
    }

    /// The index summary a pyramid writer takes (it fills in offset, length and
    /// checksum itself).
    pub(super) fn summary(&self) -> IndexEntry {
        IndexEntry {
            min: self.min,
            max: self.max,
            full_res_error: self.full_res_error,
            flags: self.flags,
            ..IndexEntry::default()
        }
    }
}
/// A root payload's length but for its mask bytes: heights, errors, min/max and
/// the mask's length.
pub(super) fn root_fixed_len(heights: usize, errors: usize) -> usize {
    2 * heights + 8 * errors + 2 * 2 * 64 + 4
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn headers_trailers_and_frames_read_back() {
        let meta = tessera_shared::fixtures::metadata(1025, 1025, 64);
        let t = Trailer {
            fingerprint: [7; 16],
            tops: 4..9,
            meta_reserve: 4242,
            spacings: 11,
            min_q: 3,
            max_q: 60000,
            nodata: 5,
            depths: {
                let mut d = [[1u64, 0]; 33];
                d[0][1] = 5;
                d
            },
            sections: vec![
                Section {
                    offset: 64,
                    len: 10,
                    count: 1,
                },
                Section {
                    offset: 74,
                    len: 20,
                    count: 2,
                },
            ],
            roots: Section {
                offset: 94,
                len: 5,
                count: 5,
            },
            meta,
        };
        let bytes = t.to_bytes(3);
        assert_eq!(Trailer::parse(&bytes, 3).unwrap(), t);
        assert!(Trailer::parse(&bytes[..bytes.len() - 1], 3).is_err());
        assert!(Trailer::parse(&bytes, 2).is_err(), "levels are checked");
        let h = Header {
            n: 16,
            k: 3,
            split: 3,
            finest: 4,
            trailer_offset: 99,
            trailer_len: bytes.len() as u64,
            file_len: 99 + bytes.len() as u64,
            checksum: 12345,
        };
        assert_eq!(Header::parse(&h.to_bytes()).unwrap(), h);
        let mut bad = h.to_bytes();
        bad[0] = b'X';
        assert!(Header::parse(&bad).is_err());
        let f = Frame {
            m: 77,
            length: 1000,
            min: 1,
            max: 2,
            checksum: 99,
            full_res_error: 0.5,
            flags: 1,
        };
        assert_eq!(Frame::parse(&f.to_bytes()), f);
    }
}
