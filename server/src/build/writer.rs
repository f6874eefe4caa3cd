//! Writing a pyramid file: records level by level, each level contiguous in
//! Morton order, into a temporary file beside the output that is renamed into
//! place only when complete and verified (DESIGN §3).
//!
//! Records arrive in post-order of the Morton quadtree (a coarse tile right
//! after its four children), so the finest level streams straight into the
//! output while each coarser level goes to its own unnamed spill file, appended
//! after the finest level at the end. File order is therefore finest level first;
//! FORMAT.md allows any level order.

use anyhow::{Context, bail};
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use tempfile::NamedTempFile;
use tessera_shared::format::{
    self, FileHeader, HEADER_LEN, INDEX_ENTRY_LEN, IndexEntry, LEVEL_ENTRY_LEN, LevelEntry, VERSION,
};
use tessera_shared::{Level, Metadata, Morton, Pyramid, TileGeometry};

/// Records of one level, in Morton order, and their index.
struct LevelSink {
    out: BufWriter<File>,
    /// Bytes written so far (relative to the level's first record).
    len: u64,
    index: Vec<IndexEntry>,
}

/// A pyramid being written.
pub struct PyramidWriter {
    geometry: TileGeometry,
    target: PathBuf,
    partial: NamedTempFile,
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
fn partial_prefix(name: &str, pid: u32) -> String {
    format!(".{name}.partial-{pid}-")
}

/// Removes partial files of `name` left by builds that were killed (their process no
/// longer exists). Only where `/proc` tells which processes are alive.
fn remove_stale_partials(dir: &Path, name: &str) {
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
        for level in geometry.levels() {
            let file = if level == geometry.finest() {
                let mut f = partial.reopen()?;
                f.seek(SeekFrom::Start(records_offset))?;
                f
            } else {
                tempfile::tempfile_in(&dir)
                    .with_context(|| format!("cannot create a spill file in {}", dir.display()))?
            };
            levels.push(LevelSink {
                out: BufWriter::with_capacity(1 << 20, file),
                len: 0,
                index: vec![IndexEntry::default(); level.tile_slots() as usize],
            });
        }
        Ok(Self {
            geometry,
            target: target.to_path_buf(),
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

    /// Appends a record; records of a level must arrive in Morton order.
    pub fn push(
        &mut self,
        level: Level,
        m: Morton,
        record: &[u8],
        min: u16,
        max: u16,
        full_res_error: f32,
    ) -> anyhow::Result<()> {
        let sink = &mut self.levels[usize::from(level.get())];
        sink.out.write_all(record)?;
        sink.index[m.get() as usize] = IndexEntry {
            offset: sink.len,
            length: u32::try_from(record.len()).context("record over 4 GiB")?,
            min,
            max,
            checksum: format::checksum(record),
            full_res_error,
            flags: 0,
        };
        sink.len += record.len() as u64;
        Ok(())
    }

    /// Appends the coarse levels, writes the header, metadata and index, syncs,
    /// checks every record and renames the file into place. Returns the final metadata
    /// (with its content hash) and the file's size.
    pub fn finish(
        self,
        mut meta: Metadata,
        mut progress: impl FnMut(u64),
    ) -> anyhow::Result<(Metadata, u64)> {
        let Self {
            geometry,
            target,
            partial,
            records_offset,
            meta_reserve,
            levels,
        } = self;
        let finest = usize::from(geometry.finest().get());
        let mut files = Vec::new();
        let mut lens = Vec::new();
        let mut indices = Vec::new();
        for sink in levels {
            files.push(
                sink.out
                    .into_inner()
                    .map_err(std::io::IntoInnerError::into_error)?,
            );
            lens.push(sink.len);
            indices.push(sink.index);
        }
        // Level record ranges: finest first, then coarser ones in descending order.
        let mut level_offset = vec![0u64; files.len()];
        let mut at = records_offset;
        for l in (0..=finest).rev() {
            level_offset[l] = at;
            at += lens[l];
        }
        let mut out = partial.reopen()?;
        for l in (0..finest).rev() {
            let spill = &mut files[l];
            spill.seek(SeekFrom::Start(0))?;
            out.seek(SeekFrom::Start(level_offset[l]))?;
            std::io::copy(spill, &mut out)?;
        }
        drop(files);
        for (l, index) in indices.iter_mut().enumerate() {
            for e in index.iter_mut().filter(|e| e.is_present()) {
                e.offset += level_offset[l];
            }
        }
        // Content hash over record checksums, levels ascending, Morton order.
        let checksums: Vec<u64> = indices
            .iter()
            .flat_map(|i| i.iter().filter(|e| e.is_present()).map(|e| e.checksum))
            .collect();
        meta.content_hash = format::content_hash(&meta, checksums.iter());
        let meta_bytes = format::encode_metadata(&meta);
        if meta_bytes.len() as u64 > meta_reserve {
            bail!(
                "metadata ({} bytes) outgrew its reserved space",
                meta_bytes.len()
            );
        }
        // Header region: header · level table · indices · metadata · zero padding.
        let level_table_offset = HEADER_LEN as u64;
        let mut region = Vec::with_capacity((records_offset - HEADER_LEN as u64) as usize);
        let mut index_at =
            level_table_offset + u64::from(geometry.level_count()) * LEVEL_ENTRY_LEN as u64;
        for (l, level) in geometry.levels().enumerate() {
            let entry = LevelEntry {
                level: level.get(),
                tiles_per_side: level.tiles_per_side(),
                index_offset: index_at,
                index_entries: level.tile_slots(),
                records_offset: level_offset[l],
                records_len: lens[l],
            };
            region.extend_from_slice(&entry.to_bytes());
            index_at += level.tile_slots() * INDEX_ENTRY_LEN as u64;
        }
        for index in &indices {
            for e in index {
                region.extend_from_slice(&e.to_bytes());
            }
        }
        let meta_offset = HEADER_LEN as u64 + region.len() as u64;
        region.extend_from_slice(&meta_bytes);
        region.resize((records_offset - HEADER_LEN as u64) as usize, 0);
        let mut header = FileHeader {
            version: VERSION,
            flags: 0,
            meta_offset,
            meta_len: meta_bytes.len() as u64,
            level_table_offset,
            level_count: u32::from(geometry.level_count()),
            index_entry_len: INDEX_ENTRY_LEN as u32,
            records_offset,
            checksum: 0,
        };
        header.checksum = header.compute_checksum(&region);
        out.seek(SeekFrom::Start(0))?;
        out.write_all(&header.to_bytes())?;
        out.write_all(&region)?;
        out.sync_all()?;
        // Verify what is on disk before it becomes visible at the output path.
        let pyramid =
            Pyramid::open_file(partial.path()).context("re-reading the written pyramid")?;
        for level in geometry.levels() {
            for tile in geometry.present_tiles(level) {
                pyramid
                    .read_record(tile)
                    .with_context(|| format!("verifying the written {tile}"))?;
                progress(1);
            }
        }
        // Temporary files are private (0600); a finished pyramid is an ordinary file.
        std::fs::set_permissions(
            partial.path(),
            std::os::unix::fs::PermissionsExt::from_mode(0o644),
        )?;
        partial
            .persist(&target)
            .map_err(|e| e.error)
            .with_context(|| format!("cannot move the finished pyramid to {}", target.display()))?;
        Ok((meta, at))
    }
}
