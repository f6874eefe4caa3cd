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

mod listing;
mod reader;
mod spool;

use crate::storage::{ObjectStorage, Storage, StoreContext, StoreOptions, is_url, object_at};
use anyhow::{Context, bail};
use std::path::Path;
use std::sync::{Arc, OnceLock};

pub use listing::expand;
use reader::without_url;
pub use reader::{Prefetch, READ_AHEAD, RangeReader};
pub use spool::SpoolScope;

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

/// What build inputs have fetched from stores so far in this process.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Fetched {
    /// Bytes of ranged GETs (tiled GeoTIFFs, headers, VRTs).
    pub ranged: u64,
    /// Bytes of objects fetched whole into a spool.
    pub spooled: u64,
}

impl Fetched {
    /// What was fetched after `before` was taken.
    pub fn since(self, before: Fetched) -> Fetched {
        Fetched {
            ranged: self.ranged - before.ranged,
            spooled: self.spooled - before.spooled,
        }
    }

    pub fn total(self) -> u64 {
        self.ranged + self.spooled
    }
}

/// The bytes fetched so far; a build reports the difference over its run.
pub fn fetched() -> Fetched {
    Fetched {
        ranged: context().metrics.get_bytes.get(),
        spooled: spool::SPOOLED.load(std::sync::atomic::Ordering::Relaxed),
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
    let old = seen.by_url.insert(
        url.to_string(),
        Seen {
            etag: object.etag().map(str::to_string),
            size: object.size(),
            windows,
        },
    );
    match old {
        Some(old) if !old.windows.is_empty() => {
            seen.bytes -= old.windows.iter().map(|(_, b)| b.len() as u64).sum::<u64>();
        }
        // New, or its bytes were let go (it left the order then): in line to go again.
        _ => seen.order.push_back(url.to_string()),
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

/// The size and ETag an earlier opening of `url` saw, if it was opened.
pub fn identity(url: &str) -> Option<(u64, Option<String>)> {
    let seen = seen()
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    seen.by_url.get(url).map(|s| (s.size, s.etag.clone()))
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
    spool::open(url, &object)
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
    use std::path::PathBuf;

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
