//! Where pyramid bytes come from, behind one small trait so object storage can be
//! added without touching the routes (DESIGN §4).

use bytes::Bytes;
use std::io;
use std::path::Path;
use std::sync::Arc;
use tessera_shared::ByteSource;

/// A pyramid file's bytes, answered by range.
pub trait Storage: Send + Sync + std::fmt::Debug + 'static {
    /// Total length in bytes.
    fn size(&self) -> u64;
    /// Bytes `offset..offset + len`; zero-copy where the backend allows.
    fn slice(&self, offset: u64, len: u64) -> io::Result<Bytes>;
}

/// A local file, memory-mapped: slices are views into the page cache, never copies.
#[derive(Debug)]
pub struct MmapStorage {
    bytes: Bytes,
}

impl MmapStorage {
    pub fn open(path: &Path) -> io::Result<Self> {
        let file = std::fs::File::open(path)?;
        // SAFETY: the mapping is read-only and pyramid files are immutable once
        // written (builds write a temporary file and rename it into place, so a
        // rebuild replaces the directory entry, not the mapped inode). Truncating a
        // served file in place would be an operator error that could fault reads.
        #[allow(unsafe_code)]
        let map = unsafe { memmap2::Mmap::map(&file)? };
        Ok(Self {
            bytes: Bytes::from_owner(map),
        })
    }
}

impl Storage for MmapStorage {
    fn size(&self) -> u64 {
        self.bytes.len() as u64
    }

    fn slice(&self, offset: u64, len: u64) -> io::Result<Bytes> {
        let end = offset.checked_add(len).filter(|e| *e <= self.size());
        match end {
            Some(end) => Ok(self.bytes.slice(offset as usize..end as usize)),
            None => Err(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                format!(
                    "range {offset}+{len} is past the end ({} bytes)",
                    self.size()
                ),
            )),
        }
    }
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
