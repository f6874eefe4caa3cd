//! A dataset's imagery on the client (DECISIONS.md "Imagery pyramids"; Yang §3: texture
//! LOD follows grid LOD): the imagery of exactly the tiles the geometry has, fetched in
//! the same Morton-range requests as the heights (API.md, `/imagery/levels/{l}/tiles`),
//! decoded from JPEG to RGBA off the render thread (a blocking task per response),
//! and pooled by tile id beside the height pool, LRU, with the same capacity.
//!
//! What a renderer uploads is [`Texels`]: `side × side` RGBA8 texels (a texture array
//! layer of `Rgba8UnormSrgb`), texel `(u, v)` centred at tile sample
//! `((u + ½)·T/side, (v + ½)·T/side)` (FORMAT.md "Imagery pyramids"), so the
//! tile's UV `(i/T, j/T)` samples it at its own sample `(i, j)`.

use super::static_file::StaticFileError;
use crate::errors::Chain;
use crate::loadtest::record::RecordHook;
use crate::loadtest::trace::{RequestKind, StreamDigest};
use std::collections::{BTreeMap, HashMap, HashSet};
use std::sync::mpsc;
use std::time::{Duration, Instant};
use tessera_shared::api::ImageryInfo;
use tessera_shared::wire::WireError;
use tessera_shared::wire::{self, Frame};
use tessera_shared::{Level, MortonRange, TileId, morton, range_query};

/// One tile's imagery, ready for a texture layer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Texels {
    pub side: u32,
    /// `side × side` RGBA8, north row first, alpha 255.
    pub rgba: Vec<u8>,
}

