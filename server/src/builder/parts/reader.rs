//! Reading a part file: opened and checked (header, trailer, length), then its
//! records and roots read back with every checksum verified.

use super::layout::{Frame, Header, Section, Trailer, root_fixed_len};
use super::split::PartSpec;
use super::{FRAME_LEN, HEADER_LEN, MAX_TRAILER};
use crate::builder::mesh_error::BlockErrors;
use crate::builder::node::Node;
use crate::builder::writer::SINK_BUFFER;
use anyhow::{Context, bail, ensure};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use tessera_shared::format;
use tessera_shared::{CellMask, Level, Morton, TileGeometry};

/// A part file opened and checked (header, trailer, length) without reading its
/// records.
#[derive(Debug)]
pub struct PartFile {
    pub path: PathBuf,
    file: File,
    pub(super) header: Header,
    pub(super) trailer: Trailer,
}

impl PartFile {
    /// Opens a part file; errors say what is wrong (the caller names the file).
    pub fn open(path: &Path) -> anyhow::Result<Self> {
        let file = File::open(path)?;
        let len = file.metadata()?.len();
        ensure!(
            len >= HEADER_LEN as u64,
            "truncated: {len} bytes, shorter than a part header"
        );
        let mut hb = [0u8; HEADER_LEN];
        file.read_exact_at(&mut hb, 0)?;
        let header = Header::parse(&hb)?;
        ensure!(
            header.file_len == len,
            "{}: {len} bytes where its header says {}",
            if len < header.file_len {
                "truncated"
            } else {
                "wrong length"
            },
            header.file_len
        );
        ensure!(
            header.trailer_len <= MAX_TRAILER
                && header.trailer_offset >= HEADER_LEN as u64
                && header.trailer_offset.checked_add(header.trailer_len) == Some(len),
            "corrupt: its header places the trailer outside the file"
        );
        let mut tb = vec![0u8; header.trailer_len as usize];
        file.read_exact_at(&mut tb, header.trailer_offset)?;
        ensure!(
            header.compute_checksum(&tb) == header.checksum,
            "corrupt: the checksum of its header and trailer does not match"
        );
        let trailer = Trailer::parse(&tb, header.split)?;
        ensure!(
            header.n >= 1 && header.k < header.n,
            "corrupt: part {} of {}",
            header.k,
            header.n
        );
        ensure!(
            header.split <= header.finest
                && usize::from(header.finest - header.split) + 1 == trailer.sections.len()
                && trailer.meta.levels.checked_sub(1) == Some(header.finest),
            "corrupt: its levels do not fit together"
        );
        let mut end = HEADER_LEN as u64;
        let mut spans: Vec<Section> = trailer.sections.clone();
        spans.push(trailer.roots);
        spans.sort_by_key(|s| s.offset);
        for s in &spans {
            ensure!(
                s.offset >= end && s.offset.checked_add(s.len).is_some_and(|e| e <= len),
                "corrupt: its sections overlap or lie outside the file"
            );
            end = s.offset + s.len;
        }
        Ok(Self {
            path: path.to_path_buf(),
            file,
            header,
            trailer,
        })
    }

    /// Part `k` of `n`.
    pub fn spec(&self) -> PartSpec {
        PartSpec {
            k: self.header.k,
            n: self.header.n,
        }
    }

    pub(super) fn split(&self) -> Level {
        Level::new(self.header.split).expect("checked against the finest level")
    }

    /// The records of `level` (at least the split level), in Morton order.
    pub(super) fn records(&self, level: Level) -> anyhow::Result<Records> {
        let i = usize::from(level.get() - self.header.split);
        let s = self.trailer.sections[i];
        let mut reader = BufReader::with_capacity(SINK_BUFFER, self.file.try_clone()?);
        reader.seek(SeekFrom::Start(s.offset))?;
        let shift = 2 * u32::from(level.get() - self.header.split);
        Ok(Records {
            reader,
            level,
            remaining: s.len,
            left: s.count,
            next: self.trailer.tops.start << shift,
            end: self.trailer.tops.end << shift,
            buf: Vec::new(),
        })
    }

    /// The split level's nodes, one per code of the part's slice.
    pub(super) fn roots(&self, g: &TileGeometry) -> anyhow::Result<Roots> {
        let s = self.trailer.roots;
        let mut reader = BufReader::with_capacity(SINK_BUFFER, self.file.try_clone()?);
        reader.seek(SeekFrom::Start(s.offset))?;
        ensure!(
            s.count == self.trailer.tops.end - self.trailer.tops.start,
            "corrupt: {} split-level tiles for a slice of {}",
            s.count,
            self.trailer.tops.end - self.trailer.tops.start
        );
        Ok(Roots {
            reader,
            remaining: s.len,
            next: self.trailer.tops.start,
            end: self.trailer.tops.end,
            side: g.tile_samples(),
            spacings: self.trailer.spacings as usize,
        })
    }

    /// Reads every record and root, checking their checksums.
    pub fn check(&self, interrupt: &crate::builder::interrupt::Interrupt) -> anyhow::Result<()> {
        let g = TileGeometry::new(
            self.trailer.meta.width,
            self.trailer.meta.height,
            self.trailer.meta.tile_size,
        )?;
        for l in self.header.split..=self.header.finest {
            interrupt.check()?;
            let mut r = self.records(Level::new(l).expect("a level"))?;
            while r.next()?.is_some() {}
        }
        let mut roots = self.roots(&g)?;
        for _ in self.trailer.tops.clone() {
            roots.next()?;
        }
        roots.finish()
    }
}

