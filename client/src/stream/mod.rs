//! Streaming tiles from a Tessera server, or straight from a pyramid file on a
//! static host (DESIGN §5, §9, Kang §6.1).
//!
//! The frame thread never waits on the network. Each frame it calls
//! [`Streamer::frame`], which
//! 1. accepts finished tiles (already decoded by the fetch tasks) into the
//!    [`pool::TilePool`] until the frame's time budget is spent;
//! 2. cancels requests none of whose tiles are still wanted;
//! 3. requests what the selection needs now (required), coalesced into Morton ranges
//!    per level, up to a cap on requests in flight; and then what the enlarged,
//!    predicted view will need (prefetch), but only while the frame is still within
//!    its budget — prefetch stops when over it (Kang §6.1).
//!
//! Failed requests are retried with exponential backoff per tile; a server that is
//! slow, failing or restarting only delays refinement, while the pool keeps drawing
//! what it has. When a range stream breaks on one tile (a frame that fails its
//! checksum or does not decode, or a stream cut short, which breaks on the first tile
//! still missing), only that tile backs off: the tiles that were to follow it are
//! asked for again after the base delay, without it, so that a tile that always
//! arrives damaged cannot hold back the others batched with it.
//!
//! A record the server reports corrupt (an error frame, or a 500 for a single tile)
//! is retried with the same backoff, since a reload or another replica may serve it
//! whole, and written off only after [`StreamConfig::corrupt_attempts`] reports.
//! Tiles that fail or are written off are marked unavailable in the pool, so that
//! the selection draws their children in their place (DESIGN §8: the client never
//! goes blind); [`Streamer::last_error`] says what happened.
//!
//! Requested tiles the server has no record of — the trailer's outside ranges, or a
//! 404 for a single tile: outside the DEM or, in format v2, wholly no-data — are
//! marked absent in the pool: they are never asked for again, and selection
//! neither waits for them nor counts them as holes.
//!
//! Two backends feed the same streamer ([`TileSource`]): a Tessera server (one
//! request per batch of Morton ranges, `?ranges=`), and a pyramid file read
//! serverlessly with HTTP Range ([`source`]): its index is local, so tiles with no
//! record are absent without a request, and each run of wanted records contiguous in
//! the file (a Morton range, gaps of absent tiles included) is one Range request.
//! A record that fails its index checksum is reported corrupt, as a server's error
//! frame is. Selection, budget, prefetch, retries, cancellation and statistics are
//! the same.

mod fetch;
pub mod pool;
pub mod source;

use crate::select::Wanted;
use anyhow::Context;
use fetch::{Blame, Decoded, Event, fetch, fetch_one, fetch_range};
use pool::TilePool;
use source::StaticFile;
pub use source::TileSource;
use std::collections::{HashMap, HashSet};
use std::sync::{Arc, mpsc};
use std::time::{Duration, Instant};
use tessera_shared::codec::RecordLayout;
use tessera_shared::{Level, Morton, TileGeometry, TileId, api, morton, range_query};

/// Most codes one trailer may mark absent: far more than one request names
/// ([`StreamConfig::max_tiles_per_request`]), so a hostile trailer cannot make the
/// frame thread walk a huge range.
const MAX_ABSENT_PER_TRAILER: usize = 1 << 16;

/// How tiles are requested.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RequestMode {
    /// Morton-range batches per level (`/levels/{l}/tiles?ranges=…`).
    Ranges,
    /// One request per tile (`/tiles/{l}/{x}/{y}`), for comparison.
    Single,
}

/// Streaming settings.
#[derive(Clone, Debug)]
pub struct StreamConfig {
    pub mode: RequestMode,
    pub max_in_flight: usize,
    pub max_tiles_per_request: usize,
    /// Per-frame time for accepting tiles and issuing requests.
    pub budget: Duration,
    pub retry_base: Duration,
    pub retry_max: Duration,
    pub request_timeout: Duration,
    /// Reports of a corrupt record (from the server, not damage in transit) after
    /// which a tile is written off and not asked for again; each report before
    /// that backs it off like any failure.
    pub corrupt_attempts: u32,
}

impl Default for StreamConfig {
    fn default() -> Self {
        Self {
            mode: RequestMode::Ranges,
            max_in_flight: 4,
            max_tiles_per_request: 16,
            budget: Duration::from_millis(4),
            retry_base: Duration::from_millis(100),
            retry_max: Duration::from_secs(4),
            request_timeout: Duration::from_secs(20),
            corrupt_attempts: 4,
        }
    }
}

