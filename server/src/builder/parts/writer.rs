//! Writing a part file: records streamed per level, the split level's roots, then
//! trailer and header, published under its name only when complete and re-read.

use super::layout::{Frame, Header, Section, Trailer, root_fixed_len};
use super::reader::PartFile;
use super::split::PartSpec;
use super::{FRAME_LEN, HEADER_LEN, ROOTS_BUFFER};
use crate::builder::node::Node;
use crate::builder::sink::Sink;
use crate::builder::writer::{SINK_BUFFER, partial_prefix, publish, remove_stale_partials};
use anyhow::{Context, ensure};
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::ops::Range;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use tempfile::NamedTempFile;
use tessera_shared::format::{self, IndexEntry};
use tessera_shared::{Level, Morton, TileGeometry};
use xxhash_rust::xxh3::Xxh3;

/// One level's records as they are made.
struct Stream {
    out: BufWriter<File>,
    len: u64,
    records: u64,
}

/// A part being written: records stream to one file per level (the finest straight
/// into the part file, the others into unnamed spill files appended at the end), the
/// split level's nodes to a spill file of their own; then the trailer and header.
/// Nothing grows with the number of tiles.
pub(super) struct PartWriter {
    target: PathBuf,
    partial: NamedTempFile,
    spec: PartSpec,
    split: Level,
    finest: Level,
    tops: Range<u64>,
    next_top: u64,
    /// Split level first.
    levels: Vec<Stream>,
    roots: BufWriter<File>,
    roots_len: u64,
    scratch: Vec<u8>,
}

impl PartWriter {
    pub(super) fn create(
        target: &Path,
        spec: PartSpec,
        geometry: &TileGeometry,
        split: Level,
        tops: Range<u64>,
    ) -> anyhow::Result<Self> {
        let dir = target.parent().context("a part file has a folder")?;
        let name = spec.file_name();
        remove_stale_partials(dir, &name);
        let partial = tempfile::Builder::new()
            .prefix(&partial_prefix(&name, std::process::id()))
            .tempfile_in(dir)
            .with_context(|| format!("cannot create a file in {}", dir.display()))?;
        let finest = geometry.finest();
        let mut levels = Vec::new();
        for l in split.get()..=finest.get() {
            let file = if l == finest.get() {
                let mut f = partial.reopen()?;
                f.seek(SeekFrom::Start(HEADER_LEN as u64))?;
                f
            } else {
                tempfile::tempfile_in(dir)
                    .with_context(|| format!("cannot create a spill file in {}", dir.display()))?
            };
            levels.push(Stream {
                out: BufWriter::with_capacity(SINK_BUFFER, file),
                len: 0,
                records: 0,
            });
        }
        let roots = tempfile::tempfile_in(dir)
            .with_context(|| format!("cannot create a spill file in {}", dir.display()))?;
        Ok(Self {
            target: target.to_path_buf(),
            partial,
            spec,
            split,
            finest,
            next_top: tops.start,
            tops,
            levels,
            roots: BufWriter::with_capacity(ROOTS_BUFFER, roots),
            roots_len: 0,
            scratch: Vec::new(),
        })
    }

    pub(super) fn records(&self) -> u64 {
        self.levels.iter().map(|s| s.records).sum()
    }

    /// Writes `bytes` to the roots' spill file, hashing them.
    fn put_root_bytes(&mut self, bytes: &[u8], hash: &mut Xxh3) -> anyhow::Result<()> {
        self.roots
            .write_all(bytes)
            .context("writing a split-level tile")?;
        hash.update(bytes);
        Ok(())
    }

