//! Writing a pyramid file: records level by level, each level contiguous in
//! Morton order, into a temporary file beside the output that is renamed into
//! place only when complete and verified (docs/ARCHITECTURE.md#building-out-of-core).
//!
//! Records arrive in post-order of the Morton quadtree (a coarse tile right
//! after its four children), so the finest level streams straight into the
//! output while each coarser level goes to its own unnamed spill file, appended
//! after the finest level at the end. File order is therefore finest level first;
//! FORMAT.md allows any level order.

use anyhow::{Context, bail};
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use tempfile::NamedTempFile;
use tessera_shared::format::{
    self, FileHeader, HEADER_LEN, INDEX_ENTRY_LEN, IndexEntry, LEVEL_ENTRY_LEN, LevelEntry, VERSION,
};
use tessera_shared::reader::{self, FileSource};
use tessera_shared::{Level, Metadata, Morton, TileGeometry};
use xxhash_rust::xxh3::Xxh3;

/// Write buffer of each level's record stream.
pub const SINK_BUFFER: usize = 1 << 20;

/// Index entries of one level buffered before they are written to the partial file.
/// Entries arrive in Morton order; short gaps are padded with absent entries so the
/// buffer is one contiguous run (one write), long gaps flush it.
const INDEX_RUN: usize = 4096;
/// The largest run buffer a level holds.
pub const INDEX_RUN_BYTES: usize = (INDEX_RUN + 256) * size_of::<IndexEntry>();

/// Records of one level, in Morton order; their index goes straight to the file.
struct LevelSink {
    out: BufWriter<File>,
    /// Bytes written so far (relative to the level's first record).
    len: u64,
    /// Absolute file offset of this level's index.
    index_offset: u64,
    /// Morton code of `run[0]`.
    run_start: u64,
    run: Vec<IndexEntry>,
}

impl LevelSink {
    /// Adds the entry of tile `m` (offsets still relative to the level's first record).
    fn index(&mut self, file: &File, m: u64, entry: IndexEntry) -> anyhow::Result<()> {
        let next = self.run_start + self.run.len() as u64;
        if self.run.is_empty() {
            self.run_start = m;
        } else if m < next || m - next > 256 || self.run.len() >= INDEX_RUN {
            self.flush_index(file)?;
            self.run_start = m;
        } else {
            self.run
                .resize(self.run.len() + (m - next) as usize, IndexEntry::default());
        }
        self.run.push(entry);
        Ok(())
    }

    fn flush_index(&mut self, file: &File) -> anyhow::Result<()> {
        if self.run.is_empty() {
            return Ok(());
        }
        let bytes: Vec<u8> = self.run.iter().flat_map(IndexEntry::to_bytes).collect();
        file.write_all_at(
            &bytes,
            self.index_offset + self.run_start * INDEX_ENTRY_LEN as u64,
        )
        .context("writing the index")?;
        self.run.clear();
        Ok(())
    }
}

/// A pyramid being written.
///
/// Nothing here grows with the number of tiles: record bytes stream to files and
/// index entries are written into the partial file's index region as they come,
/// so a DEM whose tile grid is mostly empty (or a header that lies about its size)
/// costs disk, proven by data, not memory (docs/ARCHITECTURE.md#bad-input-is-an-error).
pub struct PyramidWriter {
    geometry: TileGeometry,
    target: PathBuf,
    partial: NamedTempFile,
    /// The partial file, for positional index writes.
    file: File,
    records_offset: u64,
    meta_reserve: u64,
    levels: Vec<LevelSink>,
}

impl std::fmt::Debug for PyramidWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PyramidWriter")
            .field("target", &self.target)
            .field("partial", &self.partial.path())
            .finish_non_exhaustive()
    }
}

/// Partial files are named `.NAME.partial-PID-XXXXXX` so a later build can tell
/// whose they are.
pub(super) fn partial_prefix(name: &str, pid: u32) -> String {
    format!(".{name}.partial-{pid}-")
}