/// Running totals.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StreamStats {
    pub requests: u64,
    /// Morton ranges those requests asked for (a server request may name several;
    /// a Range request to a static file is one).
    #[serde(default)]
    pub ranges: u64,
    /// Requests answered in full.
    pub responses: u64,
    pub bytes: u64,
    pub tiles: u64,
    pub failures: u64,
    /// Reports of a corrupt record from the server (error frames, 500s).
    pub corrupt: u64,
    /// Tiles written off after [`StreamConfig::corrupt_attempts`] such reports.
    #[serde(default)]
    pub written_off: u64,
    pub cancelled: u64,
}

/// What one frame's streaming work did.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrameWork {
    pub accepted: usize,
    pub issued: usize,
    pub stream_us: f64,
    pub in_flight: usize,
    pub prefetch_skipped: bool,
}

struct Flight {
    tiles: HashSet<TileId>,
    task: tokio::task::JoinHandle<()>,
}

/// Where a streamer's requests go.
enum Backend {
    /// A Tessera server: its root URL, without a trailing `/`, and the dataset.
    Server { url: String, dataset: String },
    /// A pyramid file read with HTTP Range (or from `file://`), its index local.
    Static(Arc<StaticFile>),
}

/// Fetches tiles in the background on its own runtime.
pub struct Streamer {
    _owned: Option<tokio::runtime::Runtime>,
    rt: tokio::runtime::Handle,
    client: reqwest::Client,
    backend: Backend,
    layout: RecordLayout,
    config: StreamConfig,
    tx: mpsc::Sender<Event>,
    rx: mpsc::Receiver<Event>,
    flights: HashMap<u64, Flight>,
    next_id: u64,
    backoff: HashMap<TileId, (u32, Instant)>,
    /// How many times the server has reported each tile's record corrupt.
    corrupt_reports: HashMap<TileId, u32>,
    /// Tiles reported corrupt `corrupt_attempts` times: not asked for again.
    written_off: HashSet<TileId>,
    pub stats: StreamStats,
    pub last_error: Option<String>,
    /// Time from sending each finished request to its last byte.
    pub latencies_ms: Vec<f64>,
}

impl std::fmt::Debug for Streamer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let source = match &self.backend {
            Backend::Server { url, dataset } => format!("{dataset} on {url}"),
            Backend::Static(file) => file.url.clone(),
        };
        f.debug_struct("Streamer")
            .field("source", &source)
            .field("in_flight", &self.flights.len())
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

/// The HTTP client of a streamer. HTTPS goes through rustls with the `ring`
/// provider, installed here once for the process (reqwest has no provider of its
/// own; one installed already serves as well).
fn http_client(timeout: Duration) -> anyhow::Result<reqwest::Client> {
    static PROVIDER: std::sync::Once = std::sync::Once::new();
    PROVIDER.call_once(|| {
        let _ = rustls::crypto::ring::default_provider().install_default();
    });
    Ok(reqwest::Client::builder().timeout(timeout).build()?)
}

fn own_runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?)
}

impl Streamer {
    /// A streamer for dataset `name` on `server` (e.g. `http://127.0.0.1:8080`).
    pub fn new(
        server: &str,
        name: &str,
        layout: RecordLayout,
        config: StreamConfig,
    ) -> anyhow::Result<Self> {
        let rt = own_runtime()?;
        let handle = rt.handle().clone();
        Self::with_runtime(Some(rt), handle, server, name, layout, config)
    }

    /// A streamer for `source`, on `runtime` or one of its own, and the dataset's
    /// document (API.md): from the server's `/v1/datasets/{name}`, or built from a
    /// static file's header as the server would build it. The records' layout comes
    /// from that document.
    pub fn open(
        source: &TileSource,
        config: StreamConfig,
        runtime: Option<tokio::runtime::Handle>,
    ) -> anyhow::Result<(Self, api::DatasetInfo)> {
        let (owned, rt) = if let Some(h) = runtime {
            (None, h)
        } else {
            let rt = own_runtime()?;
            let h = rt.handle().clone();
            (Some(rt), h)
        };
        let client = http_client(config.request_timeout)?;
        let (backend, info) = match source {
            TileSource::Server { url, dataset } => {
                let url = url.trim_end_matches('/').to_string();
                // The document on a connection of its own (as the probe streamer of
                // old did): the tile requests start on a new connection, which the
                // latency tests' proxy holds, as it holds only a connection's first
                // response or one after a pause.
                let probe = http_client(config.request_timeout)?;
                let info = rt.block_on(describe(&probe, &url, dataset))?;
                (
                    Backend::Server {
                        url,
                        dataset: dataset.clone(),
                    },
                    info,
                )
            }
            TileSource::StaticFile { url } => {
                let file = rt.block_on(StaticFile::open(&client, url))?;
                tracing::debug!(
                    "{url}: opened with {} requests, {} bytes",
                    file.open_requests,
                    file.open_bytes
                );
                let info = file.describe(source.name());
                (Backend::Static(Arc::new(file)), info)
            }
        };
        let geometry = TileGeometry::new(info.width, info.height, info.tile_size)?;
        let layout = RecordLayout::new(geometry.tile_log2(), info.format_version);
        let streamer = Self::build(owned, rt, client, backend, layout, config);
        Ok((streamer, info))
    }

