//! A pyramid in object storage behind the [`Storage`] trait
//! (docs/ARCHITECTURE.md#storage, docs/ARCHITECTURE.md#scale-out).
//!
//! Opened with one HEAD (size, ETag, modification time); the header and the level
//! indices are then read once by the pyramid reader. Every read goes through the
//! shared [`BlockCache`]; what it lacks is fetched as ranged GETs, one per run of
//! missing blocks, all at once, each conditional on the ETag seen at open
//! (`If-Match`), so a replaced object can never be mixed into a response: the first
//! read that notices marks the dataset changed, and it answers 503 until a reload.
//! The store's client retries 5xx answers, timeouts and broken connections with
//! exponential backoff ([`StoreOptions`]); what still fails is an
//! `io::Error` naming the URL, which the routes turn into a 503 with a JSON reason.

use super::block_cache::{self, BLOCK, BlockCache};
use super::location::{ObjectLocation, StoreOptions};
use super::runtime;
use super::{Storage, StorageUnavailable};
use bytes::Bytes;
use futures_util::future::{BoxFuture, Either};
use object_store::{GetOptions, GetRange, ObjectStoreExt};
use prometheus::{Histogram, HistogramOpts, IntCounter, IntCounterVec, IntGauge, Opts, Registry};
use std::future::Ready;
use std::io;
use std::ops::Range;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

/// What every object-store dataset of a server shares: the block cache, the
/// metrics and the retry settings.
#[derive(Debug)]
pub struct StoreContext {
    pub cache: BlockCache,
    pub metrics: StoreMetrics,
    pub options: StoreOptions,
}

impl StoreContext {
    /// A context whose metrics are registered in `registry`.
    pub fn new(cache_bytes: u64, options: StoreOptions, registry: &Registry) -> Self {
        Self {
            cache: BlockCache::new(cache_bytes),
            metrics: StoreMetrics::new(registry),
            options,
        }
    }
}

/// Object-store metrics (`/metrics`).
#[derive(Debug, Clone)]
pub struct StoreMetrics {
    /// Ranged GETs and HEADs by operation and outcome (`ok`, `error`, `changed`).
    pub requests: IntCounterVec,
    /// Time per GET, first byte to last, retries included.
    pub get_seconds: Histogram,
    pub get_bytes: IntCounter,
    pub cache_hits: IntCounter,
    pub cache_misses: IntCounter,
    pub cache_bytes: IntGauge,
    pub cache_capacity: IntGauge,
}

impl StoreMetrics {
    fn new(registry: &Registry) -> Self {
        let requests = IntCounterVec::new(
            Opts::new(
                "tessera_store_requests_total",
                "Object-store requests by operation (get, head) and outcome (ok, error, changed)",
            ),
            &["op", "outcome"],
        )
        .expect("valid metric");
        let get_seconds = Histogram::with_opts(
            HistogramOpts::new(
                "tessera_store_get_duration_seconds",
                "Time per ranged GET to the object store, retries included",
            )
            .buckets(vec![
                0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0,
            ]),
        )
        .expect("valid metric");
        let get_bytes = IntCounter::new(
            "tessera_store_get_bytes_total",
            "Bytes fetched from the object store",
        )
        .expect("valid metric");
        let cache_hits = IntCounter::new(
            "tessera_block_cache_hits_total",
            "Object-store blocks read from the block cache",
        )
        .expect("valid metric");
        let cache_misses = IntCounter::new(
            "tessera_block_cache_misses_total",
            "Object-store blocks the block cache lacked (fetched from the store)",
        )
        .expect("valid metric");
        let cache_bytes = IntGauge::new(
            "tessera_block_cache_bytes",
            "Bytes held by the object-store block cache",
        )
        .expect("valid metric");
        let cache_capacity = IntGauge::new(
            "tessera_block_cache_capacity_bytes",
            "Capacity of the object-store block cache (--block-cache-mib)",
        )
        .expect("valid metric");
        for c in [
            Box::new(requests.clone()) as Box<dyn prometheus::core::Collector>,
            Box::new(get_seconds.clone()),
            Box::new(get_bytes.clone()),
            Box::new(cache_hits.clone()),
            Box::new(cache_misses.clone()),
            Box::new(cache_bytes.clone()),
            Box::new(cache_capacity.clone()),
        ] {
            registry.register(c).expect("metric names are unique");
        }
        Self {
            requests,
            get_seconds,
            get_bytes,
            cache_hits,
            cache_misses,
            cache_bytes,
            cache_capacity,
        }
    }
}

/// One object, read by range.
#[derive(Debug)]
pub struct ObjectStorage {
    loc: ObjectLocation,
    size: u64,
    etag: Option<String>,
    modified: Option<SystemTime>,
    /// This opening's id in the block cache.
    id: u64,
    ctx: Arc<StoreContext>,
    /// Why the object can no longer be trusted, once a read has found it changed.
    changed: Mutex<Option<String>>,
}