/// Removes partial files of `name` left by builds that were killed (their process no
/// longer exists). Only where `/proc` tells which processes are alive.
pub(super) fn remove_stale_partials(dir: &Path, name: &str) {
    if !Path::new("/proc/self").exists() {
        return;
    }
    let prefix = format!(".{name}.partial-");
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let file_name = entry.file_name();
        let Some(rest) = file_name.to_str().and_then(|n| n.strip_prefix(&prefix)) else {
            continue;
        };
        let Some(pid) = rest.split('-').next().and_then(|p| p.parse::<u32>().ok()) else {
            continue;
        };
        if !Path::new(&format!("/proc/{pid}")).exists() {
            match std::fs::remove_file(entry.path()) {
                Ok(()) => {
                    tracing::info!(file = %entry.path().display(), "removed a partial file left by an interrupted build");
                }
                Err(e) => {
                    tracing::warn!(file = %entry.path().display(), error = %e, "cannot remove a stale partial file");
                }
            }
        }
    }
}

/// Why a pyramid's records cannot start at `records_offset`: the index before them
/// (mostly holes on disk) makes the file longer than its file system allows.
fn header_region_too_long(geometry: &TileGeometry, records_offset: u64, dir: &Path) -> String {
    let side = geometry.finest().tiles_per_side();
    format!(
        "the pyramid's records would start at byte {records_offset} ({}), past the longest \
         file the file system of {} holds: the tile grid is square, so the index of a {} × {} \
         DEM in tiles of {} has {side} × {side} slots at its finest level (use a larger \
         --tile-size, or split the raster)",
        super::plausible::bytes(records_offset),
        dir.display(),
        geometry.width(),
        geometry.height(),
        geometry.tile_size(),
    )
}

/// Index bytes for all levels.
fn index_len(geometry: &TileGeometry) -> u64 {
    geometry
        .levels()
        .map(|l| l.tile_slots() * INDEX_ENTRY_LEN as u64)
        .sum()
}

impl PyramidWriter {
    /// Creates the temporary file in the output's directory. `meta_reserve` bounds the
    /// encoded metadata (known up to a few numbers when the build starts).
    pub fn create(
        target: &Path,
        geometry: TileGeometry,
        meta_reserve: u64,
    ) -> anyhow::Result<Self> {
        let dir = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let name = target
            .file_name()
            .context("output path has no file name")?
            .to_string_lossy()
            .into_owned();
        if !dir.is_dir() {
            bail!("output directory {} does not exist", dir.display());
        }
        remove_stale_partials(&dir, &name);
        let partial = tempfile::Builder::new()
            .prefix(&partial_prefix(&name, std::process::id()))
            .tempfile_in(&dir)
            .with_context(|| {
                format!("cannot create a file in output directory {}", dir.display())
            })?;
        let header_region = HEADER_LEN as u64
            + u64::from(geometry.level_count()) * LEVEL_ENTRY_LEN as u64
            + index_len(&geometry)
            + meta_reserve;
        let records_offset = header_region.next_multiple_of(4096);
        let mut levels = Vec::new();
        let mut index_offset =
            HEADER_LEN as u64 + u64::from(geometry.level_count()) * LEVEL_ENTRY_LEN as u64;
        for level in geometry.levels() {
            let file = if level == geometry.finest() {
                let mut f = partial.reopen()?;
                f.seek(SeekFrom::Start(records_offset))
                    .with_context(|| header_region_too_long(&geometry, records_offset, &dir))?;
                f
            } else {
                tempfile::tempfile_in(&dir)
                    .with_context(|| format!("cannot create a spill file in {}", dir.display()))?
            };
            levels.push(LevelSink {
                out: BufWriter::with_capacity(SINK_BUFFER, file),
                len: 0,
                index_offset,
                run_start: 0,
                run: Vec::new(),
            });
            index_offset += level.tile_slots() * INDEX_ENTRY_LEN as u64;
        }
        Ok(Self {
            geometry,
            target: target.to_path_buf(),
            file: partial.reopen()?,
            partial,
            records_offset,
            meta_reserve,
            levels,
        })
    }

    /// The path the finished pyramid will have.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Appends a record; records of a level must arrive in Morton order. `summary`
    /// gives the index entry's min, max, error and flags; the writer fills in where
    /// the record lies and its checksum.
    pub fn push(
        &mut self,
        level: Level,
        m: Morton,
        record: &[u8],
        summary: IndexEntry,
    ) -> anyhow::Result<()> {
        let sink = &mut self.levels[usize::from(level.get())];
        let target = &self.target;
        sink.out
            .write_all(record)
            .with_context(|| format!("cannot write {}", target.display()))?;
        let entry = IndexEntry {
            offset: sink.len,
            length: u32::try_from(record.len()).context("record over 4 GiB")?,
            checksum: format::checksum(record),
            ..summary
        };
        sink.index(&self.file, m.get(), entry)
            .with_context(|| format!("cannot write {}", target.display()))?;
        sink.len += record.len() as u64;
        Ok(())
    }

