//! A pyramid in a local file behind the [`Storage`] trait: positional reads on the
//! descriptor opened at start-up, into pooled frame buffers.

use super::{Storage, StorageUnavailable};
use bytes::Bytes;
use std::io;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, PoisonError};
use std::time::SystemTime;

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

    /// `len` as a buffer length, if bytes `offset..offset + len` lie within the file
    /// as it was opened.
    fn checked_len(&self, offset: u64, len: u64) -> io::Result<usize> {
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
        usize::try_from(len).map_err(|_| past_end())
    }

    /// Fills `buf` from `offset`; a short read means the file was truncated.
    fn read_at(&self, buf: &mut [u8], offset: u64) -> io::Result<()> {
        read_exact_at(&self.file, buf, offset).map_err(|e| {
            if e.kind() == io::ErrorKind::UnexpectedEof {
                io::Error::new(
                    io::ErrorKind::UnexpectedEof,
                    format!(
                        "the file ends before byte {}: it was truncated after it was opened",
                        offset + buf.len() as u64
                    ),
                )
            } else {
                e
            }
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
        let mut buf = vec![0; self.checked_len(offset, len)?];
        self.read_at(&mut buf, offset)?;
        Ok(Bytes::from(buf))
    }

    fn reads_while_writing(&self) -> bool {
        true
    }

    /// Into a pooled buffer: a frame is written to the socket and dropped within
    /// moments, so the next frame reuses its (cache-warm) buffer.
    fn framed(&self, head: &[u8], offset: u64, len: u64) -> io::Result<Bytes> {
        let len = self.checked_len(offset, len)?;
        let mut buf = PooledBuf::take(head.len() + len);
        let (h, body) = buf.as_mut().split_at_mut(head.len());
        h.copy_from_slice(head);
        self.read_at(body, offset)?;
        Ok(Bytes::from_owner(buf))
    }

    fn check_unchanged(&self) -> Result<(), StorageUnavailable> {
        let meta = self.file.metadata().map_err(StorageUnavailable::Stat)?;
        if meta.len() != self.size {
            return Err(StorageUnavailable::Resized {
                opened: self.size,
                now: meta.len(),
            });
        }
        if meta.modified().ok() != self.modified {
            return Err(StorageUnavailable::ModifiedInPlace);
        }
        Ok(())
    }
}

/// Pooled buffers are 64 KiB to 64 MiB; other sizes are plain allocations.
const POOL_MIN_LOG2: u32 = 16;
const POOL_MAX_LOG2: u32 = 26;
/// At most this many bytes of free buffers are kept.
const POOL_BYTES: usize = 64 << 20;

/// Frame buffers kept for reuse, by power-of-two size class, last in first out. A
/// frame is handed to hyper, written to the socket and dropped within moments, so
/// the next frame's `pread` lands in a buffer that is still in the CPU's cache and
/// is not cleared first (a fresh `vec![0; n]` is a `memset`). Only free buffers are
/// held, at most [`POOL_BYTES`] in all; a buffer in use belongs to its response.
struct Pool {
    classes: [Mutex<Vec<Vec<u8>>>; (POOL_MAX_LOG2 - POOL_MIN_LOG2 + 1) as usize],
    free_bytes: AtomicUsize,
}

static POOL: Pool = Pool {
    classes: [const { Mutex::new(Vec::new()) }; (POOL_MAX_LOG2 - POOL_MIN_LOG2 + 1) as usize],
    free_bytes: AtomicUsize::new(0),
};

/// The size class of a `len`-byte read: `None` outside the pooled sizes.
fn pool_class(len: usize) -> Option<usize> {
    let log2 = len.max(1).next_power_of_two().trailing_zeros();
    (POOL_MIN_LOG2..=POOL_MAX_LOG2)
        .contains(&log2)
        .then(|| (log2 - POOL_MIN_LOG2) as usize)
}

/// `len` bytes of a pooled buffer; given back to the pool when dropped (when the
/// last `Bytes` view of it goes).
struct PooledBuf {
    buf: Vec<u8>,
    len: usize,
}

impl PooledBuf {
    fn take(len: usize) -> Self {
        let Some(class) = pool_class(len) else {
            return Self {
                buf: vec![0; len],
                len,
            };
        };
        let reused = POOL.classes[class]
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .pop();
        let buf = match reused {
            Some(b) => {
                POOL.free_bytes.fetch_sub(b.len(), Ordering::Relaxed);
                b
            }
            None => vec![0; 1 << (class as u32 + POOL_MIN_LOG2)],
        };
        Self { buf, len }
    }
}

impl AsMut<[u8]> for PooledBuf {
    fn as_mut(&mut self) -> &mut [u8] {
        &mut self.buf[..self.len]
    }
}

impl AsRef<[u8]> for PooledBuf {
    fn as_ref(&self) -> &[u8] {
        &self.buf[..self.len]
    }
}

impl Drop for PooledBuf {
    fn drop(&mut self) {
        let Some(class) = pool_class(self.buf.len()) else {
            return;
        };
        if self.buf.len() != 1 << (class as u32 + POOL_MIN_LOG2) {
            return;
        }
        let size = self.buf.len();
        if POOL.free_bytes.fetch_add(size, Ordering::Relaxed) + size > POOL_BYTES {
            POOL.free_bytes.fetch_sub(size, Ordering::Relaxed);
            return;
        }
        POOL.classes[class]
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .push(std::mem::take(&mut self.buf));
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pooled_buffers_come_back_and_odd_sizes_are_plain() {
        assert_eq!(pool_class(1), None);
        assert_eq!(pool_class(65_536), Some(0));
        assert_eq!(pool_class(65_537), Some(1));
        assert_eq!(pool_class(64 << 20), Some(10));
        assert_eq!(pool_class((64 << 20) + 1), None);
        // A 3 MiB class buffer (4 MiB), given back when dropped and taken again:
        // other tests may share the pool, so look for this very allocation.
        let mut a = PooledBuf::take(3 << 20);
        assert_eq!(a.as_mut().len(), 3 << 20);
        a.as_mut()[0] = 7;
        let ptr = a.buf.as_ptr();
        drop(a);
        let b = PooledBuf::take((3 << 20) + 5);
        assert_eq!(b.as_ref().len(), (3 << 20) + 5);
        assert_eq!(b.buf.as_ptr(), ptr, "the freed buffer is reused first");
        // Small and huge reads are not pooled.
        assert_eq!(PooledBuf::take(100).buf.len(), 100);
    }

    #[test]
    fn a_frame_is_the_head_then_the_bytes_and_a_truncated_file_is_an_error() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("f");
        let data: Vec<u8> = (0..300_000u32).map(|i| (i % 251) as u8).collect();
        std::fs::write(&path, &data).expect("write");
        let s = FileStorage::open(&path).expect("open");
        assert!(s.reads_while_writing());
        let plain = DefaultFramed(FileStorage::open(&path).expect("open"));
        assert!(!plain.reads_while_writing());
        for _ in 0..3 {
            let f = s.framed(b"HEAD", 1000, 200_000).expect("read");
            assert_eq!(&f[..4], b"HEAD");
            assert_eq!(&f[4..], &data[1000..201_000]);
            assert_eq!(f, plain.framed(b"HEAD", 1000, 200_000).expect("read"));
        }
        assert!(s.framed(b"", 299_999, 2).is_err(), "past the end as opened");
        std::fs::OpenOptions::new()
            .write(true)
            .open(&path)
            .expect("open")
            .set_len(150_000)
            .expect("truncate");
        let e = s.framed(b"", 100_000, 100_000).expect_err("truncated");
        assert!(e.to_string().contains("truncated"), "{e}");
    }

    /// A storage that keeps [`Storage::framed`]'s default.
    #[derive(Debug)]
    struct DefaultFramed(FileStorage);

    impl Storage for DefaultFramed {
        fn size(&self) -> u64 {
            self.0.size()
        }
        fn slice(&self, offset: u64, len: u64) -> io::Result<Bytes> {
            self.0.slice(offset, len)
        }
        fn check_unchanged(&self) -> Result<(), StorageUnavailable> {
            Ok(())
        }
        fn label(&self) -> String {
            String::new()
        }
    }
}
