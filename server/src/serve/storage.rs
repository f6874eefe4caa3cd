//! Where pyramid bytes come from, behind one small trait so object storage can be
//! added without touching the routes (DESIGN §4).

use bytes::Bytes;
use futures_util::future::BoxFuture;
use std::io;
use std::path::Path;
use std::sync::Arc;
use std::time::SystemTime;
use tessera_shared::ByteSource;

/// A pyramid file's bytes, answered by range.
pub trait Storage: Send + Sync + std::fmt::Debug + 'static {
    /// Total length in bytes, as it was when the storage was opened.
    fn size(&self) -> u64;
    /// Bytes `offset..offset + len`; an error if they cannot all be read.
    fn slice(&self, offset: u64, len: u64) -> io::Result<Bytes>;
    /// `Err` naming what changed if the bytes may no longer be the ones opened
    /// (a file truncated or rewritten in place). Cheap: called on every request.
    fn check_unchanged(&self) -> Result<(), String>;
    /// When the bytes were last modified, as it was when the storage was opened
    /// (`Last-Modified`); `None` where unknown.
    fn modified(&self) -> Option<SystemTime> {
        None
    }
    /// [`Storage::slice`] for async callers. The default reads in place: a local
    /// `pread` is brief, and served records are usually in the page cache. Object
    /// storage fetches without blocking the caller's runtime.
    fn read(&self, offset: u64, len: u64) -> BoxFuture<'_, io::Result<Bytes>> {
        Box::pin(std::future::ready(self.slice(offset, len)))
    }
    /// Whether the bytes can be served now (`/healthz/ready`): `Err` with the reason
    /// when the storage is unreachable or no longer what was opened.
    fn ready(&self) -> BoxFuture<'_, Result<(), String>> {
        Box::pin(std::future::ready(self.check_unchanged()))
    }
    /// Where the bytes are, for messages: a path or a URL.
    fn label(&self) -> String;
}

/// A local file read with positional reads (`pread`) on the descriptor opened at
/// start-up.
///
/// Not a memory map: a mapped file that is truncated under the server turns the next
/// read of a vanished page into SIGBUS, which kills the whole process. A `pread` past
/// the new end is an ordinary short read, so only that dataset fails. Holding the
/// descriptor also keeps the old inode readable when a new file is renamed over the
/// path (the safe deploy), until a reload opens the new one.
#[derive(Debug)]
pub struct FileStorage {
    path: std::path::PathBuf,
    file: std::fs::File,
    size: u64,
    modified: Option<SystemTime>,
}

impl FileStorage {
    pub fn open(path: &Path) -> io::Result<Self> {
        let file = std::fs::File::open(path)?;
        let meta = file.metadata()?;
        Ok(Self {
            path: path.to_path_buf(),
            size: meta.len(),
            modified: meta.modified().ok(),
            file,
        })
    }
}

impl Storage for FileStorage {
    fn size(&self) -> u64 {
        self.size
    }

    fn label(&self) -> String {
        self.path.display().to_string()
    }

    fn modified(&self) -> Option<SystemTime> {
        self.modified
    }

    fn slice(&self, offset: u64, len: u64) -> io::Result<Bytes> {
        let past_end = || {
            io::Error::new(
                io::ErrorKind::UnexpectedEof,
                format!(
                    "bytes {offset}+{len} are past the end ({} bytes)",
                    self.size
                ),
            )
        };
        let end = offset.checked_add(len).ok_or_else(past_end)?;
        if end > self.size {
            return Err(past_end());
        }
        let mut buf = vec![0; usize::try_from(len).map_err(|_| past_end())?];
        read_exact_at(&self.file, &mut buf, offset).map_err(|e| {
            if e.kind() == io::ErrorKind::UnexpectedEof {
                io::Error::new(
                    io::ErrorKind::UnexpectedEof,
                    format!(
                        "the file ends before byte {end}: it was truncated after it was opened"
                    ),
                )
            } else {
                e
            }
        })?;
        Ok(Bytes::from(buf))
    }

    fn check_unchanged(&self) -> Result<(), String> {
        let meta = self
            .file
            .metadata()
            .map_err(|e| format!("cannot stat the open file: {e}"))?;
        if meta.len() != self.size {
            return Err(format!(
                "the file changed size under the server ({} bytes when opened, {} now)",
                self.size,
                meta.len()
            ));
        }
        if meta.modified().ok() != self.modified {
            return Err("the file was modified in place after it was opened".to_string());
        }
        Ok(())
    }
}

#[cfg(unix)]
fn read_exact_at(file: &std::fs::File, buf: &mut [u8], offset: u64) -> io::Result<()> {
    std::os::unix::fs::FileExt::read_exact_at(file, buf, offset)
}

#[cfg(windows)]
fn read_exact_at(file: &std::fs::File, mut buf: &mut [u8], mut offset: u64) -> io::Result<()> {
    use std::os::windows::fs::FileExt;
    while !buf.is_empty() {
        match file.seek_read(buf, offset)? {
            0 => return Err(io::ErrorKind::UnexpectedEof.into()),
            n => {
                buf = &mut buf[n..];
                offset += n as u64;
            }
        }
    }
    Ok(())
}

/// Lets the shared pyramid reader parse headers and indices from any [`Storage`].
#[derive(Debug, Clone)]
pub struct StorageSource(pub Arc<dyn Storage>);

impl ByteSource for StorageSource {
    fn size(&self) -> io::Result<u64> {
        Ok(self.0.size())
    }

    fn read_at(&self, offset: u64, buf: &mut [u8]) -> io::Result<()> {
        buf.copy_from_slice(&self.0.slice(offset, buf.len() as u64)?);
        Ok(())
    }
}