/// Why imagery could not be had: a request, its answer, or a record in it.
#[derive(Debug, thiserror::Error)]
pub enum ImageryError {
    #[error("imagery record does not decode as JPEG: {0}")]
    Jpeg(image::ImageError),
    #[error("imagery record is {width}×{height}, the dataset says {side}²")]
    Size { width: u32, height: u32, side: u32 },
    #[error("GET {url}")]
    Request {
        url: String,
        #[source]
        source: reqwest::Error,
    },
    #[error("GET {url}: {status}")]
    Status {
        url: String,
        status: reqwest::StatusCode,
    },
    #[error("the imagery decode task failed")]
    Task(#[source] tokio::task::JoinError),
    /// What was wrong in the answer to `GET url`.
    #[error("GET {url}")]
    Answer {
        url: String,
        #[source]
        source: Box<ImageryError>,
    },
    #[error("{0}")]
    Wire(WireError),
    #[error("frame for a code outside level {level}")]
    OutsideLevel { level: Level },
    /// A tile's record that does not decode.
    #[error("{tile}")]
    Tile {
        tile: TileId,
        #[source]
        source: Box<ImageryError>,
    },
    #[error("server: {message}")]
    Server { message: String },
    #[error(transparent)]
    StaticFile(#[from] StaticFileError),
    #[error(transparent)]
    Join(#[from] tokio::task::JoinError),
    #[error("{url}: {tile}: record outside the read")]
    OutsideRead { url: String, tile: TileId },
    #[error(
        "{url}: {tile}: imagery record fails its checksum in the index (corrupt in the file, or damaged on the way)"
    )]
    Checksum { url: String, tile: TileId },
    /// A record of a static imagery file that does not decode.
    #[error("{url}: {tile}")]
    FileTile {
        url: String,
        tile: TileId,
        #[source]
        source: Box<ImageryError>,
    },
}

/// Decodes one imagery record (a JPEG of `side × side`, the dataset's `texels`).
pub fn decode(record: &[u8], side: u32) -> Result<Texels, ImageryError> {
    let img = image::load_from_memory_with_format(record, image::ImageFormat::Jpeg)
        .map_err(ImageryError::Jpeg)?;
    if (img.width(), img.height()) != (side, side) {
        return Err(ImageryError::Size {
            width: img.width(),
            height: img.height(),
            side,
        });
    }
    Ok(Texels {
        side,
        rgba: img.to_rgba8().into_raw(),
    })
}

/// The Morton ranges, per level, that hold `tiles` (one request per level).
pub fn ranges_by_level(tiles: &[TileId]) -> BTreeMap<Level, Vec<MortonRange>> {
    let mut by_level: BTreeMap<Level, Vec<tessera_shared::Morton>> = BTreeMap::new();
    for t in tiles {
        by_level.entry(t.level()).or_default().push(t.morton());
    }
    by_level
        .into_iter()
        .map(|(l, codes)| (l, morton::coalesce(codes)))
        .collect()
}

/// An HTTP client for [`fetch`], set up as the streamer's (TLS provider, timeout).
pub fn http_client(timeout: Duration) -> reqwest::Result<reqwest::Client> {
    super::http::http_client(timeout, false)
}

/// Fetches and decodes the imagery of `ranges` of `level` from the server at `base`
/// (`http://host:port`): one request, the JPEG decodes on a blocking thread. Tiles
/// without a record (outside ranges) are simply not returned.
pub async fn fetch(
    client: &reqwest::Client,
    base: &str,
    info: &ImageryInfo,
    level: Level,
    ranges: &[MortonRange],
) -> Result<Vec<(TileId, Texels)>, ImageryError> {
    fetch_recorded(client, base, info, level, ranges, None).await
}

/// [`fetch`], recording the request with `record` (`tessera load --record`): it is
/// completed, with the digest of its frames, once its stream has been read in full
/// and is well-formed ([`crate::loadtest::record`]).
async fn fetch_recorded(
    client: &reqwest::Client,
    base: &str,
    info: &ImageryInfo,
    level: Level,
    ranges: &[MortonRange],
    record: Option<RecordHook>,
) -> Result<Vec<(TileId, Texels)>, ImageryError> {
    let url = format!(
        "{base}{}",
        info.tiles
            .replace("{level}", &level.to_string())
            .replace("{ranges}", &range_query::format(ranges))
    );
    let recording = record.map(|r| r.sent(RequestKind::Imagery, &url, Some(level)));
    let resp = client
        .get(&url)
        .send()
        .await
        .map_err(|source| ImageryError::Request {
            url: url.clone(),
            source,
        })?;
    let status = resp.status();
    if !status.is_success() {
        return Err(ImageryError::Status { url, status });
    }
    let body = resp.bytes().await.map_err(|source| ImageryError::Request {
        url: url.clone(),
        source,
    })?;
    let side = info.texels;
    tokio::task::spawn_blocking(move || {
        let mut out = Vec::new();
        let frames = wire::decode_all(&body).map_err(ImageryError::Wire)?;
        if let Some(r) = recording {
            let mut digest = StreamDigest::new();
            for f in &frames {
                digest.push(f);
            }
            r.complete_stream(status.as_u16(), body.len() as u64, &digest);
        }
        for f in frames {
            match f {
                Frame::Tile {
                    level: l,
                    morton,
                    record,
                    ..
                } => {
                    let tile = TileId::from_morton(l, morton)
                        .ok_or(ImageryError::OutsideLevel { level: l })?;
                    let texels = decode(&record, side).map_err(|e| ImageryError::Tile {
                        tile,
                        source: Box::new(e),
                    })?;
                    out.push((tile, texels));
                }
                Frame::Error { message, .. } => return Err(ImageryError::Server { message }),
                _ => {}
            }
        }
        Ok(out)
    })
    .await
    .map_err(ImageryError::Task)?
    .map_err(|e| ImageryError::Answer {
        url,
        source: Box::new(e),
    })
}

/// How long a tile whose imagery request failed waits before it is asked for again.
const RETRY_AFTER: Duration = Duration::from_secs(1);

/// One finished imagery request: the tiles it asked for, and what came back.
type Answer = (Vec<TileId>, Result<Vec<(TileId, Texels)>, ImageryError>);

/// Where a feed's imagery comes from.
#[derive(Clone, Debug)]
enum Origin {
    /// A server at this base URL (`http://host:port`): the imagery route.
    Server(String),
    /// A `.tessimg` file read serverlessly (HTTP Range, `file://`), beside the
    /// pyramid file the heights come from.
    File(std::sync::Arc<super::static_file::StaticFile>),
}

/// A flight's imagery: each frame, the drawn tiles without imagery are asked for
/// (one request per level, on the streamer's runtime), so that texture LOD follows
/// the geometry's (Yang §3); answers are pooled when the next frame looks.
#[derive(Debug)]
pub struct ImageryFeed {
    rt: tokio::runtime::Handle,
    client: reqwest::Client,
    origin: Origin,
    info: ImageryInfo,
    pool: ImageryPool,
    tx: mpsc::Sender<Answer>,
    rx: mpsc::Receiver<Answer>,
    pending: HashSet<TileId>,
    /// Tiles the server has no imagery record for (the DEM has none): not asked again.
    none: HashSet<TileId>,
    retry_at: HashMap<TileId, Instant>,
    /// Records the feed's requests (`tessera load --record`; [`ImageryFeed::recording`]).
    record: Option<RecordHook>,
    pub requests: u64,
    pub last_error: Option<String>,
}

impl ImageryFeed {
    /// A feed from the server at `base` (`http://host:port`), pooling `capacity` tiles.
    pub fn new(
        rt: tokio::runtime::Handle,
        client: reqwest::Client,
        base: String,
        info: ImageryInfo,
        capacity: usize,
    ) -> Self {
        Self::with_origin(rt, client, Origin::Server(base), info, capacity)
    }

