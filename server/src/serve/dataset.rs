//! One served dataset: a pyramid file (or object) and what its records were found
//! to be.

use crate::http::cache::LastModified;
use crate::storage::{FileStorage, Storage, StorageSource, StorageUnavailable};
use anyhow::Context;
use bytes::Bytes;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU8, Ordering};
use tessera_shared::format::{self, IndexEntry};
use tessera_shared::{Level, MortonRange, Pyramid, TileId};

const UNCHECKED: u8 = 0;
const GOOD: u8 = 1;
const CORRUPT: u8 = 2;
/// Passes its checksum but does not decode (PNG tiles): served as stored, counted once.
const UNDECODABLE: u8 = 3;

/// One served pyramid.
#[derive(Debug)]
pub struct Dataset {
    pub name: String,
    /// Where the pyramid is: a path, or an object's URL (for messages and logs).
    pub path: PathBuf,
    pub storage: Arc<dyn Storage>,
    pub pyramid: Pyramid<StorageSource>,
    /// The file's modification time when it was opened (fstat of the open descriptor),
    /// sent as `Last-Modified` beside every ETag.
    pub last_modified: LastModified,
    /// Per level and Morton code: whether the record's checksum has been checked.
    /// Records are immutable, so each is hashed once, on first use.
    checked: Vec<Vec<AtomicU8>>,
    /// The imagery pyramid beside this DEM's (`NAME.tessimg`,
    /// DECISIONS.md "Imagery pyramids"), itself a dataset whose [`Dataset::pyramid`] is
    /// opened with `Pyramid::open_imagery`.
    pub imagery: Option<Arc<Dataset>>,
    /// Whether the pyramid stores some places only down to a coarser level (its
    /// sources say so: DECISIONS.md "Multi-resolution pyramids"), so an absent tile
    /// may be its ancestor's surface rather than no data.
    pub multi_resolution: bool,
}

/// A record that failed its checksum.
#[derive(Debug, Clone)]
pub struct Corrupt {
    pub tile: TileId,
    pub entry: IndexEntry,
    /// Whether this read is the one that found the damage (metrics count distinct
    /// records as well as reads).
    pub first: bool,
}

/// A requested code and what [`Dataset::records`] found for it: `None` when no
/// tile is stored there, else the record or why it is corrupt.
#[derive(Debug)]
pub struct RangeRecord {
    pub tile: TileId,
    pub record: Option<Result<(IndexEntry, Bytes), Corrupt>>,
}

/// Why a present record could not be served.
#[derive(Debug)]
pub enum RecordError {
    /// The record fails its checksum: that tile alone is bad.
    Corrupt(Corrupt),
    /// The file cannot be read as it was opened (truncated or changed under the
    /// server): the whole dataset is unavailable until a reload.
    Unavailable(DatasetUnavailable),
}

/// Why a dataset cannot be served now: it answers 503 until a reload.
#[derive(Debug, thiserror::Error)]
#[error("dataset {name:?} ({}): {reason}", path.display())]
pub struct DatasetUnavailable {
    pub name: String,
    pub path: PathBuf,
    /// Boxed: an object store's error is large, and this travels in every tile
    /// route's `Result`.
    pub reason: Box<UnavailableReason>,
}

/// What made a dataset unavailable ([`DatasetUnavailable`]).
#[derive(Debug, thiserror::Error)]
pub enum UnavailableReason {
    /// Its storage is no longer what was opened, or cannot be reached.
    #[error(transparent)]
    Storage(#[from] StorageUnavailable),
    /// A read failed: `what` (a tile, a level) could not be read.
    #[error("cannot read {what}: {source}")]
    Unreadable {
        what: String,
        source: std::io::Error,
    },
}

impl Dataset {
    /// Opens a local pyramid file.
    pub fn open(name: String, path: &Path) -> anyhow::Result<Self> {
        let storage: Arc<dyn Storage> =
            Arc::new(FileStorage::open(path).with_context(|| path.display().to_string())?);
        Self::from_storage(name, path.to_path_buf(), storage)
    }

    /// Opens a pyramid held by `storage`, labelled `path` in messages.
    pub fn from_storage(
        name: String,
        path: PathBuf,
        storage: Arc<dyn Storage>,
    ) -> anyhow::Result<Self> {
        let pyramid = Pyramid::open(StorageSource(storage.clone()))
            .with_context(|| path.display().to_string())?;
        Self::from_pyramid(name, path, storage, pyramid)
    }

