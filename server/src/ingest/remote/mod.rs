//! Build inputs in object storage or on HTTP servers (DECISIONS.md "Inputs in object
//! storage"): `s3://…`, `gs://…`, `az://…` and `http(s)://…` URLs, named as arguments,
//! in `--inputs` lists and in VRTs, carried through the build as paths whose text is
//! the URL (so a piece's name, and the pyramid, are what the same file on local disk
//! gives).
//!
//! - A tiled GeoTIFF (a COG) is read in place: the header through a short read-ahead,
//!   then, band by band, exactly the byte ranges of the tiles that band needs, one
//!   ranged GET per run of adjacent tiles (`reader.rs`). Overviews are never read.
//! - Anything else (a striped GeoTIFF, `.hgt`, PNG) is fetched whole once into a
//!   folder under TMPDIR, and read from there; the log says so, and one that would not
//!   fit in TMPDIR's free space is refused before a byte is fetched.
//! - Every request is conditional on the ETag seen when the object was opened, and
//!   retried with backoff (`storage::location`): an object changed mid-build, or
//!   missing, is an error naming its URL.

mod reader;

use crate::storage::{ObjectStorage, Storage, StoreContext, StoreOptions, is_url, object_at};
use anyhow::{Context, bail};
use futures_util::StreamExt;
use object_store::{GetOptions, ObjectStore};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};

use reader::without_url;
pub use reader::{Prefetch, READ_AHEAD, RangeReader};

/// The URL an input path stands for, when it is one.
pub fn url_of(path: &Path) -> Option<&str> {
    path.to_str().filter(|s| is_url(s))
}

/// The store context of build inputs: no block cache (each chunk is fetched once, as
/// its band needs it), the same retries as the server's stores, and metrics of its
/// own (what [`fetched`] reports).
fn context() -> &'static Arc<StoreContext> {
    static CTX: OnceLock<Arc<StoreContext>> = OnceLock::new();
    CTX.get_or_init(|| {
        Arc::new(StoreContext::new(
            0,
            StoreOptions::default(),
            &prometheus::Registry::new(),
        ))
    })
}

/// Bytes fetched whole into spools (ranged reads are counted by the context).
static SPOOLED: AtomicU64 = AtomicU64::new(0);

/// What build inputs have fetched from stores so far in this process.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Fetched {
    /// Bytes of ranged GETs (tiled GeoTIFFs, headers, VRTs).
    pub ranged: u64,
    /// Bytes of objects fetched whole into a spool.
    pub spooled: u64,
}

impl Fetched {
    pub fn total(self) -> u64 {
        self.ranged + self.spooled
    }
}

/// The bytes fetched so far; a build reports the difference over its run.
pub fn fetched() -> Fetched {
    Fetched {
        ranged: context().metrics.get_bytes.get(),
        spooled: SPOOLED.load(Ordering::Relaxed),
    }
}

/// Opens the object `url` names (a HEAD: its size and ETag, which every later read
/// must match). Errors do not repeat the URL: callers name the input.
fn open_object(url: &str) -> anyhow::Result<Arc<ObjectStorage>> {
    let loc = object_at(url, StoreOptions::default())
        .map_err(|e| anyhow::anyhow!(without_url(url, std::io::Error::other(e.to_string()))))?;
    let storage = ObjectStorage::open(loc, context().clone()).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            anyhow::anyhow!("no such object in the store")
        } else {
            anyhow::anyhow!(without_url(url, e))
        }
    })?;
    Ok(Arc::new(storage))
}

/// The text of a small object (a VRT), refusing one over `limit` bytes.
pub fn read_text(url: &str, limit: u64, what: &str) -> anyhow::Result<String> {
    let o = open_object(url)?;
    if o.size() > limit {
        bail!(
            "{} bytes is too large for {what} (at most {} MiB)",
            o.size(),
            limit >> 20
        );
    }
    let bytes = o.slice(0, o.size()).map_err(|e| without_url(url, e))?;
    String::from_utf8(bytes.to_vec()).with_context(|| format!("{what} is not UTF-8 text"))
}

/// Whether a key names a DEM file by its extension.
fn is_dem_key(key: &str) -> bool {
    Path::new(key)
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| {
            super::DEM_EXTENSIONS
                .iter()
                .any(|d| e.eq_ignore_ascii_case(d))
        })
}