    /// A feed reading the imagery pyramid `file` serverlessly, pooling `capacity`
    /// tiles; `info` describes it ([`ImageryInfo::new`] of its metadata).
    pub(crate) fn from_file(
        rt: tokio::runtime::Handle,
        client: reqwest::Client,
        file: std::sync::Arc<super::static_file::StaticFile>,
        info: ImageryInfo,
        capacity: usize,
    ) -> Self {
        Self::with_origin(rt, client, Origin::File(file), info, capacity)
    }

    fn with_origin(
        rt: tokio::runtime::Handle,
        client: reqwest::Client,
        origin: Origin,
        info: ImageryInfo,
        capacity: usize,
    ) -> Self {
        let (tx, rx) = mpsc::channel();
        Self {
            rt,
            client,
            origin,
            info,
            pool: ImageryPool::new(capacity),
            tx,
            rx,
            pending: HashSet::new(),
            none: HashSet::new(),
            retry_at: HashMap::new(),
            record: None,
            requests: 0,
            last_error: None,
        }
    }

    /// Records the feed's requests with `record` (the streamer's, when it records).
    pub fn recording(mut self, record: Option<RecordHook>) -> Self {
        self.record = record;
        self
    }

    /// Texels per tile side.
    pub fn texels(&self) -> u32 {
        self.info.texels
    }

    pub fn pool(&self) -> &ImageryPool {
        &self.pool
    }