/// A store error as an `io::Error` naming the object.
fn store_error(url: &str, what: &str, e: &object_store::Error) -> io::Error {
    let kind = match e {
        object_store::Error::NotFound { .. } => io::ErrorKind::NotFound,
        object_store::Error::Precondition { .. } => io::ErrorKind::InvalidData,
        _ => io::ErrorKind::Other,
    };
    io::Error::new(kind, format!("{url}: {what}: {e}"))
}

impl ObjectStorage {
    /// HEADs the object (blocking: servers open datasets at start-up and on reload).
    pub fn open(loc: ObjectLocation, ctx: Arc<StoreContext>) -> io::Result<Self> {
        let (store, key, url) = (loc.store.clone(), loc.key.clone(), loc.url.clone());
        let head = runtime::block_on(async move { store.head(&key).await });
        let meta = head.map_err(|e| {
            ctx.metrics
                .requests
                .with_label_values(&["head", "error"])
                .inc();
            store_error(&url, "cannot open the object", &e)
        })?;
        ctx.metrics
            .requests
            .with_label_values(&["head", "ok"])
            .inc();
        ctx.metrics
            .cache_capacity
            .set(i64::try_from(ctx.cache.capacity()).unwrap_or(i64::MAX));
        Ok(Self {
            size: meta.size,
            etag: meta.e_tag,
            modified: Some(SystemTime::from(meta.last_modified)),
            id: ctx.cache.object_id(),
            loc,
            ctx,
            changed: Mutex::new(None),
        })
    }

    pub fn url(&self) -> &str {
        &self.loc.url
    }

    /// The ETag seen at open, which every read must match.
    pub fn etag(&self) -> Option<&str> {
        self.etag.as_deref()
    }

    fn mark_changed(&self, why: String) {
        let mut c = self
            .changed
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if c.is_none() {
            tracing::error!(url = %self.loc.url, "{why}");
            *c = Some(why);
        }
    }

    /// One ranged GET of `range`, conditional on the ETag seen at open.
    fn get(
        &self,
        range: Range<u64>,
    ) -> impl Future<Output = io::Result<(u64, Bytes)>> + Send + 'static {
        let (store, key, url) = (
            self.loc.store.clone(),
            self.loc.key.clone(),
            self.loc.url.clone(),
        );
        let options = GetOptions {
            range: Some(GetRange::Bounded(range.clone())),
            if_match: self.etag.clone(),
            ..GetOptions::default()
        };
        let (metrics, size) = (self.ctx.metrics.clone(), self.size);
        async move {
            let started = Instant::now();
            let got = async {
                let r = store.get_opts(&key, options).await?;
                let object_size = r.meta.size;
                Ok::<_, object_store::Error>((object_size, r.bytes().await?))
            }
            .await;
            metrics.get_seconds.observe(started.elapsed().as_secs_f64());
            match got {
                Ok((object_size, bytes)) => {
                    if object_size != size {
                        metrics
                            .requests
                            .with_label_values(&["get", "changed"])
                            .inc();
                        return Err(io::Error::new(
                            io::ErrorKind::InvalidData,
                            format!(
                                "{url}: the object changed in the store after it was opened \
                                 ({size} bytes then, {object_size} now)"
                            ),
                        ));
                    }
                    if bytes.len() as u64 != range.end - range.start {
                        metrics.requests.with_label_values(&["get", "error"]).inc();
                        return Err(io::Error::new(
                            io::ErrorKind::UnexpectedEof,
                            format!(
                                "{url}: asked for bytes {}..{}, the store sent {}",
                                range.start,
                                range.end,
                                bytes.len()
                            ),
                        ));
                    }
                    metrics.requests.with_label_values(&["get", "ok"]).inc();
                    metrics.get_bytes.inc_by(bytes.len() as u64);
                    Ok((range.start, bytes))
                }
                Err(e @ object_store::Error::Precondition { .. }) => {
                    metrics
                        .requests
                        .with_label_values(&["get", "changed"])
                        .inc();
                    Err(store_error(
                        &url,
                        "the object changed in the store after it was opened (its ETag no longer matches)",
                        &e,
                    ))
                }
                Err(e) => {
                    metrics.requests.with_label_values(&["get", "error"]).inc();
                    Err(store_error(&url, "the object store failed", &e))
                }
            }
        }
    }

    /// Bytes `offset..offset + len`: cached blocks, and the rest fetched at once.
    fn read_range(
        &self,
        offset: u64,
        len: u64,
    ) -> io::Result<
        Either<Ready<io::Result<Bytes>>, impl Future<Output = io::Result<Bytes>> + Send + 'static>,
    > {
        let range = offset
            .checked_add(len)
            .filter(|&end| end <= self.size)
            .map(|end| offset..end)
            .ok_or_else(|| {
                io::Error::new(
                    io::ErrorKind::UnexpectedEof,
                    format!(
                        "{}: bytes {offset}+{len} are past the end ({} bytes)",
                        self.loc.url, self.size
                    ),
                )
            })?;
        if let Some(why) = self
            .changed
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
        {
            return Err(io::Error::new(io::ErrorKind::InvalidData, why));
        }
        let plan = self.ctx.cache.plan(self.id, self.size, &range);
        let m = &self.ctx.metrics;
        m.cache_hits.inc_by(plan.cached.len() as u64);
        let missing: u64 = plan
            .fetch
            .iter()
            .map(|r| (r.end - r.start).div_ceil(BLOCK))
            .sum();
        m.cache_misses.inc_by(missing);
        let gets: Vec<_> = plan.fetch.iter().map(|r| self.get(r.clone())).collect();
        let cached: Vec<(u64, Bytes)> = plan
            .cached
            .into_iter()
            .map(|(b, bytes)| (b * BLOCK, bytes))
            .collect();
        let uncovered = move |range: &Range<u64>| {
            io::Error::other(format!("bytes {}..{} not covered", range.start, range.end))
        };
        if gets.is_empty() {
            // All cached: answered here, without a trip through the I/O runtime.
            let bytes = block_cache::assemble(&range, cached).ok_or_else(|| uncovered(&range));
            return Ok(Either::Left(std::future::ready(bytes)));
        }
        let (ctx, id) = (self.ctx.clone(), self.id);
        Ok(Either::Right(async move {
            let fetched = futures_util::future::join_all(gets).await;
            let mut pieces = cached;
            for f in fetched {
                let (at, bytes) = f?;
                // Fetched runs are block-aligned (the cache plans them so).
                ctx.cache.insert(id, at, &bytes);
                pieces.push((at, bytes));
            }
            block_cache::assemble(&range, pieces).ok_or_else(|| uncovered(&range))
        }))
    }

    /// Marks the object changed when that is why a read failed.
    fn settle(&self, result: io::Result<Bytes>) -> io::Result<Bytes> {
        if let Err(e) = &result
            && e.kind() == io::ErrorKind::InvalidData
        {
            self.mark_changed(e.to_string());
        }
        self.ctx
            .metrics
            .cache_bytes
            .set(i64::try_from(self.ctx.cache.bytes()).unwrap_or(i64::MAX));
        result
    }
}