/// Expands an input URL: a prefix ending in `/` lists the DEM files directly under it
/// (as a folder does), a key with `*`, `?` or `[` lists those matching it (a `*` does
/// not cross `/`), anything else is one object (opening it says whether it exists).
/// Keys are taken in byte order, as files of a folder are.
pub fn expand(url: &str) -> anyhow::Result<Vec<PathBuf>> {
    let wildcard = url.find(['*', '?', '[']);
    let folder = url.ends_with('/');
    if wildcard.is_none() && !folder {
        return Ok(vec![PathBuf::from(url)]);
    }
    if url.starts_with("http://") || url.starts_with("https://") {
        bail!(
            "{url}: an HTTP server cannot be listed; name each file, or list their URLs in a file \
             given with --inputs"
        );
    }
    // The folder that is listed: up to the last `/` before any wildcard.
    let cut = wildcard.unwrap_or(url.len());
    let slash = url[..cut].rfind('/').map_or(0, |i| i + 1);
    let (prefix_url, rest) = url.split_at(slash);
    let loc = object_at(prefix_url, StoreOptions::default())?;
    let prefix = loc.key.clone();
    let pattern = if rest.is_empty() {
        None
    } else {
        let full = if prefix.as_ref().is_empty() {
            rest.to_string()
        } else {
            format!("{}/{rest}", prefix.as_ref())
        };
        Some(
            glob::Pattern::new(&full)
                .with_context(|| format!("{url}: not a valid glob pattern"))?,
        )
    };
    let (store, recursive) = (loc.store.clone(), pattern.is_some());
    let listed: Result<Vec<String>, object_store::Error> =
        crate::storage::runtime::block_on(async move {
            let p = (!prefix.as_ref().is_empty()).then_some(prefix);
            let mut keys = Vec::new();
            if recursive {
                let mut s = store.list(p.as_ref());
                while let Some(o) = s.next().await {
                    keys.push(o?.location.to_string());
                }
            } else {
                // One level, as a folder.
                let l = store.list_with_delimiter(p.as_ref()).await?;
                keys.extend(l.objects.into_iter().map(|o| o.location.to_string()));
            }
            Ok(keys)
        });
    let listed = listed.map_err(|e| anyhow::anyhow!("{url}: cannot list the store: {e}"))?;
    let options = glob::MatchOptions {
        require_literal_separator: true,
        ..glob::MatchOptions::default()
    };
    let mut keys: Vec<String> = listed
        .into_iter()
        .filter(|k| match &pattern {
            Some(p) => p.matches_with(k, options),
            None => is_dem_key(k),
        })
        .collect();
    keys.sort();
    if keys.is_empty() {
        match &pattern {
            Some(_) => bail!("{url}: no object matches this pattern"),
            None => bail!(
                "{url}: the prefix holds no DEM files (.{})",
                super::DEM_EXTENSIONS.join(", .")
            ),
        }
    }
    // Back to URLs: the listed prefix's URL, then the key's part below it.
    let base = loc.key.as_ref().len();
    Ok(keys
        .into_iter()
        .map(|k| {
            let below = k[base..].trim_start_matches('/');
            PathBuf::from(format!("{prefix_url}{below}"))
        })
        .collect())
}

/// What an earlier opening of an object fetched: its ETag and its header's windows.
/// A mosaic opens each input twice (to plan, then to read); the second opening
/// fetches no header again, and an object whose ETag changed in between is an error
/// (it changed during the build).
struct Seen {
    etag: Option<String>,
    size: u64,
    windows: Vec<(u64, bytes::Bytes)>,
}

/// Headers kept, at most (bytes): beyond it the oldest go, and their objects' next
/// opening fetches its header again.
const SEEN_BYTES: u64 = 32 << 20;

#[derive(Default)]
struct SeenObjects {
    by_url: std::collections::HashMap<String, Seen>,
    order: std::collections::VecDeque<String>,
    bytes: u64,
}

fn seen() -> &'static std::sync::Mutex<SeenObjects> {
    static SEEN: OnceLock<std::sync::Mutex<SeenObjects>> = OnceLock::new();
    SEEN.get_or_init(Default::default)
}

/// Checks `object` against an earlier opening; the header windows it fetched.
fn recall(url: &str, object: &ObjectStorage) -> anyhow::Result<Vec<(u64, bytes::Bytes)>> {
    let seen = seen()
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    match seen.by_url.get(url) {
        Some(s) if s.etag.as_deref() != object.etag() || s.size != object.size() => bail!(
            "the object changed in the store during the build ({} bytes, ETag {:?} when first \
             opened; {} bytes, ETag {:?} now)",
            s.size,
            s.etag,
            object.size(),
            object.etag()
        ),
        Some(s) => Ok(s.windows.clone()),
        None => Ok(Vec::new()),
    }
}

fn remember(url: &str, object: &ObjectStorage, windows: Vec<(u64, bytes::Bytes)>) {
    let mut seen = seen()
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let bytes: u64 = windows.iter().map(|(_, b)| b.len() as u64).sum();
    if let Some(old) = seen.by_url.insert(
        url.to_string(),
        Seen {
            etag: object.etag().map(str::to_string),
            size: object.size(),
            windows,
        },
    ) {
        seen.bytes -= old.windows.iter().map(|(_, b)| b.len() as u64).sum::<u64>();
    } else {
        seen.order.push_back(url.to_string());
    }
    seen.bytes += bytes;
    while seen.bytes > SEEN_BYTES
        && let Some(oldest) = seen.order.pop_front()
    {
        if let Some(old) = seen.by_url.get_mut(&oldest) {
            // The ETag stays known; only the bytes go.
            let freed: u64 = old.windows.iter().map(|(_, b)| b.len() as u64).sum();
            old.windows.clear();
            seen.bytes -= freed;
        }
    }
}

