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
//! A server source opens with one request, the dataset's bootstrap (API.md,
//! [`tessera_shared::bootstrap`]): its document, the records of its coarsest levels
//! and the error tables of the next ones. The records are decoded during the open
//! and put in the pool before the first frame ([`Streamer::preload`]), so frame 0
//! draws the root level instead of empty sky, and the first frame's requests already
//! name the tiles its view needs. A server without the route (404) is opened the old
//! way, with its document alone (`--no-bootstrap` asks for that). A static file's
//! root level is fetched during the open too when it is small ([`ROOT_PRELOAD`]).
//!
//! HTTP/2: with [`StreamConfig::http2`] a server reached over `http://` is spoken to
//! in h2c with prior knowledge (the server speaks it beside HTTP/1.1 on one port),
//! so every request shares one connection instead of waiting for one of its own; if
//! the open fails that way (a proxy in between that speaks only HTTP/1.1), the
//! client says so and opens again over HTTP/1.1. Over `https://` HTTP/2 is
//! negotiated by ALPN whenever the server offers it.
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
pub mod imagery;
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
use tessera_shared::bootstrap::Bootstrap;
use tessera_shared::codec::RecordLayout;
use tessera_shared::wire::Frame;
use tessera_shared::{
    ErrorTable, Level, Morton, TileGeometry, TileId, api, codec, morton, range_query,
};

/// A static file's root level is fetched during the open (one Range request more,
/// before the first frame) when its records add up to at most this.
pub const ROOT_PRELOAD: u64 = 4 << 20;

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
    /// Open a server source with its bootstrap (one request; `false`:
    /// `--no-bootstrap`, the dataset's document alone, then tiles as frames ask).
    pub bootstrap: bool,
    /// Speak HTTP/2 to an `http://` server (h2c with prior knowledge, `--http2`).
    pub http2: bool,
    /// Where the first view is (`tessera fly`: its path's start), sent with the
    /// bootstrap so that it carries that view's records at every level
    /// ([`tessera_shared::focus`]); `None` asks for the bootstrap every client shares.
    pub focus: Option<tessera_shared::focus::Focus>,
    /// Record this client's requests to a server (`tessera load --record`); `None`
    /// records nothing and costs nothing.
    pub record: Option<crate::loadtest::record::RecordHook>,
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
            bootstrap: true,
            http2: false,
            focus: None,
            record: None,
        }
    }
}

/// How a flight opens its source and speaks to a server (`tessera fly`, `tessera
/// load`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::Args)]
pub struct OpenArgs {
    /// Open a server's dataset the old way: its document alone, then the root and
    /// every level after it as frames ask, one round trip each, instead of the
    /// bootstrap (one request carrying the document, the coarsest levels' tiles and
    /// the next levels' error tables). For side-by-side measurement and servers
    /// that predate the bootstrap (a 404 falls back by itself).
    #[arg(long)]
    pub no_bootstrap: bool,
    /// Speak HTTP/2 to an http:// server (h2c with prior knowledge): every request on
    /// one connection, none waiting for a connection of its own. Falls back to
    /// HTTP/1.1, with a warning, when the open fails that way (a proxy in between
    /// that speaks only HTTP/1.1). Over https:// HTTP/2 is negotiated by itself.
    #[arg(long)]
    pub http2: bool,
}

