//! A `Read + Seek` view of an object in a store, for the GeoTIFF decoder, that fetches
//! what the reader is told it will need (the chunks of the next band of rows, one
//! ranged GET per run of adjacent chunks) and, for the header and anything else it
//! was not told of, a short read-ahead window. Each byte of a chunk is fetched once.

use crate::storage::{ObjectStorage, Storage};
use bytes::Bytes;
use std::io::{self, Read, Seek, SeekFrom};
use std::ops::Range;
use std::sync::{Arc, Mutex, PoisonError};

/// Bytes fetched for a read the reader was not told of (the header's): a COG's first
/// image directory and tag values lie within a few kilobytes of the start (GDAL
/// writes them first), and what follows them is overview data, so windows start
/// small; a miss right where the last window ended doubles it (a long tag array read
/// in pieces).
pub const READ_AHEAD: u64 = 512;

/// The largest read-ahead window.
const MAX_READ_AHEAD: u64 = 1 << 20;

/// Read-ahead windows kept besides the band: the header's reads come back to the
/// first one (tag values stored out of line), and few others are ever needed.
const KEPT_WINDOWS: usize = 4;

#[derive(Debug, Default)]
struct Windows {
    /// The current band's chunks, as fetched runs `(start, bytes)`.
    band: Vec<(u64, Bytes)>,
    /// Read-ahead windows, oldest first.
    ahead: Vec<(u64, Bytes)>,
}

impl Windows {
    /// The window to fetch for a read of `len` bytes at `pos` that no window holds.
    fn next_window(&self, pos: u64, len: u64) -> u64 {
        let grown = self
            .ahead
            .last()
            .filter(|(at, b)| at + b.len() as u64 == pos)
            .map_or(READ_AHEAD, |(_, b)| {
                (2 * b.len() as u64).min(MAX_READ_AHEAD)
            });
        len.max(grown)
    }
}

impl Windows {
    fn find(&self, pos: u64) -> Option<(u64, Bytes)> {
        self.band
            .iter()
            .chain(self.ahead.iter().rev())
            .find(|(at, b)| *at <= pos && pos < at + b.len() as u64)
            .cloned()
    }

    fn held(&self) -> u64 {
        self.band
            .iter()
            .chain(&self.ahead)
            .map(|(_, b)| b.len() as u64)
            .sum()
    }
}

/// A store error without the `URL: ` the store puts first: the build names the
/// input once, around every error of it.
pub fn without_url(url: &str, e: io::Error) -> io::Error {
    let text = e.to_string();
    match text.strip_prefix(url).and_then(|t| t.strip_prefix(": ")) {
        Some(rest) => io::Error::new(e.kind(), rest.to_string()),
        None => e,
    }
}

/// The reader the decoder owns.
#[derive(Debug)]
pub struct RangeReader {
    storage: Arc<ObjectStorage>,
    pos: u64,
    windows: Arc<Mutex<Windows>>,
}

/// The next band's runs, being fetched in the background.
type Pending = (
    Vec<Range<u64>>,
    std::sync::mpsc::Receiver<io::Result<Vec<(u64, Bytes)>>>,
);

/// The handle the GeoTIFF reader keeps to say which chunks come next
/// ([`Prefetch::band`], [`Prefetch::ahead`]).
#[derive(Debug)]
pub struct Prefetch {
    storage: Arc<ObjectStorage>,
    windows: Arc<Mutex<Windows>>,
    pending: Mutex<Option<Pending>>,
}

/// Runs of adjacent ranges (empty ones left out), in file order.
fn runs(chunks: &[Range<u64>]) -> Vec<Range<u64>> {
    let mut sorted: Vec<Range<u64>> = chunks.iter().filter(|r| r.end > r.start).cloned().collect();
    sorted.sort_by_key(|r| r.start);
    let mut runs: Vec<Range<u64>> = Vec::new();
    for r in sorted {
        match runs.last_mut() {
            Some(last) if r.start <= last.end => last.end = last.end.max(r.end),
            _ => runs.push(r),
        }
    }
    runs
}

