//! The datasets a server holds: one pyramid file each, named by its file stem.

use super::cache::LastModified;
use super::storage::{FileStorage, Storage, StorageSource};
use anyhow::{Context, bail};
use bytes::Bytes;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU8, Ordering};
use tessera_shared::format::{self, IndexEntry};
use tessera_shared::{Pyramid, TileId};

const UNCHECKED: u8 = 0;
const GOOD: u8 = 1;
const CORRUPT: u8 = 2;
/// Passes its checksum but does not decode (PNG tiles): served as stored, counted once.
const UNDECODABLE: u8 = 3;

/// One served pyramid.
#[derive(Debug)]
pub struct Dataset {
    pub name: String,
    pub path: PathBuf,
    pub storage: Arc<dyn Storage>,
    pub pyramid: Pyramid<StorageSource>,
    /// The file's modification time when it was opened (fstat of the open descriptor),
    /// sent as `Last-Modified` beside every ETag.
    pub last_modified: LastModified,
    /// Per level and Morton code: whether the record's checksum has been checked.
    /// Records are immutable, so each is hashed once, on first use.
    checked: Vec<Vec<AtomicU8>>,
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

/// Why a present record could not be served.
#[derive(Debug, Clone)]
pub enum RecordError {
    /// The record fails its checksum: that tile alone is bad.
    Corrupt(Corrupt),
    /// The file cannot be read as it was opened (truncated or changed under the
    /// server): the whole dataset is unavailable until a reload.
    Unavailable(String),
}

impl Dataset {
    pub fn open(name: String, path: &Path) -> anyhow::Result<Self> {
        let storage: Arc<dyn Storage> =
            Arc::new(FileStorage::open(path).with_context(|| path.display().to_string())?);
        let pyramid = Pyramid::open(StorageSource(storage.clone()))
            .with_context(|| path.display().to_string())?;
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
        Ok(Self {
            name,
            path: path.to_path_buf(),
            last_modified: LastModified::new(storage.modified()),
            storage,
            pyramid,
            checked,
        })
    }

    pub fn content_hash(&self) -> &str {
        &self.pyramid.metadata().content_hash
    }

    /// `Err` with the reason when the file is no longer the one opened (truncated
    /// or rewritten in place): the dataset then answers 503 until a reload.
    pub fn available(&self) -> Result<(), String> {
        self.storage
            .check_unchanged()
            .map_err(|e| format!("dataset {:?} ({}): {e}", self.name, self.path.display()))
    }

    fn state(&self, tile: TileId) -> &AtomicU8 {
        &self.checked[usize::from(tile.level().get())][tile.morton().get() as usize]
    }

    /// A present tile's index entry and stored record, checksum-checked.
    /// `Ok(None)` for an absent tile.
    pub fn record(&self, tile: TileId) -> Result<Option<(IndexEntry, Bytes)>, RecordError> {
        let Some(&entry) = self.pyramid.entry(tile) else {
            return Ok(None);
        };
        let bytes = self
            .storage
            .slice(entry.offset, u64::from(entry.length))
            .map_err(|e| {
                RecordError::Unavailable(format!(
                    "dataset {:?} ({}): cannot read {tile}: {e}",
                    self.name,
                    self.path.display()
                ))
            })?;
        let corrupt = |first| RecordError::Corrupt(Corrupt { tile, entry, first });
        let state = self.state(tile);
        match state.load(Ordering::Relaxed) {
            GOOD | UNDECODABLE => Ok(Some((entry, bytes))),
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
                    Ok(Some((entry, bytes)))
                } else {
                    if first {
                        tracing::error!(dataset = %self.name, %tile, "record fails its checksum; not serving it");
                    }
                    Err(corrupt(first))
                }
            }
        }
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

/// All datasets by name.
#[derive(Debug, Default)]
pub struct Registry {
    pub datasets: BTreeMap<String, Arc<Dataset>>,
}

impl Registry {
    /// Loads every `.tess` file named, and every `.tess` file directly inside each
    /// directory named.
    pub fn load(paths: &[PathBuf]) -> anyhow::Result<Self> {
        let mut files = Vec::new();
        for p in paths {
            let meta =
                std::fs::metadata(p).with_context(|| format!("{}: cannot read", p.display()))?;
            if meta.is_dir() {
                let mut found: Vec<PathBuf> = std::fs::read_dir(p)
                    .with_context(|| format!("{}: cannot list", p.display()))?
                    .flatten()
                    .map(|e| e.path())
                    .filter(|f| f.extension().is_some_and(|e| e == "tess") && f.is_file())
                    .collect();
                found.sort();
                files.extend(found);
            } else {
                files.push(p.clone());
            }
        }
        if files.is_empty() {
            bail!(
                "no .tess pyramid files found in {}",
                paths
                    .iter()
                    .map(|p| p.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        let mut datasets = BTreeMap::new();
        for f in files {
            let name = f
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or("")
                .to_string();
            if !valid_name(&name) {
                bail!(
                    "{}: dataset name {name:?} must be letters, digits, '_', '-' or '.'",
                    f.display()
                );
            }
            let ds = Dataset::open(name.clone(), &f)?;
            if let Some(prev) = datasets.insert(name.clone(), Arc::new(ds)) {
                bail!(
                    "two datasets are named {name:?}: {} and {}",
                    prev.path.display(),
                    f.display()
                );
            }
        }
        Ok(Self { datasets })
    }

    pub fn get(&self, name: &str) -> Option<&Arc<Dataset>> {
        self.datasets.get(name)
    }
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