/// A level's records in a part, checked as they are read.
pub(super) struct Records {
    reader: BufReader<File>,
    level: Level,
    remaining: u64,
    left: u64,
    /// The smallest code the next record may have, and the end of the slice.
    next: u64,
    end: u64,
    buf: Vec<u8>,
}

impl Records {
    pub(super) fn next(&mut self) -> anyhow::Result<Option<(Morton, &[u8], Frame)>> {
        let level = self.level;
        if self.left == 0 {
            ensure!(
                self.remaining == 0,
                "corrupt: level {level} has {} bytes after its last record",
                self.remaining
            );
            return Ok(None);
        }
        ensure!(
            self.remaining >= FRAME_LEN as u64,
            "corrupt: level {level} ends {} records early",
            self.left
        );
        let mut fb = [0u8; FRAME_LEN];
        self.reader
            .read_exact(&mut fb)
            .with_context(|| format!("reading level {level}"))?;
        let frame = Frame::parse(&fb);
        self.remaining -= FRAME_LEN as u64;
        ensure!(
            frame.m >= self.next && frame.m < self.end,
            "corrupt: level {level} holds a record for Morton code {} out of order or outside \
             the part's slice",
            frame.m
        );
        ensure!(
            frame.length > 0 && u64::from(frame.length) <= self.remaining,
            "corrupt: level {level} Morton code {}: record length {} does not fit",
            frame.m,
            frame.length
        );
        self.buf.resize(frame.length as usize, 0);
        self.reader
            .read_exact(&mut self.buf)
            .with_context(|| format!("reading level {level}"))?;
        ensure!(
            format::checksum(&self.buf) == frame.checksum,
            "corrupt: level {level} Morton code {}: the record's checksum does not match",
            frame.m
        );
        self.remaining -= u64::from(frame.length);
        self.left -= 1;
        self.next = frame.m + 1;
        Ok(Some((Morton::from_raw(frame.m), &self.buf, frame)))
    }
}

/// A part's split-level nodes, checked as they are read.
pub(super) struct Roots {
    reader: BufReader<File>,
    remaining: u64,
    next: u64,
    end: u64,
    side: usize,
    spacings: usize,
}

impl Roots {
    /// The next code's node (`None`: absent).
    pub(super) fn next(&mut self) -> anyhow::Result<Option<Node>> {
        let m = self.next;
        ensure!(m < self.end, "corrupt: more split-level tiles than codes");
        self.next += 1;
        let mut tag = [0u8; 1];
        self.take(&mut tag, m)?;
        match tag[0] {
            0 => return Ok(None),
            1 => {}
            t => bail!("corrupt: split-level tile {m} has tag {t}"),
        }
        let mut lb = [0u8; 8];
        self.take(&mut lb, m)?;
        let len = u64::from_le_bytes(lb);
        let fixed = root_fixed_len(self.side * self.side, self.spacings * 64);
        ensure!(
            len >= fixed as u64 && len.saturating_add(8) <= self.remaining,
            "corrupt: split-level tile {m} has a payload of {len} bytes"
        );
        let mut payload = vec![0u8; len as usize];
        self.take(&mut payload, m)?;
        self.take(&mut lb, m)?;
        ensure!(
            format::checksum(&payload) == u64::from_le_bytes(lb),
            "corrupt: split-level tile {m}: its checksum does not match"
        );
        let (heights, rest) = payload.split_at(2 * self.side * self.side);
        let (errors, rest) = rest.split_at(8 * self.spacings * 64);
        let (ranges, rest) = rest.split_at(256);
        let (mask_len, mask) = rest.split_at(4);
        ensure!(
            u32::from_le_bytes(mask_len.try_into()?) as usize == mask.len(),
            "corrupt: split-level tile {m}: its mask length does not match"
        );
        let u16s = |b: &[u8]| -> Vec<u16> {
            b.chunks_exact(2)
                .map(|c| u16::from_le_bytes([c[0], c[1]]))
                .collect()
        };
        let ranges = u16s(ranges);
        let mut min = [0u16; 64];
        let mut max = [0u16; 64];
        min.copy_from_slice(&ranges[..64]);
        max.copy_from_slice(&ranges[64..]);
        let mask = CellMask::decode(mask, self.side as u32 - 1)
            .map_err(|e| anyhow::anyhow!("corrupt: split-level tile {m}: {e}"))?;
        Ok(Some(Node {
            heights: u16s(heights),
            errors: BlockErrors {
                values: errors
                    .chunks_exact(8)
                    .map(|c| f64::from_bits(u64::from_le_bytes(c.try_into().expect("8 bytes"))))
                    .collect(),
            },
            min,
            max,
            mask,
        }))
    }

    /// Checks that every code's node was read and nothing follows.
    pub(super) fn finish(&self) -> anyhow::Result<()> {
        ensure!(
            self.next == self.end && self.remaining == 0,
            "corrupt: {} bytes after the last split-level tile",
            self.remaining
        );
        Ok(())
    }

    fn take(&mut self, buf: &mut [u8], m: u64) -> anyhow::Result<()> {
        ensure!(
            buf.len() as u64 <= self.remaining,
            "corrupt: split-level tile {m} runs past its section"
        );
        self.reader
            .read_exact(buf)
            .with_context(|| format!("reading split-level tile {m}"))?;
        self.remaining -= buf.len() as u64;
        Ok(())
    }
}