/// A reader over `storage` and the handle that fills it ahead of the decoder;
/// `known` are windows of the object fetched before (its header, by an earlier
/// opening).
pub fn range_reader(
    storage: Arc<ObjectStorage>,
    known: Vec<(u64, Bytes)>,
) -> (RangeReader, Prefetch) {
    let windows = Arc::new(Mutex::new(Windows {
        band: Vec::new(),
        ahead: known,
    }));
    (
        RangeReader {
            storage: storage.clone(),
            pos: 0,
            windows: windows.clone(),
        },
        Prefetch {
            storage,
            windows,
            pending: Mutex::new(None),
        },
    )
}

impl Prefetch {
    /// Fetches `chunks` (byte ranges, in any order; empty ones are skipped), one GET
    /// per run of adjacent ranges, replacing the previous band's; taken from the
    /// background fetch [`Prefetch::ahead`] started when it asked for the same.
    pub fn band(&self, chunks: &[Range<u64>]) -> io::Result<()> {
        let runs = runs(chunks);
        // The old band goes first, so at most this band and the next are held.
        self.windows
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .band
            .clear();
        let pending = self
            .pending
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .take();
        let band = match pending {
            Some((asked, rx)) if asked == runs => rx.recv().unwrap_or_else(|_| {
                Err(io::Error::other(
                    "the background fetch of a band was dropped",
                ))
            }),
            _ => {
                let mut band = Vec::with_capacity(runs.len());
                for r in runs {
                    let bytes = self
                        .storage
                        .slice(r.start, r.end - r.start)
                        .map_err(|e| without_url(self.storage.url(), e))?;
                    band.push((r.start, bytes));
                }
                Ok(band)
            }
        }?;
        self.windows
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .band = band;
        Ok(())
    }

    /// Starts fetching `chunks` (the next band's) in the background, so that the
    /// store's latency passes while the current band decodes.
    pub fn ahead(&self, chunks: &[Range<u64>]) {
        let runs = runs(chunks);
        let (tx, rx) = std::sync::mpsc::sync_channel(1);
        let storage = self.storage.clone();
        let asked = runs.clone();
        crate::storage::runtime::io_runtime().spawn(async move {
            let mut band = Vec::with_capacity(asked.len());
            for r in asked {
                match storage.read(r.start, r.end - r.start).await {
                    Ok(bytes) => band.push((r.start, bytes)),
                    Err(e) => {
                        let _ = tx.send(Err(without_url(storage.url(), e)));
                        return;
                    }
                }
            }
            let _ = tx.send(Ok(band));
        });
        *self.pending.lock().unwrap_or_else(PoisonError::into_inner) = Some((runs, rx));
    }

    /// The read-ahead windows fetched so far (the header's, once the file is open).
    pub fn header_windows(&self) -> Vec<(u64, Bytes)> {
        self.windows
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .ahead
            .clone()
    }

    /// Bytes held for the decoder now.
    pub fn held(&self) -> u64 {
        self.windows
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .held()
    }
}

impl Read for RangeReader {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let size = self.storage.size();
        if buf.is_empty() || self.pos >= size {
            return Ok(0);
        }
        let found = self
            .windows
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .find(self.pos);
        let (at, bytes) = if let Some(w) = found {
            w
        } else {
            let len = self
                .windows
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .next_window(self.pos, buf.len() as u64)
                .min(size - self.pos);
            let bytes = self
                .storage
                .slice(self.pos, len)
                .map_err(|e| without_url(self.storage.url(), e))?;
            let mut w = self.windows.lock().unwrap_or_else(PoisonError::into_inner);
            if w.ahead.len() == KEPT_WINDOWS {
                w.ahead.remove(0);
            }
            w.ahead.push((self.pos, bytes.clone()));
            (self.pos, bytes)
        };
        let from = (self.pos - at) as usize;
        let n = (bytes.len() - from).min(buf.len());
        buf[..n].copy_from_slice(&bytes[from..from + n]);
        self.pos += n as u64;
        Ok(n)
    }
}

impl Seek for RangeReader {
    fn seek(&mut self, to: SeekFrom) -> io::Result<u64> {
        let size = self.storage.size();
        let pos = match to {
            SeekFrom::Start(p) => Some(p),
            SeekFrom::End(d) => size.checked_add_signed(d),
            SeekFrom::Current(d) => self.pos.checked_add_signed(d),
        }
        .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "seek before the start"))?;
        self.pos = pos;
        Ok(pos)
    }
}