    /// Appends the coarse levels, rewrites the index with absolute offsets, writes the
    /// header and metadata, syncs, checks every record and renames the file into
    /// place. Returns the final metadata (with its content hash) and the file's size.
    ///
    /// Every pass streams (index a chunk at a time, hashes fed incrementally), so
    /// finishing costs a few MiB whatever the number of tiles.
    ///
    /// `meta` is a DEM's [`Metadata`] or an imagery pyramid's
    /// [`ImageryMetadata`](tessera_shared::imagery::ImageryMetadata): [`FileMeta`].
    pub fn finish<M: FileMeta>(
        self,
        mut meta: M,
        interrupt: &super::interrupt::Interrupt,
        mut progress: impl FnMut(u64),
    ) -> anyhow::Result<(M, u64)> {
        let Self {
            geometry,
            target,
            partial,
            file: out,
            records_offset,
            meta_reserve,
            levels,
        } = self;
        let finest = usize::from(geometry.finest().get());
        let mut files = Vec::new();
        let mut lens = Vec::new();
        let mut index_offsets = Vec::new();
        for mut sink in levels {
            sink.flush_index(&out)?;
            files.push(
                sink.out
                    .into_inner()
                    .map_err(std::io::IntoInnerError::into_error)
                    .context("writing a record")?,
            );
            lens.push(sink.len);
            index_offsets.push(sink.index_offset);
        }
        // Level record ranges: finest first, then coarser ones in descending order.
        let mut level_offset = vec![0u64; files.len()];
        let mut at = records_offset;
        for l in (0..=finest).rev() {
            level_offset[l] = at;
            at += lens[l];
        }
        for l in (0..finest).rev() {
            let spill = &mut files[l];
            spill.seek(SeekFrom::Start(0))?;
            let mut dst = &out;
            dst.seek(SeekFrom::Start(level_offset[l]))?;
            std::io::copy(spill, &mut dst).context("appending a level's records")?;
        }
        drop(files);
        // The metadata's own numbers are final, so its content hash can be fed as the
        // index is rewritten: record checksums, levels ascending, Morton order.
        let mut content = meta.content_hasher();
        let mut chunk = Vec::new();
        for (l, level) in geometry.levels().enumerate() {
            interrupt.check()?;
            let slots = level.tile_slots();
            let mut m = 0u64;
            while m < slots {
                let n = (slots - m).min(1 << 16);
                let off = index_offsets[l] + m * INDEX_ENTRY_LEN as u64;
                chunk.resize(n as usize * INDEX_ENTRY_LEN, 0);
                out.read_exact_at(&mut chunk, off)
                    .context("re-reading the index")?;
                let mut dirty = false;
                for b in chunk.chunks_exact_mut(INDEX_ENTRY_LEN) {
                    let mut e = IndexEntry::parse(b);
                    if e.is_present() {
                        e.offset += level_offset[l];
                        content.record(e.checksum);
                        b.copy_from_slice(&e.to_bytes());
                        dirty = true;
                    }
                }
                if dirty {
                    out.write_all_at(&chunk, off).context("writing the index")?;
                }
                m += n;
            }
        }
        meta.set_content_hash(content.finish());
        let meta_bytes = meta.encode();
        if meta_bytes.len() as u64 > meta_reserve {
            bail!(
                "metadata ({} bytes) outgrew its reserved space",
                meta_bytes.len()
            );
        }
        // Header region: header · level table · indices · metadata · zero padding.
        let level_table_offset = HEADER_LEN as u64;
        let mut table = Vec::new();
        for (l, level) in geometry.levels().enumerate() {
            let entry = LevelEntry {
                level: level.get(),
                tiles_per_side: level.tiles_per_side(),
                index_offset: index_offsets[l],
                index_entries: level.tile_slots(),
                records_offset: level_offset[l],
                records_len: lens[l],
            };
            table.extend_from_slice(&entry.to_bytes());
        }
        let meta_offset = level_table_offset + table.len() as u64 + index_len(&geometry);
        out.write_all_at(&table, level_table_offset)
            .context("writing the level table")?;
        // Zero the metadata's reserved space (the file is sparse there otherwise, but
        // explicit zeros keep the checksummed bytes independent of the filesystem).
        let mut meta_area = meta_bytes.clone();
        meta_area.resize((records_offset - meta_offset) as usize, 0);
        out.write_all_at(&meta_area, meta_offset)
            .context("writing the metadata")?;
        let mut header = FileHeader {
            version: VERSION,
            flags: M::HEADER_FLAGS,
            meta_offset,
            meta_len: meta_bytes.len() as u64,
            level_table_offset,
            level_count: u32::from(geometry.level_count()),
            index_entry_len: INDEX_ENTRY_LEN as u32,
            records_offset,
            checksum: 0,
        };
        // The header checksum over the region as it now lies on disk.
        let mut h = Xxh3::new();
        h.update(&header.to_bytes()[..56]);
        let mut pos = HEADER_LEN as u64;
        while pos < records_offset {
            let n = (records_offset - pos).min(1 << 21) as usize;
            chunk.resize(n, 0);
            out.read_exact_at(&mut chunk, pos)
                .context("re-reading the header region")?;
            h.update(&chunk);
            pos += n as u64;
        }
        drop(chunk);
        header.checksum = h.digest();
        out.write_all_at(&header.to_bytes(), 0)
            .context("writing the header")?;
        out.sync_all().context("syncing the pyramid to disk")?;
        // Verify what is on disk before it becomes visible at the output path.
        let source = FileSource::open(partial.path())?;
        let written = M::check_written(&source, &mut |_, _, _| {
            progress(1);
            Ok(())
        })
        .context("re-reading the written pyramid")?;
        anyhow::ensure!(
            written == meta,
            "the written pyramid's metadata differs from what was written"
        );
        interrupt.check()?;
        publish(partial, &target, "pyramid")?;
        Ok((meta, at))
    }
}

