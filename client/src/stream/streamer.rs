//! The streamer: where its requests go, what is in flight and backing off, what the
//! open fetched for the pool, and its statistics. Opening one is `open`, its
//! per-frame work `frame`.

use super::config::StreamConfig;
use super::fetch::{Decoded, Event};
use super::pool::TilePool;
use super::static_file::StaticFile;
use super::stats::StreamStats;
use std::collections::{HashMap, HashSet};
use std::sync::{Arc, mpsc};
use std::time::Instant;
use tessera_shared::codec::RecordLayout;
use tessera_shared::{ErrorTable, TileId};

/// A request in flight: the tiles it asked for, and its task.
pub(super) struct Flight {
    pub(super) tiles: HashSet<TileId>,
    pub(super) task: tokio::task::JoinHandle<()>,
}

/// Where a streamer's requests go.
pub(super) enum Backend {
    /// A Tessera server: its root URL, without a trailing `/`, and the dataset.
    Server { url: String, dataset: String },
    /// A pyramid file read with HTTP Range (or from `file://`), its index local.
    Static(Arc<StaticFile>),
}

/// Fetches tiles in the background on its own runtime.
pub struct Streamer {
    pub(super) _owned: Option<tokio::runtime::Runtime>,
    pub(super) rt: tokio::runtime::Handle,
    pub(super) client: reqwest::Client,
    pub(super) backend: Backend,
    pub(super) layout: RecordLayout,
    pub(super) config: StreamConfig,
    pub(super) tx: mpsc::Sender<Event>,
    pub(super) rx: mpsc::Receiver<Event>,
    pub(super) flights: HashMap<u64, Flight>,
    pub(super) next_id: u64,
    pub(super) backoff: HashMap<TileId, (u32, Instant)>,
    /// How many times the server has reported each tile's record corrupt.
    pub(super) corrupt_reports: HashMap<TileId, u32>,
    /// Tiles reported corrupt `corrupt_attempts` times: not asked for again.
    pub(super) written_off: HashSet<TileId>,
    pub stats: StreamStats,
    pub last_error: Option<String>,
    /// Time from sending each finished request to its last byte.
    pub latencies_ms: Vec<f64>,
    /// What the open fetched for the pool: decoded tiles and tiles known absent
    /// ([`Streamer::preload`]).
    pub(super) preloaded: Vec<Decoded>,
    pub(super) preload_absent: Vec<TileId>,
    /// Error tables of the levels under the preloaded ones (the bootstrap's).
    pub(super) tables: HashMap<TileId, ErrorTable>,
    /// Requests and bytes the open took.
    pub(super) opened: (u32, u64),
    /// The dataset's imagery, if it has any ([`Streamer::imagery_feed`]).
    pub(super) imagery: Option<tessera_shared::api::ImageryInfo>,
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

impl Streamer {
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

    pub(super) fn pending(&self, tile: TileId) -> bool {
        self.flights.values().any(|f| f.tiles.contains(&tile))
    }
}