    /// Appends the spill files, the trailer and the header, re-reads the whole part
    /// and renames it into place. Returns its size.
    pub(super) fn finish(
        self,
        mut trailer: Trailer,
        interrupt: &crate::builder::interrupt::Interrupt,
    ) -> anyhow::Result<u64> {
        let Self {
            target,
            partial,
            spec,
            split,
            finest,
            tops,
            next_top,
            levels,
            roots,
            roots_len,
            ..
        } = self;
        ensure!(
            next_top == tops.end,
            "the part's split-level tiles stopped at {next_top} of {}",
            tops.end
        );
        let mut files = Vec::new();
        for s in levels {
            let f = s
                .out
                .into_inner()
                .map_err(std::io::IntoInnerError::into_error)
                .context("writing a record")?;
            files.push((f, s.len, s.records));
        }
        let mut roots = roots
            .into_inner()
            .map_err(std::io::IntoInnerError::into_error)
            .context("writing a split-level tile")?;
        // Finest level first (already in place), then the coarser ones, then roots.
        let mut sections = vec![Section::default(); files.len()];
        let last = files.len() - 1;
        sections[last] = Section {
            offset: HEADER_LEN as u64,
            len: files[last].1,
            count: files[last].2,
        };
        let mut at = HEADER_LEN as u64 + files[last].1;
        let mut out = partial.reopen()?;
        for (i, (spill, len, count)) in files.iter_mut().enumerate().rev().skip(1) {
            interrupt.check()?;
            spill.seek(SeekFrom::Start(0))?;
            out.seek(SeekFrom::Start(at))?;
            let copied = std::io::copy(spill, &mut out).context("appending a level's records")?;
            ensure!(copied == *len, "a level's spill file lost bytes");
            sections[i] = Section {
                offset: at,
                len: *len,
                count: *count,
            };
            at += *len;
        }
        drop(files);
        roots.seek(SeekFrom::Start(0))?;
        out.seek(SeekFrom::Start(at))?;
        let copied = std::io::copy(&mut roots, &mut out).context("appending the roots")?;
        ensure!(copied == roots_len, "the roots' spill file lost bytes");
        trailer.sections = sections;
        trailer.roots = Section {
            offset: at,
            len: roots_len,
            count: tops.end - tops.start,
        };
        at += roots_len;
        let trailer_bytes = trailer.to_bytes(split.get());
        out.write_all_at(&trailer_bytes, at)
            .context("writing the trailer")?;
        let file_len = at + trailer_bytes.len() as u64;
        let mut header = Header {
            n: spec.n,
            k: spec.k,
            split: split.get(),
            finest: finest.get(),
            trailer_offset: at,
            trailer_len: trailer_bytes.len() as u64,
            file_len,
            checksum: 0,
        };
        header.checksum = header.compute_checksum(&trailer_bytes);
        out.write_all_at(&header.to_bytes(), 0)
            .context("writing the header")?;
        out.set_len(file_len)?;
        out.sync_all().context("syncing the part to disk")?;
        // Re-read what is on disk before it becomes visible under its name.
        let written = PartFile::open(partial.path()).context("re-reading the written part")?;
        written
            .check(interrupt)
            .context("re-reading the written part")?;
        interrupt.check()?;
        publish(partial, &target, "part")?;
        Ok(file_len)
    }
}

impl Sink for PartWriter {
    fn record(
        &mut self,
        level: Level,
        m: Morton,
        record: &[u8],
        summary: IndexEntry,
    ) -> anyhow::Result<()> {
        let s = &mut self.levels[usize::from(level.get() - self.split.get())];
        let frame = Frame {
            m: m.get(),
            length: u32::try_from(record.len()).context("record over 4 GiB")?,
            min: summary.min,
            max: summary.max,
            checksum: format::checksum(record),
            full_res_error: summary.full_res_error,
            flags: summary.flags,
        };
        s.out
            .write_all(&frame.to_bytes())
            .and_then(|()| s.out.write_all(record))
            .with_context(|| format!("cannot write {}", self.target.display()))?;
        s.len += (FRAME_LEN + record.len()) as u64;
        s.records += 1;
        Ok(())
    }

    /// Root frame: `0` (absent), or `1`, the payload's length (u64), the payload
    /// (heights, block errors, block min/max, mask) and its XXH3-64.
    fn top(&mut self, m: Morton, node: Option<Node>) -> anyhow::Result<()> {
        ensure!(
            m.get() == self.next_top && m.get() < self.tops.end,
            "split-level tile {m} arrived out of order (expected {})",
            self.next_top
        );
        self.next_top += 1;
        let Some(node) = node else {
            self.roots
                .write_all(&[0])
                .context("writing a split-level tile")?;
            self.roots_len += 1;
            return Ok(());
        };
        let mask = node.mask.encode();
        let payload = root_fixed_len(node.heights.len(), node.errors.values.len()) + mask.len();
        self.roots
            .write_all(&[1])
            .context("writing a split-level tile")?;
        self.roots
            .write_all(&(payload as u64).to_le_bytes())
            .context("writing a split-level tile")?;
        let mut hash = Xxh3::new();
        let mut scratch = std::mem::take(&mut self.scratch);
        for chunk in node.heights.chunks(1 << 14) {
            scratch.clear();
            scratch.extend(chunk.iter().flat_map(|v| v.to_le_bytes()));
            self.put_root_bytes(&scratch, &mut hash)?;
        }
        for chunk in node.errors.values.chunks(1 << 13) {
            scratch.clear();
            scratch.extend(chunk.iter().flat_map(|v| v.to_bits().to_le_bytes()));
            self.put_root_bytes(&scratch, &mut hash)?;
        }
        scratch.clear();
        scratch.extend(
            node.min
                .iter()
                .chain(&node.max)
                .flat_map(|v| v.to_le_bytes()),
        );
        scratch.extend_from_slice(&(mask.len() as u32).to_le_bytes());
        scratch.extend_from_slice(&mask);
        self.put_root_bytes(&scratch, &mut hash)?;
        self.scratch = scratch;
        self.roots
            .write_all(&hash.digest().to_le_bytes())
            .context("writing a split-level tile")?;
        self.roots_len += 1 + 8 + payload as u64 + 8;
        Ok(())
    }
}