    /// Pools what has arrived, then asks for the imagery of `tiles` (those drawn this
    /// frame) that is neither pooled, pending nor waiting to be retried. Returns the
    /// number of requests sent.
    pub fn frame(&mut self, tiles: &[TileId]) -> usize {
        while let Ok((asked, answer)) = self.rx.try_recv() {
            for t in &asked {
                self.pending.remove(t);
            }
            match answer {
                Ok(got) => {
                    let mut have = HashSet::new();
                    for (t, texels) in got {
                        have.insert(t);
                        self.retry_at.remove(&t);
                        self.pool.insert(t, texels);
                    }
                    self.none
                        .extend(asked.into_iter().filter(|t| !have.contains(t)));
                }
                Err(e) => {
                    tracing::warn!("imagery: {}", Chain(&e));
                    self.last_error = Some(Chain(&e).to_string());
                    let at = Instant::now() + RETRY_AFTER;
                    self.retry_at.extend(asked.into_iter().map(|t| (t, at)));
                }
            }
        }
        self.pool.touch(tiles);
        let now = Instant::now();
        let want: Vec<TileId> = self
            .pool
            .missing(tiles)
            .into_iter()
            .filter(|t| {
                !self.pending.contains(t)
                    && !self.none.contains(t)
                    && self.retry_at.get(t).is_none_or(|&at| at <= now)
            })
            .collect();
        let mut sent = 0;
        for (level, ranges) in ranges_by_level(&want) {
            let asked: Vec<TileId> = want
                .iter()
                .copied()
                .filter(|t| t.level() == level)
                .collect();
            self.pending.extend(asked.iter().copied());
            let (client, origin, info, tx, record) = (
                self.client.clone(),
                self.origin.clone(),
                self.info.clone(),
                self.tx.clone(),
                self.record.clone(),
            );
            self.rt.spawn(async move {
                let answer = match &origin {
                    Origin::Server(base) => {
                        fetch_recorded(&client, base, &info, level, &ranges, record).await
                    }
                    Origin::File(file) => {
                        fetch_from_file(&client, file, info.texels, level, &ranges).await
                    }
                };
                let _ = tx.send((asked, answer));
            });
            sent += 1;
        }
        self.requests += sent as u64;
        sent
    }

