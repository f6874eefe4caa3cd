//! The datasets a server holds: one pyramid file each, named by its file stem, with
//! the imagery pyramid beside it when there is one (see [`super::attached_imagery`]).

use super::attached_imagery as imagery;
use super::dataset::{Dataset, valid_name};
use crate::storage::{self, Location, ObjectStorage, Storage, StoreContext};
use anyhow::{Context, bail};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

/// All datasets by name.
#[derive(Debug, Default)]
pub struct Registry {
    pub datasets: BTreeMap<String, Arc<Dataset>>,
}

impl Registry {
    /// Loads every `.tess` file named, every `.tess` file directly inside each
    /// directory named, and every object URL named (`s3://…`, [`storage::locate`]),
    /// the objects read through `store` (its block cache and metrics).
    /// The one dataset of `path` (a `.tess` file or an object URL) for a command-line
    /// tool (`query`, `export`), read through a store of its own (a 64 MiB block cache,
    /// the environment's credentials, metrics nobody scrapes).
    pub fn open_one(path: &std::path::Path) -> anyhow::Result<Arc<Dataset>> {
        let store = Arc::new(StoreContext::new(
            64 << 20,
            storage::StoreOptions::default(),
            &prometheus::Registry::new(),
        ));
        let registry = Self::load(&[path.to_path_buf()], &store)?;
        registry
            .datasets
            .into_values()
            .next()
            .ok_or_else(|| anyhow::anyhow!("{}: no pyramid", path.display()))
    }

    pub fn load(paths: &[PathBuf], store: &Arc<StoreContext>) -> anyhow::Result<Self> {
        let mut found: Vec<(String, PathBuf, Location)> = Vec::new();
        for p in paths {
            let raw = p.to_string_lossy();
            if let Location::Object(o) = storage::locate(&raw, store.options)? {
                found.push((o.stem(), p.clone(), Location::Object(o)));
                continue;
            }
            let meta =
                std::fs::metadata(p).with_context(|| format!("{}: cannot read", p.display()))?;
            let files = if meta.is_dir() {
                let mut files: Vec<PathBuf> = std::fs::read_dir(p)
                    .with_context(|| format!("{}: cannot list", p.display()))?
                    .flatten()
                    .map(|e| e.path())
                    .filter(|f| f.extension().is_some_and(|e| e == "tess") && f.is_file())
                    .collect();
                files.sort();
                files
            } else {
                vec![p.clone()]
            };
            for f in files {
                let stem = f
                    .file_stem()
                    .and_then(|s| s.to_str())
                    .unwrap_or("")
                    .to_string();
                found.push((stem, f.clone(), Location::Local(f)));
            }
        }
        if found.is_empty() {
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
        for (name, label, location) in found {
            if !valid_name(&name) {
                bail!(
                    "{}: dataset name {name:?} must be letters, digits, '_', '-' or '.'",
                    label.display()
                );
            }
            let ds = match location {
                Location::Local(f) => {
                    let mut ds = Dataset::open(name.clone(), &f)?;
                    ds.imagery = imagery::open_beside(&ds, &f)?;
                    ds
                }
                Location::Object(o) => {
                    let beside = o.sibling(crate::imagery::EXTENSION);
                    let storage: Arc<dyn Storage> =
                        Arc::new(ObjectStorage::open(o, store.clone())?);
                    let mut ds = Dataset::from_storage(name.clone(), label.clone(), storage)?;
                    if let Some(beside) = beside {
                        ds.imagery = imagery::open_beside_object(&ds, beside, store)?;
                    }
                    ds
                }
            };
            if let Some(prev) = datasets.insert(name.clone(), Arc::new(ds)) {
                bail!(
                    "two datasets are named {name:?}: {} and {}",
                    prev.path.display(),
                    label.display()
                );
            }
        }
        Ok(Self { datasets })
    }

    pub fn get(&self, name: &str) -> Option<&Arc<Dataset>> {
        self.datasets.get(name)
    }
}
