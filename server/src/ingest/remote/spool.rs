//! Inputs that cannot be read by range (striped GeoTIFFs, `.hgt`, PNG), fetched whole
//! once per build into a folder under TMPDIR and read from there.

use super::super::RowSource;
use crate::storage::{ObjectStorage, Storage, StoreOptions, object_at};
use anyhow::{Context, bail};
use futures_util::StreamExt;
use object_store::{GetOptions, ObjectStore};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};

/// Bytes fetched whole into spools (ranged reads are counted by the context).
pub(super) static SPOOLED: AtomicU64 = AtomicU64::new(0);

/// Opens `url`'s spooled copy (fetching it the first time) with the reader its
/// content calls for.
pub(super) fn open(
    url: &str,
    object: &ObjectStorage,
) -> anyhow::Result<(Box<dyn RowSource>, &'static str)> {
    let spooled = spooled(url, object)?;
    let (inner, format) = super::super::open_raster(&spooled.path)?;
    Ok((
        Box::new(Spooled {
            inner,
            _file: spooled,
        }),
        format,
    ))
}

#[derive(Debug)]
struct SpoolFile {
    _dir: tempfile::TempDir,
    path: PathBuf,
}

/// The spooled copies of this build's inputs, by URL: fetched once, however often the
/// build opens them; removed by [`SpoolScope`].
fn spools() -> &'static std::sync::Mutex<std::collections::HashMap<String, Arc<SpoolFile>>> {
    static SPOOLS: OnceLock<std::sync::Mutex<std::collections::HashMap<String, Arc<SpoolFile>>>> =
        OnceLock::new();
    SPOOLS.get_or_init(Default::default)
}

fn spooled(url: &str, object: &ObjectStorage) -> anyhow::Result<Arc<SpoolFile>> {
    if let Some(s) = spools()
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .get(url)
    {
        return Ok(s.clone());
    }
    let s = Arc::new(spool(url, object)?);
    spools()
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .insert(url.to_string(), s.clone());
    Ok(s)
}

/// Held for a build: when it ends (done, failed or interrupted), the spooled copies
/// of its inputs go (a reader still open keeps its own until it is dropped).
#[derive(Debug)]
pub struct SpoolScope(());

impl SpoolScope {
    pub fn new() -> Self {
        Self(())
    }
}

impl Default for SpoolScope {
    fn default() -> Self {
        Self::new()
    }
}

impl Drop for SpoolScope {
    fn drop(&mut self) {
        spools()
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clear();
    }
}

/// Fetches the whole object into a fresh folder under TMPDIR, under its own file
/// name (an `.hgt` tile's name is its place), checked against the ETag seen at open.
fn spool(url: &str, object: &ObjectStorage) -> anyhow::Result<SpoolFile> {
    let tmp = std::env::temp_dir();
    let size = object.size();
    if let Ok(st) = rustix::fs::statvfs(&tmp)
        && st.f_blocks > 0
    {
        let free = st.f_bavail.saturating_mul(st.f_frsize);
        if size > free {
            bail!(
                "{size} bytes must be fetched whole (it is not a tiled GeoTIFF), but TMPDIR \
                 ({}) has {free} bytes free; convert it to a Cloud-Optimized GeoTIFF \
                 (gdal_translate -of COG), or point TMPDIR at a larger disk",
                tmp.display()
            );
        }
    }
    let dir = tempfile::Builder::new()
        .prefix("tessera-input-")
        .tempdir_in(&tmp)
        .with_context(|| format!("cannot make a spool folder in {}", tmp.display()))?;
    let name = Path::new(url)
        .file_name()
        .map_or_else(|| "input".into(), std::ffi::OsStr::to_os_string);
    let path = dir.path().join(name);
    let mut file = std::fs::File::create(&path)
        .with_context(|| format!("cannot create {}", path.display()))?;
    let loc = object_at(url, StoreOptions::default())?;
    let (store, key) = (loc.store.clone(), loc.key.clone());
    let etag = object.etag().map(str::to_string);
    let (tx, rx) = std::sync::mpsc::sync_channel::<Result<bytes::Bytes, String>>(4);
    crate::storage::runtime::io_runtime().spawn(async move {
        let options = GetOptions {
            if_match: etag,
            ..GetOptions::default()
        };
        let got: Result<_, object_store::Error> = store.get_opts(&key, options).await;
        match got {
            Ok(r) => {
                let mut s = r.into_stream();
                while let Some(chunk) = s.next().await {
                    let msg = chunk.map_err(|e| format!("the download failed: {e}"));
                    let stop = msg.is_err();
                    if tx.send(msg).is_err() || stop {
                        return;
                    }
                }
            }
            Err(e @ object_store::Error::Precondition { .. }) => {
                let _ = tx.send(Err(format!(
                    "the object changed in the store after it was opened: {e}"
                )));
            }
            Err(e) => {
                let _ = tx.send(Err(format!("cannot fetch the object: {e}")));
            }
        }
    });
    let mut got = 0u64;
    for chunk in rx {
        let chunk = chunk.map_err(anyhow::Error::msg)?;
        file.write_all(&chunk)
            .with_context(|| format!("cannot write {}", path.display()))?;
        got += chunk.len() as u64;
        SPOOLED.fetch_add(chunk.len() as u64, Ordering::Relaxed);
    }
    if got != size {
        bail!("fetched {got} bytes of the {size} the store announced");
    }
    file.sync_all().ok();
    Ok(SpoolFile { _dir: dir, path })
}

/// A reader of a spooled copy, which keeps the copy while it reads.
struct Spooled {
    inner: Box<dyn RowSource>,
    _file: Arc<SpoolFile>,
}

impl std::fmt::Debug for Spooled {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Spooled")
            .field("inner", &self.inner)
            .finish_non_exhaustive()
    }
}

impl RowSource for Spooled {
    fn info(&self) -> &super::super::SourceInfo {
        self.inner.info()
    }
    fn read_rows(&mut self, out: &mut [f32]) -> anyhow::Result<()> {
        self.inner.read_rows(out)
    }
    fn edge_distance(&self) -> Option<&[f32]> {
        self.inner.edge_distance()
    }
    fn skip_rows(&mut self, n: u32) -> anyhow::Result<()> {
        self.inner.skip_rows(n)
    }

    fn set_window(&mut self, columns: &[std::ops::Range<u32>], until: u32) -> anyhow::Result<()> {
        self.inner.set_window(columns, until)
    }

    fn input_windows(&self) -> Vec<(PathBuf, [u32; 4])> {
        self.inner.input_windows()
    }

    fn buffer_bytes(&self) -> u64 {
        self.inner.buffer_bytes()
    }
    fn vertical_datum(&self) -> Option<tessera_shared::VerticalDatum> {
        self.inner.vertical_datum()
    }
    fn datum_clue(&self) -> Option<super::super::DatumClue> {
        self.inner.datum_clue()
    }
}
