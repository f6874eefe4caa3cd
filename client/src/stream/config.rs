//! Streaming settings: how tiles are requested, budgets, retries, the bootstrap,
//! HTTP/2, the first view's focus and request recording; and the command line's
//! share of them ([`OpenArgs`]).

use std::time::Duration;

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