    /// Opens a local imagery pyramid ([`crate::imagery`]).
    pub fn open_imagery(name: String, path: &Path) -> anyhow::Result<Self> {
        let storage: Arc<dyn Storage> =
            Arc::new(FileStorage::open(path).with_context(|| path.display().to_string())?);
        Self::imagery_from_storage(name, path.to_path_buf(), storage)
    }

    /// Opens an imagery pyramid in any storage (a local file, an object), `path`
    /// naming it in messages.
    pub fn imagery_from_storage(
        name: String,
        path: PathBuf,
        storage: Arc<dyn Storage>,
    ) -> anyhow::Result<Self> {
        let pyramid = Pyramid::open_imagery(StorageSource(storage.clone()))
            .with_context(|| path.display().to_string())?;
        Self::from_pyramid(name, path, storage, pyramid)
    }

    fn from_pyramid(
        name: String,
        path: PathBuf,
        storage: Arc<dyn Storage>,
        pyramid: Pyramid<StorageSource>,
    ) -> anyhow::Result<Self> {
        // The hash goes verbatim into ETag headers and URLs: refuse the file now rather
        // than fail (or worse, emit a broken header) on every request.
        pyramid
            .metadata()
            .check_content_hash()
            .map_err(|e| anyhow::anyhow!("{}: cannot serve: {e}", path.display()))?;
        let checked = pyramid
            .geometry()
            .levels()
            .map(|l| {
                (0..l.tile_slots())
                    .map(|_| AtomicU8::new(UNCHECKED))
                    .collect()
            })
            .collect();
        let finest = pyramid.geometry().finest().get();
        let multi_resolution = pyramid.metadata().sources.iter().any(|s| s.level < finest);
        Ok(Self {
            name,
            multi_resolution,
            last_modified: LastModified::new(storage.modified()),
            path,
            storage,
            pyramid,
            checked,
            imagery: None,
        })
    }

    /// The file's own content hash (an imagery pyramid's, not its DEM's).
    pub fn content_hash(&self) -> &str {
        self.pyramid
            .imagery()
            .map_or(&self.pyramid.metadata().content_hash, |i| &i.content_hash)
    }

    /// `Err` with the reason when the file is no longer the one opened (truncated
    /// or rewritten in place): the dataset then answers 503 until a reload.
    pub fn available(&self) -> Result<(), DatasetUnavailable> {
        self.storage
            .check_unchanged()
            .map_err(|e| self.unavailable(e.into()))
    }

    fn unavailable(&self, reason: UnavailableReason) -> DatasetUnavailable {
        DatasetUnavailable {
            name: self.name.clone(),
            path: self.path.clone(),
            reason: Box::new(reason),
        }
    }

    fn state(&self, tile: TileId) -> &AtomicU8 {
        &self.checked[usize::from(tile.level().get())][tile.morton().get() as usize]
    }

    /// A present tile's index entry and stored record, checksum-checked.
    /// `Ok(None)` for an absent tile. Blocking: for the tile makers' blocking
    /// threads; async routes use [`Dataset::records`].
    pub fn record(&self, tile: TileId) -> Result<Option<(IndexEntry, Bytes)>, RecordError> {
        let Some(&entry) = self.pyramid.entry(tile) else {
            return Ok(None);
        };
        let bytes = self
            .storage
            .slice(entry.offset, u64::from(entry.length))
            .map_err(|e| RecordError::Unavailable(self.unreadable(tile.to_string(), e)))?;
        self.checked(tile, entry, bytes)
            .map(Some)
            .map_err(RecordError::Corrupt)
    }

    fn unreadable(&self, what: String, source: std::io::Error) -> DatasetUnavailable {
        self.unavailable(UnavailableReason::Unreadable { what, source })
    }