    /// Requests and bytes it took to open a static file (its header region): 0 for a
    /// server, whose dataset document is not counted either.
    pub fn open_cost(&self) -> (u32, u64) {
        match &self.backend {
            Backend::Server { .. } => (0, 0),
            Backend::Static(f) => (f.open_requests, f.open_bytes),
        }
    }

    /// A streamer whose fetches run on an existing runtime (the load generator runs
    /// many clients on one).
    pub fn on_runtime(
        handle: tokio::runtime::Handle,
        server: &str,
        name: &str,
        layout: RecordLayout,
        config: StreamConfig,
    ) -> anyhow::Result<Self> {
        Self::with_runtime(None, handle, server, name, layout, config)
    }

    fn with_runtime(
        owned: Option<tokio::runtime::Runtime>,
        rt: tokio::runtime::Handle,
        server: &str,
        name: &str,
        layout: RecordLayout,
        config: StreamConfig,
    ) -> anyhow::Result<Self> {
        let client = http_client(config.request_timeout)?;
        let backend = Backend::Server {
            url: server.trim_end_matches('/').to_string(),
            dataset: name.to_string(),
        };
        Ok(Self::build(owned, rt, client, backend, layout, config))
    }

    fn build(
        owned: Option<tokio::runtime::Runtime>,
        rt: tokio::runtime::Handle,
        client: reqwest::Client,
        backend: Backend,
        layout: RecordLayout,
        config: StreamConfig,
    ) -> Self {
        let (tx, rx) = mpsc::channel();
        Self {
            _owned: owned,
            rt,
            client,
            backend,
            layout,
            config,
            tx,
            rx,
            flights: HashMap::new(),
            next_id: 0,
            backoff: HashMap::new(),
            corrupt_reports: HashMap::new(),
            written_off: HashSet::new(),
            stats: StreamStats::default(),
            last_error: None,
            latencies_ms: Vec::new(),
        }
    }

    /// Runs a future on the streamer's runtime (for one-off requests such as metadata).
    pub fn block_on<F: Future>(&self, f: F) -> F::Output {
        self.rt.block_on(f)
    }

    pub fn client(&self) -> &reqwest::Client {
        &self.client
    }

    /// Whether `tile` was written off as corrupt (it will not be asked for again):
    /// waiting for it is waiting forever.
    pub fn written_off(&self, tile: TileId) -> bool {
        self.written_off.contains(&tile)
    }

    fn pending(&self, tile: TileId) -> bool {
        self.flights.values().any(|f| f.tiles.contains(&tile))
    }

