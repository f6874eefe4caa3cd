//! Opening a streamer on its source: a server's bootstrap (or its dataset document
//! alone), with the records it carries decoded for the pool, or a static pyramid
//! file's header region and, when small, its root level.

use super::config::StreamConfig;
use super::fetch::{Decoded, Event, fetch_range};
use super::http::{http_client, own_runtime};
use super::static_file::{self, StaticFile, StaticFileError};
use super::stats::StreamStats;
use super::streamer::{Backend, Streamer};
use super::tile_source::TileSource;
use crate::errors::Chain;
use std::collections::{HashMap, HashSet};
use std::sync::{Arc, mpsc};
use tessera_shared::bootstrap::Bootstrap;
use tessera_shared::codec::RecordLayout;
use tessera_shared::tile::GeometryError;
use tessera_shared::wire::Frame;
use tessera_shared::{ErrorTable, Level, TileGeometry, TileId, api, codec};

/// Why a streamer could not be opened: its runtime or HTTP client, its source
/// (a server's bootstrap or document, a static file), or the document's geometry.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    #[error(transparent)]
    Runtime(#[from] std::io::Error),
    #[error(transparent)]
    Http(#[from] reqwest::Error),
    #[error(transparent)]
    StaticFile(#[from] StaticFileError),
    #[error(transparent)]
    Geometry(#[from] GeometryError),
    #[error("{url}: HTTP {status}: {body}")]
    Status {
        url: String,
        status: reqwest::StatusCode,
        body: String,
    },
    #[error("{url}: more than {MAX_BOOTSTRAP} bytes")]
    TooBig { url: String },
    #[error("{url}: the bootstrap describes dataset {name:?}")]
    OtherDataset { url: String, name: String },
    #[error("{url}: not the dataset description of API.md")]
    NotDocument {
        url: String,
        #[source]
        source: serde_json::Error,
    },
}

/// A static file's root level is fetched during the open (one Range request more,
/// before the first frame) when its records add up to at most this.
pub const ROOT_PRELOAD: u64 = 4 << 20;

impl Streamer {
    /// A streamer for dataset `name` on `server` (e.g. `http://127.0.0.1:8080`).
    pub fn new(
        server: &str,
        name: &str,
        layout: RecordLayout,
        config: StreamConfig,
    ) -> Result<Self, OpenError> {
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
    ) -> Result<(Self, api::DatasetInfo), OpenError> {
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
                    Err(failed) if h2c => {
                        let (e, owned) = *failed;
                        tracing::warn!(
                            "{url}: cannot open over HTTP/2 with prior knowledge ({}); opening over HTTP/1.1",
                            Chain(&e)
                        );
                        Self::open_server(owned, rt, &url, dataset, &config, false)
                            .map_err(|failed| failed.0)
                    }
                    r => r.map_err(|failed| failed.0),
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
    ) -> Result<(Self, api::DatasetInfo), Box<(OpenError, Option<tokio::runtime::Runtime>)>> {
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
            Ok::<_, OpenError>((client, info, boot, layout))
        })();
        let (client, info, boot, layout) = match built {
            Ok(b) => b,
            Err(e) => return Err(Box::new((e, owned))),
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
        for run in static_file::byte_runs(&records) {
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

    /// A streamer whose fetches run on an existing runtime (the load generator runs
    /// many clients on one).
    pub fn on_runtime(
        handle: tokio::runtime::Handle,
        server: &str,
        name: &str,
        layout: RecordLayout,
        config: StreamConfig,
    ) -> Result<Self, OpenError> {
        Self::with_runtime(None, handle, server, name, layout, config)
    }

    fn with_runtime(
        owned: Option<tokio::runtime::Runtime>,
        rt: tokio::runtime::Handle,
        server: &str,
        name: &str,
        layout: RecordLayout,
        config: StreamConfig,
    ) -> Result<Self, OpenError> {
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
}

/// The record layout a dataset's document announces.
fn layout_of(info: &api::DatasetInfo) -> Result<RecordLayout, GeometryError> {
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
) -> Result<Option<(Bootstrap, u64)>, OpenError> {
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
        // backoff and report what they could not get
        // (docs/ARCHITECTURE.md#the-client-never-goes-blind).
        let body = r.text().await.unwrap_or_default();
        tracing::warn!(
            "{url}: HTTP {status}: {}; opening with the dataset's document",
            body.trim()
        );
        return Ok(None);
    }
    if !status.is_success() {
        let body = r.text().await.unwrap_or_default();
        return Err(OpenError::Status {
            url,
            status,
            body: body.trim().to_string(),
        });
    }
    let mut body = Vec::new();
    while let Some(chunk) = r.chunk().await? {
        body.extend_from_slice(&chunk);
        if body.len() > MAX_BOOTSTRAP {
            return Err(OpenError::TooBig { url });
        }
    }
    if let Some(rec) = recording {
        rec.complete_body(status.as_u16(), &body);
    }
    match Bootstrap::decode(&body) {
        Ok(b) => {
            if b.info.name != dataset {
                return Err(OpenError::OtherDataset {
                    url,
                    name: b.info.name,
                });
            }
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
) -> Result<api::DatasetInfo, OpenError> {
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
    if !status.is_success() {
        return Err(OpenError::Status {
            url,
            status,
            body: body.into_owned(),
        });
    }
    if let Some(rec) = recording {
        rec.complete_body(status.as_u16(), &bytes);
    }
    serde_json::from_str(&body).map_err(|source| OpenError::NotDocument { url, source })
}