    /// The records of `ranges` of `level`, in order: each requested code with its
    /// entry and checksum-checked record, or `None` when absent. The present records
    /// of a Morton range are one contiguous byte range (FORMAT.md), and touching
    /// ranges are merged, so this is one read per run — one ranged GET on a cold
    /// object store, one `pread` on a local file. `Err` only when the storage
    /// cannot be read, with the reason (the whole response is then a 503).
    pub async fn records(
        &self,
        level: Level,
        ranges: &[MortonRange],
    ) -> Result<Vec<RangeRecord>, DatasetUnavailable> {
        let mut out = Vec::new();
        // Byte spans to read: (start, end, first index into `out`, last + 1).
        let mut spans: Vec<(u64, u64, usize, usize)> = Vec::new();
        for r in ranges {
            for m in r.iter() {
                let tile =
                    TileId::from_morton(level, m).expect("ranges are checked against the level");
                let entry = self.pyramid.entry(tile).copied();
                if let Some(e) = entry {
                    let (a, z) = (e.offset, e.offset + u64::from(e.length));
                    match spans.last_mut() {
                        Some(s) if s.1 == a => {
                            s.1 = z;
                            s.3 = out.len() + 1;
                        }
                        _ => spans.push((a, z, out.len(), out.len() + 1)),
                    }
                }
                out.push((tile, entry));
            }
        }
        let mut records: Vec<Option<Result<(IndexEntry, Bytes), Corrupt>>> =
            (0..out.len()).map(|_| None).collect();
        let reads = spans
            .iter()
            .map(|&(a, z, _, _)| self.storage.read(a, z - a));
        let read = futures_util::future::join_all(reads).await;
        for (&(a, _, first, last), bytes) in spans.iter().zip(read) {
            let bytes = bytes.map_err(|e| self.unreadable(format!("level {level}"), e))?;
            for i in first..last {
                let (tile, Some(e)) = out[i] else { continue };
                let from = (e.offset - a) as usize;
                let record = bytes.slice(from..from + e.length as usize);
                records[i] = Some(self.checked(tile, e, record));
            }
        }
        Ok(out
            .into_iter()
            .zip(records)
            .map(|((tile, _), record)| RangeRecord { tile, record })
            .collect())
    }

    /// One tile's record for an async route: [`Dataset::record`] without blocking.
    pub async fn record_async(
        &self,
        tile: TileId,
    ) -> Result<Option<(IndexEntry, Bytes)>, RecordError> {
        let level = tile.level();
        let m = tile.morton();
        let one = MortonRange::new(m, m).expect("a single code");
        let mut got = self
            .records(level, &[one])
            .await
            .map_err(RecordError::Unavailable)?;
        match got.pop().and_then(|r| r.record) {
            None => Ok(None),
            Some(Ok(r)) => Ok(Some(r)),
            Some(Err(c)) => Err(RecordError::Corrupt(c)),
        }
    }

    /// `bytes` as `tile`'s record if it passes its checksum (checked once per record).
    fn checked(
        &self,
        tile: TileId,
        entry: IndexEntry,
        bytes: Bytes,
    ) -> Result<(IndexEntry, Bytes), Corrupt> {
        let corrupt = |first| Corrupt { tile, entry, first };
        let state = self.state(tile);
        match state.load(Ordering::Relaxed) {
            GOOD | UNDECODABLE => Ok((entry, bytes)),
            CORRUPT => Err(corrupt(false)),
            _ => {
                let ok = format::checksum(&bytes) == entry.checksum;
                let new = if ok { GOOD } else { CORRUPT };
                // Only the read that moves the record out of UNCHECKED reports it as
                // newly found, so concurrent first reads count it once.
                let first = state
                    .compare_exchange(UNCHECKED, new, Ordering::Relaxed, Ordering::Relaxed)
                    .is_ok();
                if ok {
                    Ok((entry, bytes))
                } else {
                    if first {
                        tracing::error!(dataset = %self.name, %tile, "record fails its checksum; not serving it");
                    }
                    Err(corrupt(first))
                }
            }
        }
    }

    /// Whether `tile`'s record has passed its checksum (it is then served without
    /// hashing it again: records are immutable).
    pub fn verified(&self, tile: TileId) -> bool {
        matches!(self.state(tile).load(Ordering::Relaxed), GOOD | UNDECODABLE)
    }

    /// Marks a record that passed its checksum but does not decode; `true` the first
    /// time (so it is counted once as a distinct corrupt record).
    pub fn mark_undecodable(&self, tile: TileId) -> bool {
        self.state(tile)
            .compare_exchange(GOOD, UNDECODABLE, Ordering::Relaxed, Ordering::Relaxed)
            .is_ok()
    }
}

/// Dataset names are file stems made of `[A-Za-z0-9_.-]`, so they are safe in URLs
/// and can never name a path.
pub fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= 128
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
}

#[cfg(test)]
mod tests {
    use super::valid_name;

    #[test]
    fn names_cannot_escape() {
        assert!(valid_name("moon8k"));
        assert!(valid_name("N46E008.v2"));
        for bad in [
            "", "..", "../etc", "a/b", "a\\b", ".hidden", "sp ace", "%2e%2e",
        ] {
            assert!(!valid_name(bad), "{bad:?}");
        }
    }
}