    /// One frame's streaming work; see the module documentation.
    pub fn frame(
        &mut self,
        pool: &mut TilePool,
        required: &[Wanted],
        prefetch: &[Wanted],
    ) -> FrameWork {
        let started = Instant::now();
        let budget = self.config.budget;
        let mut work = FrameWork::default();
        while started.elapsed() < budget {
            let Ok(ev) = self.rx.try_recv() else { break };
            match ev {
                Event::Tile(d) => {
                    let Decoded {
                        tile,
                        errors,
                        heights,
                        mask,
                    } = *d;
                    for f in self.flights.values_mut() {
                        f.tiles.remove(&tile);
                    }
                    self.backoff.remove(&tile);
                    self.corrupt_reports.remove(&tile);
                    pool.insert(tile, errors, heights, mask);
                    self.stats.tiles += 1;
                    work.accepted += 1;
                }
                Event::Absent { level, ranges } => {
                    // At most the codes a request can name: a trailer is bounded by
                    // what was asked for, whatever it claims.
                    let codes = ranges
                        .iter()
                        .flat_map(|r| r.iter())
                        .take(MAX_ABSENT_PER_TRAILER);
                    for code in codes {
                        let Some(tile) = TileId::from_morton(level, code) else {
                            continue;
                        };
                        for f in self.flights.values_mut() {
                            f.tiles.remove(&tile);
                        }
                        self.backoff.remove(&tile);
                        pool.mark_absent(tile);
                    }
                }
                Event::Corrupt { tile, error } => {
                    self.stats.corrupt += 1;
                    for f in self.flights.values_mut() {
                        f.tiles.remove(&tile);
                    }
                    let reports = self.corrupt_reports.entry(tile).or_default();
                    *reports += 1;
                    let reports = *reports;
                    let attempts = self.config.corrupt_attempts.max(1);
                    self.last_error = Some(if reports >= attempts {
                        if self.written_off.insert(tile) {
                            self.stats.written_off += 1;
                        }
                        pool.mark_unavailable(tile);
                        format!("{error}; written off after {reports} reports")
                    } else {
                        let wait = self.back_off(pool, tile);
                        format!("{error}; report {reports} of {attempts}, retrying in {wait:?}")
                    });
                }
                Event::Finished {
                    id,
                    bytes,
                    latency_ms,
                } => {
                    self.stats.bytes += bytes;
                    self.stats.responses += 1;
                    self.latencies_ms.push(latency_ms);
                    if let Some(f) = self.flights.remove(&id) {
                        // Tiles the response did not carry (should not happen) are retried.
                        for t in f.tiles {
                            self.back_off(pool, t);
                        }
                    }
                }
                Event::Failed { id, error, blame } => {
                    self.stats.failures += 1;
                    self.last_error = Some(error);
                    if let Some(f) = self.flights.remove(&id) {
                        let culprit = match blame {
                            Blame::Request => None,
                            Blame::Tile(t) => Some(t),
                            // Frames come in Morton order (one level per request).
                            Blame::Truncated => f.tiles.iter().min_by_key(|t| t.morton()).copied(),
                        }
                        .filter(|c| f.tiles.contains(c));
                        for t in f.tiles {
                            match culprit {
                                Some(c) if c != t => self.retry_soon(t),
                                _ => {
                                    self.back_off(pool, t);
                                }
                            }
                        }
                    }
                }
            }
        }
        // Cancel requests that nothing wants any more.
        let wanted: HashSet<TileId> = required.iter().chain(prefetch).map(|w| w.tile).collect();
        let stale: Vec<u64> = self
            .flights
            .iter()
            .filter(|(_, f)| !f.tiles.is_empty() && f.tiles.iter().all(|t| !wanted.contains(t)))
            .map(|(id, _)| *id)
            .collect();
        for id in stale {
            if let Some(f) = self.flights.remove(&id) {
                f.task.abort();
                self.stats.cancelled += 1;
            }
        }
        work.issued += self.issue(pool, required);
        if started.elapsed() < budget {
            work.issued += self.issue(pool, prefetch);
        } else {
            work.prefetch_skipped = !prefetch.is_empty();
        }
        work.in_flight = self.flights.len();
        work.stream_us = started.elapsed().as_secs_f64() * 1e6;
        work
    }

    /// A bystander of a request that failed on another tile: asked for again after
    /// the base delay, without raising its own backoff.
    fn retry_soon(&mut self, tile: TileId) {
        let at = Instant::now() + self.config.retry_base;
        self.backoff
            .entry(tile)
            .and_modify(|e| e.1 = at)
            .or_insert((0, at));
    }

    /// A failure blamed on `tile`: it waits `retry_base · 2ⁿ` after its n-th
    /// consecutive failure (at most `retry_max`) and is unavailable meanwhile, so
    /// that the selection draws its children in its place. Returns the wait.
    fn back_off(&mut self, pool: &mut TilePool, tile: TileId) -> Duration {
        let e = self.backoff.entry(tile).or_insert((0, Instant::now()));
        e.0 += 1;
        let delay = self
            .config
            .retry_base
            .saturating_mul(1 << e.0.min(10))
            .min(self.config.retry_max);
        e.1 = Instant::now() + delay;
        pool.mark_unavailable(tile);
        delay
    }

