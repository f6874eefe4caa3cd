//! Where pyramid bytes come from, behind one small trait so the routes read a local
//! file and an object in a store alike (docs/ARCHITECTURE.md#storage).
//!
//! - [`Storage`]: a pyramid's bytes, answered by range; [`StorageSource`] adapts it to
//!   the shared pyramid reader.
//! - [`local`]: a local file ([`FileStorage`]).
//! - [`object`]: an object in S3, GCS, Azure or behind plain HTTP(S) ([`ObjectStorage`]),
//!   read through the shared [`block_cache`]; [`location`] tells a path from an object
//!   URL and builds the store for it; every store request runs on the [`runtime`].
//! - [`upload`]: `build … -o s3://…`, a finished pyramid to its object.

pub mod block_cache;
pub mod local;
pub mod location;
pub mod object;
pub mod runtime;
pub mod upload;

pub use local::FileStorage;
pub use location::{Location, ObjectLocation, StoreOptions, is_url, locate, object_at};
pub use object::{ObjectStorage, StoreContext};

use bytes::Bytes;
use futures_util::future::BoxFuture;
use std::io;
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
    fn check_unchanged(&self) -> Result<(), StorageUnavailable>;
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
    /// Whether [`Storage::framed`] is a cheap local read, made while a response is
    /// being written: then a range stream reads each record as hyper asks for it
    /// instead of all of them up front. Object storage fetches each range once, up
    /// front (one GET), so it says no.
    fn reads_while_writing(&self) -> bool {
        false
    }
    /// `head` followed by bytes `offset..offset + len`, in one buffer: a frame of a
    /// range stream (its header, then the stored record). The default copies what
    /// [`Storage::slice`] read; a storage that reads while writing reads in place.
    fn framed(&self, head: &[u8], offset: u64, len: u64) -> io::Result<Bytes> {
        let body = self.slice(offset, len)?;
        let mut buf = Vec::with_capacity(head.len() + body.len());
        buf.extend_from_slice(head);
        buf.extend_from_slice(&body);
        Ok(Bytes::from(buf))
    }
    /// Whether the bytes can be served now (`/healthz/ready`): `Err` with the reason
    /// when the storage is unreachable or no longer what was opened.
    fn ready(&self) -> BoxFuture<'_, Result<(), StorageUnavailable>> {
        Box::pin(std::future::ready(self.check_unchanged()))
    }
    /// Where the bytes are, for messages: a path or a URL.
    fn label(&self) -> String;
}

/// Why a storage's bytes cannot be served now ([`Storage::check_unchanged`],
/// [`Storage::ready`]).
#[derive(Debug, thiserror::Error)]
pub enum StorageUnavailable {
    /// A local file's metadata cannot be read.
    #[error("cannot stat the open file: {0}")]
    Stat(#[source] io::Error),
    /// A local file is no longer the length it was when opened.
    #[error("the file changed size under the server ({opened} bytes when opened, {now} now)")]
    Resized { opened: u64, now: u64 },
    /// A local file's modification time moved.
    #[error("the file was modified in place after it was opened")]
    ModifiedInPlace,
    /// A read found the object changed in the store; the reason that read gave.
    #[error("{0}")]
    ObjectChanged(String),
    /// A HEAD found the object changed in the store.
    #[error("{url}: the object changed in the store after it was opened; reload (SIGHUP)")]
    ChangedInStore { url: String },
    /// The store answered a HEAD with an error.
    #[error("{url}: the object store is not answering: {source}")]
    StoreNotAnswering {
        url: String,
        source: object_store::Error,
    },
    /// The store did not answer a HEAD in time.
    #[error("{url}: the object store did not answer a HEAD within 2 s")]
    HeadTimeout { url: String },
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