impl OpenArgs {
    /// The default streaming settings with these.
    pub fn config(self) -> StreamConfig {
        StreamConfig {
            bootstrap: !self.no_bootstrap,
            http2: self.http2,
            ..StreamConfig::default()
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
    /// What the open fetched for the pool: decoded tiles and tiles known absent
    /// ([`Streamer::preload`]).
    preloaded: Vec<Decoded>,
    preload_absent: Vec<TileId>,
    /// Error tables of the levels under the preloaded ones (the bootstrap's).
    tables: HashMap<TileId, ErrorTable>,
    /// Requests and bytes the open took.
    opened: (u32, u64),
    /// The dataset's imagery, if it has any ([`Streamer::imagery_feed`]).
    imagery: Option<tessera_shared::imagery::ImageryInfo>,
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
/// own; one installed already serves as well). With `h2c`, HTTP/2 with prior
/// knowledge on `http://` URLs.
fn http_client(timeout: Duration, h2c: bool) -> anyhow::Result<reqwest::Client> {
    static PROVIDER: std::sync::Once = std::sync::Once::new();
    PROVIDER.call_once(|| {
        let _ = rustls::crypto::ring::default_provider().install_default();
    });
    let b = reqwest::Client::builder().timeout(timeout);
    let b = if h2c { b.http2_prior_knowledge() } else { b };
    Ok(b.build()?)
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
        let (mut streamer, info) = match source {
            TileSource::Server { url, dataset } => {
                let url = url.trim_end_matches('/').to_string();
                let h2c = config.http2 && url.starts_with("http://");
                match Self::open_server(owned, rt.clone(), &url, dataset, &config, h2c) {
                    Err((e, owned)) if h2c => {
                        tracing::warn!(
                            "{url}: cannot open over HTTP/2 with prior knowledge ({e:#}); opening over HTTP/1.1"
                        );
                        Self::open_server(owned, rt, &url, dataset, &config, false)
                            .map_err(|(e, _)| e)
                    }
                    r => r.map_err(|(e, _)| e),
                }
            }
            TileSource::StaticFile { url } => {
                let client = http_client(config.request_timeout, false)?;
                let file = rt.block_on(StaticFile::open(&client, url))?;
                tracing::debug!(
                    "{url}: opened with {} requests, {} bytes",
                    file.open_requests,
                    file.open_bytes
                );
                let info = file.describe(source.name());
                let layout = layout_of(&info)?;
                let file = Arc::new(file);
                let opened = (file.open_requests, file.open_bytes);
                let mut streamer = Self::build(
                    owned,
                    rt,
                    client,
                    Backend::Static(file.clone()),
                    layout,
                    config,
                );
                streamer.opened = opened;
                streamer.preload_static_root(&file);
                Ok((streamer, info))
            }
        }?;
        streamer.imagery.clone_from(&info.imagery);
        Ok((streamer, info))
    }

    /// The dataset's imagery, fetched beside the tiles on this streamer's runtime and
    /// connection ([`imagery::ImageryFeed`]): `None` when the dataset has none. A
    /// static pyramid file's imagery is the file beside it with `.tess` replaced by
    /// `.tessimg` (none for a presigned URL, which names one object); one that
    /// does not open is skipped with a warning, and the tint is drawn instead.
    pub fn imagery_feed(&self, capacity: usize) -> Option<imagery::ImageryFeed> {
        let url = match &self.backend {
            Backend::Server { url, .. } => url,
            Backend::Static(file) => {
                let (img, info) = self.open_imagery_beside(file)?;
                return Some(imagery::ImageryFeed::from_file(
                    self.rt.clone(),
                    self.client.clone(),
                    img,
                    info,
                    capacity,
                ));
            }
        };
        let info = self.imagery.clone()?;
        Some(
            imagery::ImageryFeed::new(
                self.rt.clone(),
                self.client.clone(),
                url.clone(),
                info,
                capacity,
            )
            .recording(self.config.record.clone()),
        )
    }

    /// The imagery pyramid beside the static pyramid `file` (`NAME.tessimg` beside
    /// `NAME.tess`, at the same host), when there is one built for exactly this DEM
    /// (its content hash), as the server attaches it. Imagery is optional: a file
    /// that is not there is `None` quietly; one that does not open, or belongs to
    /// another version of the DEM, is `None` with a warning, and the flight goes on
    /// with the hypsometric tint.
    fn open_imagery_beside(
        &self,
        file: &StaticFile,
    ) -> Option<(Arc<StaticFile>, tessera_shared::imagery::ImageryInfo)> {
        let (stem, query) = match file.url.split_once('?') {
            Some((s, q)) => (s, Some(q)),
            None => (file.url.as_str(), None),
        };
        // A query (a presigned URL's signature) names one object only.
        if query.is_some() {
            return None;
        }
        let url = format!("{}.tessimg", stem.strip_suffix(".tess")?);
        let opened = self
            .rt
            .block_on(StaticFile::open_imagery(&self.client, &url));
        let img = match opened {
            Ok(img) => img,
            Err(e) => {
                if e.downcast_ref::<source::NoSuchFile>().is_some() {
                    tracing::debug!("{url}: no imagery beside the pyramid");
                } else {
                    tracing::warn!("{url}: imagery not used: {e:#}");
                }
                return None;
            }
        };
        let meta = img.pyramid.imagery()?;
        let dem = &file.pyramid.metadata().content_hash;
        if &meta.dem.content_hash != dem {
            tracing::warn!(
                "{url}: imagery built for another version of the DEM (content hash {}, the pyramid's is {dem}): not used",
                meta.dem.content_hash
            );
            return None;
        }
        let name = file.url.rsplit('/').next().unwrap_or_default();
        let info = tessera_shared::imagery::ImageryInfo::new(
            name,
            meta,
            tessera_shared::ByteSource::size(img.pyramid.source()).unwrap_or(0),
        );
        Some((Arc::new(img), info))
    }

    /// Opens a server source: the bootstrap, or (`--no-bootstrap`, or a server that
    /// answers it 404) the dataset's document alone. On failure, the error and the
    /// runtime back, for a second try.
    #[allow(clippy::type_complexity)]
    fn open_server(
        owned: Option<tokio::runtime::Runtime>,
        rt: tokio::runtime::Handle,
        url: &str,
        dataset: &str,
        config: &StreamConfig,
        h2c: bool,
    ) -> Result<(Self, api::DatasetInfo), (anyhow::Error, Option<tokio::runtime::Runtime>)> {
        let built = (|| {
            let client = http_client(config.request_timeout, h2c)?;
            // The open on a connection of its own (as the probe streamer of old
            // did): the tile requests start on a new connection, which the latency
            // tests' proxy holds, as it holds only a connection's first response or
            // one after a pause.
            let probe = http_client(config.request_timeout, h2c)?;
            let boot = if config.bootstrap {
                rt.block_on(bootstrap(
                    &probe,
                    url,
                    dataset,
                    config.focus,
                    config.record.as_ref(),
                ))?
            } else {
                None
            };
            let (info, boot) = match boot {
                Some((b, bytes)) => (b.info.clone(), Some((b, bytes))),
                None => (
                    rt.block_on(describe(&probe, url, dataset, config.record.as_ref()))?,
                    None,
                ),
            };
            let layout = layout_of(&info)?;
            Ok::<_, anyhow::Error>((client, info, boot, layout))
        })();
        let (client, info, boot, layout) = match built {
            Ok(b) => b,
            Err(e) => return Err((e, owned)),
        };
        let backend = Backend::Server {
            url: url.to_string(),
            dataset: dataset.to_string(),
        };
        let mut streamer = Self::build(owned, rt, client, backend, layout, config.clone());
        if let Some((b, bytes)) = boot {
            streamer.opened = (1, bytes);
            streamer.take_bootstrap(b);
        }
        Ok((streamer, info))
    }

    /// Decodes a bootstrap's records for [`Streamer::preload`] and keeps its error
    /// tables. A record that does not decode, or that the server reported corrupt
    /// (an error frame), is left to the tile stream, which asks for it as frames
    /// need it and handles it as it handles any bad record.
    fn take_bootstrap(&mut self, b: Bootstrap) {
        self.preload_absent = b.absent();
        let log2 = TileGeometry::new(b.info.width, b.info.height, b.info.tile_size)
            .map_or(0, |g| g.tile_log2());
        for f in b.frames {
            match f {
                Frame::Tile {
                    level,
                    morton,
                    record,
                    ..
                } => {
                    let Some(tile) = TileId::from_morton(level, morton) else {
                        continue;
                    };
                    match codec::decode_record(&record, self.layout) {
                        Ok(rec) => self.preloaded.push(Decoded::new(tile, rec)),
                        Err(e) => {
                            tracing::warn!("bootstrap: {tile}: {e}; asking for it again");
                        }
                    }
                }
                Frame::ErrorTable {
                    level,
                    morton,
                    table,
                    ..
                } => {
                    if let (Some(tile), Some(t)) = (
                        TileId::from_morton(level, morton),
                        ErrorTable::read_from(&table, log2),
                    ) {
                        self.tables.insert(tile, t);
                    }
                }
                Frame::Error {
                    level,
                    morton,
                    message,
                } => {
                    tracing::warn!(
                        "bootstrap: level {level} code {morton}: {message}; left to the tile stream"
                    );
                }
                Frame::Trailer { .. } => {}
            }
        }
    }

    /// A static file's root level, fetched and decoded during the open when its
    /// records are small ([`ROOT_PRELOAD`]): one Range request before the first
    /// frame instead of one round trip into the flight, counted in the statistics
    /// as the tile request it is. A failure only leaves the root to the first
    /// frame's requests.
    fn preload_static_root(&mut self, file: &Arc<StaticFile>) {
        let root = Level::new(0).expect("level 0");
        let mut records: Vec<_> = file
            .pyramid
            .geometry()
            .present_tiles(root)
            .filter_map(|t| file.entry(t).map(|e| (t, e)))
            .collect();
        records.sort_by_key(|(_, e)| e.offset);
        let bytes: u64 = records.iter().map(|(_, e)| u64::from(e.length)).sum();
        if records.is_empty() || bytes > ROOT_PRELOAD {
            return;
        }
        let (tx, rx) = mpsc::channel();
        for run in source::byte_runs(&records) {
            // Tile requests like a frame's (counted as they are), made before the first.
            self.stats.requests += 1;
            self.stats.ranges += 1;
            self.rt.block_on(fetch_range(
                self.client.clone(),
                file.clone(),
                run.to_vec(),
                0,
                self.layout,
                tx.clone(),
            ));
        }
        drop(tx);
        for ev in rx {
            match ev {
                Event::Tile(d) => {
                    self.stats.tiles += 1;
                    self.preloaded.push(*d);
                }
                Event::Finished {
                    bytes, latency_ms, ..
                } => {
                    self.stats.responses += 1;
                    self.stats.bytes += bytes;
                    self.latencies_ms.push(latency_ms);
                }
                Event::Failed { error, .. } | Event::Corrupt { error, .. } => {
                    tracing::warn!("preloading the root: {error}; left to the first frame");
                }
                Event::Absent { .. } => {}
            }
        }
    }

    /// Puts what the open fetched (the bootstrap's records, a static file's root)
    /// into `pool`, and marks the tiles of those levels that have no record absent.
    /// Call it once, before the first frame: frame 0 then draws. Returns the tiles
    /// inserted.
    pub fn preload(&mut self, pool: &mut TilePool) -> usize {
        for t in self.preload_absent.drain(..) {
            pool.mark_absent(t);
        }
        // Not counted in `stats.tiles` here: those count what tile requests brought
        // (a static file's root request counts its own).
        let n = self.preloaded.len();
        for d in self.preloaded.drain(..) {
            pool.insert(d.tile, d.errors, d.heights, d.mask);
        }
        n
    }

    /// Error tables the bootstrap carried for levels whose records it did not:
    /// where those levels are rough, before any of their records is fetched.
    pub fn known_tables(&self) -> &HashMap<TileId, ErrorTable> {
        &self.tables
    }

    /// Requests and bytes the open took: the bootstrap (1 request) or a static file's
    /// header region (its root, fetched too, counts as a tile request); 0 for a
    /// server opened with its document alone, which is not counted.
    pub fn open_cost(&self) -> (u32, u64) {
        self.opened
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
        let h2c = config.http2 && server.starts_with("http://");
        let client = http_client(config.request_timeout, h2c)?;
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
            preloaded: Vec::new(),
            preload_absent: Vec::new(),
            tables: HashMap::new(),
            opened: (0, 0),
            imagery: None,
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
                        let record = self.config.record.clone();
                        self.rt
                            .spawn(fetch(client, url, level, id, layout, tx, record))
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
                        let record = self.config.record.clone();
                        self.rt
                            .spawn(fetch_one(client, url, tile, id, layout, tx, record))
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

/// The record layout a dataset's document announces.
fn layout_of(info: &api::DatasetInfo) -> anyhow::Result<RecordLayout> {
    let geometry = TileGeometry::new(info.width, info.height, info.tile_size)?;
    Ok(RecordLayout::new(geometry.tile_log2(), info.format_version))
}

/// Largest bootstrap body read (the server's budgets make one a few MiB).
const MAX_BOOTSTRAP: usize = 256 << 20;

/// `GET /v1/datasets/{name}/bootstrap` of `server`, decoded and checked, with its
/// size in bytes; `None` when the server has no such route (404: an older server),
/// answers with a server error (5xx) or sends something that is not a bootstrap,
/// which is then said in the log and the dataset opened the old way.
///
/// With `record`, the request is recorded, and completed with its body once a 2xx
/// (or the 404 of a server without the route) has been read in full.
async fn bootstrap(
    client: &reqwest::Client,
    server: &str,
    dataset: &str,
    focus: Option<tessera_shared::focus::Focus>,
    record: Option<&crate::loadtest::record::RecordHook>,
) -> anyhow::Result<Option<(Bootstrap, u64)>> {
    let mut url = format!(
        "{server}{}",
        api::fill(api::routes::BOOTSTRAP, &[("name", dataset)])
    );
    if let Some(f) = focus {
        url = format!("{url}?focus={}", f.to_query());
    }
    let recording =
        record.map(|r| r.sent(crate::loadtest::trace::RequestKind::Bootstrap, &url, None));
    let mut r = client.get(&url).send().await?;
    let status = r.status();
    if status == reqwest::StatusCode::NOT_FOUND {
        // An unknown dataset is a 404 too: the document's request says which. The
        // short body is read, so the connection can serve the document's request
        // (and a recording digests it).
        if let (Ok(body), Some(rec)) = (r.bytes().await, recording) {
            rec.complete_body(status.as_u16(), &body);
        }
        tracing::info!("{url}: 404; opening with the dataset's document");
        return Ok(None);
    }
    if status.is_server_error() {
        // The bootstrap only saves round trips: a server in trouble (its storage
        // away, a 503) is opened the old way, whose tile requests retry with
        // backoff and report what they could not get (DESIGN §8: never blind).
        let body = r.text().await.unwrap_or_default();
        tracing::warn!(
            "{url}: HTTP {status}: {}; opening with the dataset's document",
            body.trim()
        );
        return Ok(None);
    }
    if !status.is_success() {
        let body = r.text().await.unwrap_or_default();
        anyhow::bail!("{url}: HTTP {status}: {}", body.trim());
    }
    let mut body = Vec::new();
    while let Some(chunk) = r.chunk().await? {
        body.extend_from_slice(&chunk);
        anyhow::ensure!(
            body.len() <= MAX_BOOTSTRAP,
            "{url}: more than {MAX_BOOTSTRAP} bytes"
        );
    }
    if let Some(rec) = recording {
        rec.complete_body(status.as_u16(), &body);
    }
    match Bootstrap::decode(&body) {
        Ok(b) => {
            anyhow::ensure!(
                b.info.name == dataset,
                "{url}: the bootstrap describes dataset {:?}",
                b.info.name
            );
            Ok(Some((b, body.len() as u64)))
        }
        Err(e) => {
            tracing::warn!("{url}: {e}; opening with the dataset's document");
            Ok(None)
        }
    }
}

/// `GET /v1/datasets/{name}` of `server`: the dataset's document (API.md). With
/// `record`, the request is recorded, and completed with its body on a 2xx.
async fn describe(
    client: &reqwest::Client,
    server: &str,
    dataset: &str,
    record: Option<&crate::loadtest::record::RecordHook>,
) -> anyhow::Result<api::DatasetInfo> {
    let url = format!(
        "{server}{}",
        api::fill(api::routes::DATASET, &[("name", dataset)])
    );
    let recording =
        record.map(|r| r.sent(crate::loadtest::trace::RequestKind::Document, &url, None));
    let r = client.get(&url).send().await?;
    let status = r.status();
    let bytes = r.bytes().await?;
    let body = String::from_utf8_lossy(&bytes);
    anyhow::ensure!(status.is_success(), "{url}: HTTP {status}: {body}");
    if let Some(rec) = recording {
        rec.complete_body(status.as_u16(), &bytes);
    }
    serde_json::from_str(&body)
        .with_context(|| format!("{url}: not the dataset description of API.md"))
}