    /// Waits (up to `timeout`) until none of `tiles` is pending; `false` on timeout.
    pub fn settle(&mut self, tiles: &[TileId], timeout: Duration) -> bool {
        let started = Instant::now();
        loop {
            self.frame(tiles);
            if tiles.iter().all(|t| !self.pending.contains(t)) {
                return true;
            }
            if started.elapsed() >= timeout {
                return false;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }
}

/// Reads and decodes the imagery records of `ranges` of `level` from an imagery
/// pyramid file (serverless): the tiles' index entries grouped into runs contiguous
/// in the file, one read per run ([`super::static_file::byte_runs`]), each record checked
/// against its index checksum before it is decoded off the I/O threads. Tiles
/// without a record are not returned, as with [`fetch`].
async fn fetch_from_file(
    client: &reqwest::Client,
    file: &super::static_file::StaticFile,
    side: u32,
    level: Level,
    ranges: &[MortonRange],
) -> Result<Vec<(TileId, Texels)>, ImageryError> {
    let mut entries = Vec::new();
    for r in ranges {
        for code in r.start().get()..=r.end().get() {
            let Some(tile) = TileId::from_morton(level, tessera_shared::Morton::from_raw(code))
            else {
                continue;
            };
            if let Some(e) = file.entry(tile) {
                entries.push((tile, e));
            }
        }
    }
    entries.sort_by_key(|(_, e)| e.offset);
    let mut out = Vec::with_capacity(entries.len());
    for run in super::static_file::byte_runs(&entries) {
        let (start, end) = (run[0].1.offset, run[run.len() - 1].1.end());
        let bytes = file.read_range(client, start, end).await?;
        let run = run.to_vec();
        let url = file.url.clone();
        let decoded = tokio::task::spawn_blocking(move || {
            run.into_iter()
                .map(|(tile, e)| {
                    let at = usize::try_from(e.offset - start).unwrap_or(usize::MAX);
                    let record = bytes
                        .get(at..at.saturating_add(e.length as usize))
                        .ok_or_else(|| ImageryError::OutsideRead {
                            url: url.clone(),
                            tile,
                        })?;
                    if tessera_shared::format::checksum(record) != e.checksum {
                        return Err(ImageryError::Checksum {
                            url: url.clone(),
                            tile,
                        });
                    }
                    let texels = decode(record, side).map_err(|e| ImageryError::FileTile {
                        url: url.clone(),
                        tile,
                        source: Box::new(e),
                    })?;
                    Ok((tile, texels))
                })
                .collect::<Result<Vec<_>, ImageryError>>()
        })
        .await??;
        out.extend(decoded);
    }
    Ok(out)
}

/// Decoded imagery by tile, least recently used first out.
#[derive(Debug)]
pub struct ImageryPool {
    capacity: usize,
    tiles: HashMap<TileId, (Texels, u64)>,
    clock: u64,
}

impl ImageryPool {
    pub fn new(capacity: usize) -> Self {
        Self {
            capacity: capacity.max(1),
            tiles: HashMap::new(),
            clock: 0,
        }
    }

    pub fn len(&self) -> usize {
        self.tiles.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tiles.is_empty()
    }

    pub fn get(&self, tile: TileId) -> Option<&Texels> {
        self.tiles.get(&tile).map(|(t, _)| t)
    }

    /// Marks `tiles` used now (they are drawn this frame).
    pub fn touch(&mut self, tiles: &[TileId]) {
        self.clock += 1;
        for t in tiles {
            if let Some(e) = self.tiles.get_mut(t) {
                e.1 = self.clock;
            }
        }
    }

    pub fn insert(&mut self, tile: TileId, texels: Texels) {
        self.clock += 1;
        if !self.tiles.contains_key(&tile) && self.tiles.len() >= self.capacity {
            let oldest = self
                .tiles
                .iter()
                .min_by_key(|(_, (_, used))| *used)
                .map(|(t, _)| *t);
            if let Some(t) = oldest {
                self.tiles.remove(&t);
            }
        }
        self.tiles.insert(tile, (texels, self.clock));
    }

    /// Of `tiles` (those the geometry draws or holds), the ones without imagery yet:
    /// what to ask for, so that texture LOD follows the geometry's.
    pub fn missing(&self, tiles: &[TileId]) -> Vec<TileId> {
        tiles
            .iter()
            .copied()
            .filter(|t| !self.tiles.contains_key(t))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tile(level: u8, x: u32, y: u32) -> TileId {
        TileId::new(Level::new(level).unwrap(), x, y).unwrap()
    }

    fn texels(v: u8) -> Texels {
        Texels {
            side: 1,
            rgba: vec![v, v, v, 255],
        }
    }

    #[test]
    fn the_pool_evicts_the_least_recently_drawn() {
        let mut p = ImageryPool::new(2);
        let (a, b, c) = (tile(1, 0, 0), tile(1, 1, 0), tile(1, 0, 1));
        p.insert(a, texels(1));
        p.insert(b, texels(2));
        p.touch(&[a]);
        p.insert(c, texels(3));
        assert!(p.get(a).is_some() && p.get(c).is_some());
        assert!(p.get(b).is_none(), "b was the least recently used");
        assert_eq!(p.missing(&[a, b, c]), vec![b]);
    }

    #[test]
    fn ranges_coalesce_per_level() {
        let r = ranges_by_level(&[tile(1, 0, 0), tile(1, 1, 0), tile(1, 1, 1), tile(0, 0, 0)]);
        assert_eq!(r[&Level::new(0).unwrap()].len(), 1);
        // Codes 0, 1 and 3 of level 1: two ranges.
        let l1: Vec<String> = r[&Level::new(1).unwrap()]
            .iter()
            .map(ToString::to_string)
            .collect();
        assert_eq!(l1, ["0-1", "3-3"]);
    }

    #[test]
    fn decode_checks_the_stated_size() {
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
            .encode(
                &[200u8; 16 * 16 * 3],
                16,
                16,
                image::ExtendedColorType::Rgb8,
            )
            .unwrap();
        let t = decode(&jpeg, 16).unwrap();
        assert_eq!(t.rgba.len(), 16 * 16 * 4);
        assert!(
            t.rgba
                .chunks(4)
                .all(|p| p[0].abs_diff(200) <= 2 && p[3] == 255)
        );
        assert!(decode(&jpeg, 32).unwrap_err().to_string().contains("16×16"));
        assert!(decode(b"not a jpeg", 16).is_err());
    }
}