impl Storage for ObjectStorage {
    fn size(&self) -> u64 {
        self.size
    }

    fn modified(&self) -> Option<SystemTime> {
        self.modified
    }

    fn slice(&self, offset: u64, len: u64) -> io::Result<Bytes> {
        let got = match self.read_range(offset, len)? {
            Either::Left(cached) => cached.into_inner(),
            Either::Right(fetch) => runtime::block_on(fetch),
        };
        self.settle(got)
    }

    fn read(&self, offset: u64, len: u64) -> BoxFuture<'_, io::Result<Bytes>> {
        Box::pin(async move {
            let got = match self.read_range(offset, len)? {
                Either::Left(cached) => cached.into_inner(),
                Either::Right(fetch) => runtime::run(fetch).await,
            };
            self.settle(got)
        })
    }

    fn check_unchanged(&self) -> Result<(), StorageUnavailable> {
        match &*self
            .changed
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
        {
            Some(why) => Err(StorageUnavailable::ObjectChanged(why.clone())),
            None => Ok(()),
        }
    }

    fn ready(&self) -> BoxFuture<'_, Result<(), StorageUnavailable>> {
        Box::pin(async move {
            self.check_unchanged()?;
            let (store, key, url) = (
                self.loc.store.clone(),
                self.loc.key.clone(),
                self.loc.url.clone(),
            );
            let head = runtime::run(async move {
                tokio::time::timeout(Duration::from_secs(2), store.head(&key)).await
            })
            .await;
            let m = &self.ctx.metrics.requests;
            match head {
                Ok(Ok(meta)) if meta.e_tag == self.etag && meta.size == self.size => {
                    m.with_label_values(&["head", "ok"]).inc();
                    Ok(())
                }
                Ok(Ok(_)) => {
                    m.with_label_values(&["head", "changed"]).inc();
                    Err(StorageUnavailable::ChangedInStore { url })
                }
                Ok(Err(e)) => {
                    m.with_label_values(&["head", "error"]).inc();
                    Err(StorageUnavailable::StoreNotAnswering { url, source: e })
                }
                Err(_) => {
                    m.with_label_values(&["head", "error"]).inc();
                    Err(StorageUnavailable::HeadTimeout { url })
                }
            }
        })
    }

    fn label(&self) -> String {
        self.loc.url.clone()
    }
}