    /// Requests the wanted tiles that are not resident, pending or backing off, most
    /// wanted first, coalesced into Morton ranges per level.
    fn issue(&mut self, pool: &mut TilePool, wanted: &[Wanted]) -> usize {
        let now = Instant::now();
        let mut sorted: Vec<&Wanted> = wanted.iter().collect();
        sorted.sort_by(|a, b| b.rho.total_cmp(&a.rho));
        let mut by_level: Vec<(Level, Vec<Morton>)> = Vec::new();
        let mut seen = HashSet::new();
        for w in sorted {
            let t = w.tile;
            if pool.contains(t)
                || pool.is_absent(t)
                || self.written_off.contains(&t)
                || self.pending(t)
                || self.backoff.get(&t).is_some_and(|(_, at)| *at > now)
                || !seen.insert(t)
            {
                continue;
            }
            match by_level.iter_mut().find(|(l, _)| *l == t.level()) {
                Some((_, v)) => v.push(t.morton()),
                None => by_level.push((t.level(), vec![t.morton()])),
            }
        }
        let mut issued = 0;
        let per_request = match self.config.mode {
            RequestMode::Ranges => self.config.max_tiles_per_request,
            RequestMode::Single => 1,
        };
        for (level, codes) in by_level {
            for chunk in codes.chunks(per_request) {
                if self.flights.len() >= self.config.max_in_flight {
                    return issued;
                }
                let (server, dataset) = match &self.backend {
                    Backend::Server { url, dataset } => (url, dataset),
                    Backend::Static(file) => {
                        let file = file.clone();
                        let (n, full) = self.issue_static(pool, &file, level, chunk);
                        issued += n;
                        if full {
                            return issued;
                        }
                        continue;
                    }
                };
                let tiles: HashSet<TileId> = chunk
                    .iter()
                    .filter_map(|m| TileId::from_morton(level, *m))
                    .collect();
                let id = self.next_id;
                self.next_id += 1;
                let (client, tx, layout) = (self.client.clone(), self.tx.clone(), self.layout);
                let task = match self.config.mode {
                    RequestMode::Ranges => {
                        let ranges = morton::coalesce(chunk.iter().copied());
                        self.stats.ranges += ranges.len() as u64;
                        let path = api::fill(
                            api::routes::TILES,
                            &[("name", dataset), ("level", &level.to_string())],
                        );
                        let url = format!("{server}{path}?ranges={}", range_query::format(&ranges));
                        self.rt.spawn(fetch(client, url, level, id, layout, tx))
                    }
                    RequestMode::Single => {
                        let tile = *tiles.iter().next().expect("one tile per request");
                        let path = api::fill(
                            api::routes::TILE,
                            &[
                                ("name", dataset),
                                ("level", &level.to_string()),
                                ("x", &tile.x().to_string()),
                                ("y", &tile.y().to_string()),
                            ],
                        );
                        self.stats.ranges += 1;
                        let url = format!("{server}{path}");
                        self.rt.spawn(fetch_one(client, url, tile, id, layout, tx))
                    }
                };
                self.flights.insert(id, Flight { tiles, task });
                self.stats.requests += 1;
                issued += 1;
            }
        }
        issued
    }

    /// [`Streamer::issue`] for a static file: the chunk's tiles with no record are
    /// absent (the local index says so: no request); the others are grouped into
    /// runs contiguous in the file, one Range request each, while the cap on
    /// requests in flight allows. Returns the requests issued and whether the cap
    /// stopped it (the rest are asked for in a later frame).
    fn issue_static(
        &mut self,
        pool: &mut TilePool,
        file: &Arc<StaticFile>,
        level: Level,
        chunk: &[Morton],
    ) -> (usize, bool) {
        let mut present = Vec::with_capacity(chunk.len());
        for &m in chunk {
            let Some(tile) = TileId::from_morton(level, m) else {
                continue;
            };
            if let Some(e) = file.entry(tile) {
                present.push((tile, e));
            } else {
                self.backoff.remove(&tile);
                pool.mark_absent(tile);
            }
        }
        present.sort_by_key(|(_, e)| e.offset);
        let mut issued = 0;
        for run in source::byte_runs(&present) {
            if self.flights.len() >= self.config.max_in_flight {
                return (issued, true);
            }
            let id = self.next_id;
            self.next_id += 1;
            let task = self.rt.spawn(fetch_range(
                self.client.clone(),
                file.clone(),
                run.to_vec(),
                id,
                self.layout,
                self.tx.clone(),
            ));
            let tiles = run.iter().map(|(t, _)| *t).collect();
            self.flights.insert(id, Flight { tiles, task });
            self.stats.requests += 1;
            self.stats.ranges += 1;
            issued += 1;
        }
        (issued, false)
    }
}

/// `GET /v1/datasets/{name}` of `server`: the dataset's document (API.md).
async fn describe(
    client: &reqwest::Client,
    server: &str,
    dataset: &str,
) -> anyhow::Result<api::DatasetInfo> {
    let url = format!(
        "{server}{}",
        api::fill(api::routes::DATASET, &[("name", dataset)])
    );
    let r = client.get(&url).send().await?;
    let status = r.status();
    let body = r.text().await?;
    anyhow::ensure!(status.is_success(), "{url}: HTTP {status}: {body}");
    serde_json::from_str(&body)
        .with_context(|| format!("{url}: not the dataset description of API.md"))
}