/// Opens a raster input at `url`: a tiled GeoTIFF in place, anything else from a
/// spool. Errors name the URL.
pub fn open_raster(url: &str) -> anyhow::Result<(Box<dyn super::RowSource>, &'static str)> {
    let object = open_object(url)?;
    if object.size() == 0 {
        bail!("input object is empty");
    }
    let known = recall(url, &object)?;
    // The signature from the header's first window (fetched once for both openings).
    let (reader, prefetch) = reader::range_reader(object.clone(), known);
    let mut magic = [0u8; 4];
    let n = std::io::Read::read(&mut { reader }, &mut magic).map_err(|e| without_url(url, e))?;
    let tiff = [b"II*\0", b"MM\0*", b"II+\0", b"MM\0+"]
        .iter()
        .any(|m| &magic[..n] == m.as_slice());
    let known = prefetch.header_windows();
    // Remembered whatever the format: a later opening checks the ETag against it.
    remember(url, &object, known.clone());
    if tiff {
        let (reader, prefetch) = reader::range_reader(object.clone(), known);
        let mut t = super::geotiff::GeoTiff::from_reader(reader)?;
        remember(url, &object, prefetch.header_windows());
        if t.is_tiled() {
            t.set_prefetch(Box::new(prefetch));
            t.set_datum_from_name(Path::new(url));
            return Ok((Box::new(t), "GeoTIFF"));
        }
        tracing::info!(
            input = url,
            bytes = object.size(),
            "not a tiled GeoTIFF: fetching it whole into a spool"
        );
    } else {
        tracing::info!(
            input = url,
            bytes = object.size(),
            "not a GeoTIFF: fetching it whole into a spool"
        );
    }
    let spooled = spooled(url, &object)?;
    let (inner, format) = super::open_raster(&spooled.path)?;
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
    inner: Box<dyn super::RowSource>,
    _file: Arc<SpoolFile>,
}

impl std::fmt::Debug for Spooled {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Spooled")
            .field("inner", &self.inner)
            .finish_non_exhaustive()
    }
}

impl super::geotiff::ChunkFetch for Prefetch {
    fn band(&self, chunks: &[std::ops::Range<u64>]) -> std::io::Result<()> {
        Prefetch::band(self, chunks)
    }

    fn ahead(&self, chunks: &[std::ops::Range<u64>]) {
        Prefetch::ahead(self, chunks);
    }

    fn window_bytes(&self) -> u64 {
        4 * READ_AHEAD
    }
}

impl super::RowSource for Spooled {
    fn info(&self) -> &super::SourceInfo {
        self.inner.info()
    }
    fn read_rows(&mut self, out: &mut [f32]) -> anyhow::Result<()> {
        self.inner.read_rows(out)
    }
    fn edge_distance(&self) -> Option<&[f32]> {
        self.inner.edge_distance()
    }
    fn buffer_bytes(&self) -> u64 {
        self.inner.buffer_bytes()
    }
    fn vertical_datum(&self) -> Option<tessera_shared::VerticalDatum> {
        self.inner.vertical_datum()
    }
    fn datum_clue(&self) -> Option<super::DatumClue> {
        self.inner.datum_clue()
    }
}

/// GDAL's names for objects in VRTs (`/vsis3/BUCKET/KEY`, `/vsicurl/URL`, …) as URLs;
/// `None` for other paths.
pub fn gdal_vsi_url(name: &str) -> Option<String> {
    for (vsi, scheme) in [
        ("/vsis3/", "s3://"),
        ("/vsigs/", "gs://"),
        ("/vsiaz/", "az://"),
        ("/vsicurl/", ""),
    ] {
        if let Some(rest) = name.strip_prefix(vsi) {
            return Some(format!("{scheme}{rest}"));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gdal_virtual_paths_become_urls() {
        assert_eq!(
            gdal_vsi_url("/vsis3/b/k/x.tif").as_deref(),
            Some("s3://b/k/x.tif")
        );
        assert_eq!(
            gdal_vsi_url("/vsicurl/https://h/x.tif").as_deref(),
            Some("https://h/x.tif")
        );
        assert_eq!(gdal_vsi_url("/vsizip/a.zip/x.tif"), None);
        assert_eq!(gdal_vsi_url("/data/x.tif"), None);
    }

    #[test]
    fn urls_are_told_from_paths_and_http_cannot_be_listed() {
        assert_eq!(url_of(Path::new("s3://b/x.tif")), Some("s3://b/x.tif"));
        assert_eq!(url_of(Path::new("/data/x.tif")), None);
        assert_eq!(
            expand("https://h/x.tif").unwrap(),
            [PathBuf::from("https://h/x.tif")]
        );
        let e = expand("https://h/dem/").unwrap_err().to_string();
        assert!(e.contains("cannot be listed"), "{e}");
        // A URL's file name is the local file's: the pyramid names its pieces alike.
        assert_eq!(
            Path::new("s3://bucket/dem/N46E008.tif")
                .file_name()
                .unwrap(),
            "N46E008.tif"
        );
    }
}