/// What sees each checked record while a written file is re-read.
pub type EachRecord<'a> =
    dyn FnMut(tessera_shared::TileId, &IndexEntry, &[u8]) -> Result<(), reader::ReadError> + 'a;

/// What a pyramid file's header describes it with: a DEM's [`Metadata`], or an
/// imagery pyramid's metadata (same container, FORMAT.md "Imagery pyramids").
pub trait FileMeta: PartialEq + Sized {
    /// The header's flags (and so its magic).
    const HEADER_FLAGS: u32;
    /// The content hash fed with this metadata (its hash empty).
    fn content_hasher(&self) -> format::ContentHasher;
    fn set_content_hash(&mut self, hash: String);
    /// The bytes stored in the header region.
    fn encode(&self) -> Vec<u8>;
    /// Checks a whole written file of this kind, returning the metadata it holds.
    fn check_written(
        source: &FileSource,
        each: &mut EachRecord<'_>,
    ) -> Result<Self, reader::ReadError>;
}

impl FileMeta for Metadata {
    const HEADER_FLAGS: u32 = 0;
    fn content_hasher(&self) -> format::ContentHasher {
        format::ContentHasher::new(self)
    }
    fn set_content_hash(&mut self, hash: String) {
        self.content_hash = hash;
    }
    fn encode(&self) -> Vec<u8> {
        format::encode_metadata(self)
    }
    fn check_written(
        source: &FileSource,
        each: &mut EachRecord<'_>,
    ) -> Result<Self, reader::ReadError> {
        reader::check_streaming(source, each)
    }
}

impl FileMeta for tessera_shared::imagery::ImageryMetadata {
    const HEADER_FLAGS: u32 = format::FILE_IMAGERY;
    fn content_hasher(&self) -> format::ContentHasher {
        format::ContentHasher::imagery(self)
    }
    fn set_content_hash(&mut self, hash: String) {
        self.content_hash = hash;
    }
    fn encode(&self) -> Vec<u8> {
        format::encode_imagery_metadata(self)
    }
    fn check_written(
        source: &FileSource,
        each: &mut EachRecord<'_>,
    ) -> Result<Self, reader::ReadError> {
        reader::check_streaming_imagery(source, each)
    }
}

/// Renames a finished, verified temporary file into place as an ordinary file:
/// temporary files are private (0600), a finished pyramid or part is not.
pub(super) fn publish(partial: NamedTempFile, target: &Path, what: &str) -> anyhow::Result<()> {
    std::fs::set_permissions(
        partial.path(),
        std::os::unix::fs::PermissionsExt::from_mode(0o644),
    )?;
    partial
        .persist(target)
        .map_err(|e| e.error)
        .with_context(|| format!("cannot move the finished {what} to {}", target.display()))?;
    Ok(())
}
