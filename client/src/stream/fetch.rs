//! The fetch tasks: one request each, run on the streamer's runtime. A task
//! streams the response, decodes its records off the frame thread (no more decodes
//! at once than there are cores) and sends the frame thread what came of it
//! ([`Event`]): decoded tiles, records the server reports corrupt, the requested
//! tiles the server has no record of (absent), and how the request ended, with whom
//! to blame for a failure ([`Blame`]).

use super::static_file::{StaticFile, Transport, Validators};
use crate::loadtest::record::RecordHook;
use crate::loadtest::trace::{RequestKind, StreamDigest};
use std::sync::{Arc, OnceLock, mpsc};
use std::time::{Duration, Instant};
use tessera_shared::ByteSource;
use tessera_shared::codec::RecordLayout;
use tessera_shared::format::IndexEntry;
use tessera_shared::wire::{Frame, FrameDecoder, WireError};
use tessera_shared::{CellMask, ErrorTable, Level, Morton, MortonRange, TileId, codec};

/// A decoded tile on its way to the pool.
pub(super) struct Decoded {
    pub(super) tile: TileId,
    pub(super) errors: ErrorTable,
    pub(super) heights: Vec<u16>,
    pub(super) mask: CellMask,
}

impl Decoded {
    pub(super) fn new(tile: TileId, rec: codec::TileRecord) -> Self {
        Self {
            tile,
            errors: rec.errors,
            heights: rec.heights,
            mask: rec.mask,
        }
    }
}

/// What the fetch tasks tell the frame thread.
pub(super) enum Event {
    Tile(Box<Decoded>),
    /// Requested codes of `level` that hold no tile (the trailer's outside ranges,
    /// or a 404 for a single tile): outside the DEM or wholly no-data.
    Absent {
        level: Level,
        ranges: Vec<MortonRange>,
    },
    Corrupt {
        tile: TileId,
        error: String,
    },
    Finished {
        id: u64,
        bytes: u64,
        latency_ms: f64,
    },
    Failed {
        id: u64,
        error: String,
        blame: Blame,
    },
}

/// What a failed request's failure is to be blamed on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Blame {
    /// The request as a whole (no connection, an HTTP error, a broken stream).
    Request,
    /// One tile: its frame failed its checksum or its record did not decode.
    Tile(TileId),
    /// The stream ended early: on the first tile of the request still missing.
    Truncated,
}

/// A failed request: what to report, and whom to blame.
pub(super) type Failure = (String, Blame);

/// The process-wide limit on concurrent tile decodes: one per core.
fn decode_slots() -> Arc<tokio::sync::Semaphore> {
    static SLOTS: OnceLock<Arc<tokio::sync::Semaphore>> = OnceLock::new();
    SLOTS
        .get_or_init(|| {
            let cores = std::thread::available_parallelism().map_or(2, std::num::NonZero::get);
            Arc::new(tokio::sync::Semaphore::new(cores))
        })
        .clone()
}

/// Decodes one record off the I/O threads: decoding is CPU work, and no more decodes
/// run at once than there are cores, so that many clients in one process cannot
/// starve the I/O threads. The read goes on meanwhile: latency is the network's.
///
/// With `check` (the index's checksum and where the bytes came from), the record is
/// first checked against it: a mismatch is reported as a corrupt record
/// ([`Event::Corrupt`]), not as a failure of the request, since the index says
/// exactly where the next record starts.
fn spawn_decode(
    tile: TileId,
    record: Vec<u8>,
    check: Option<(u64, String)>,
    layout: RecordLayout,
    tx: mpsc::Sender<Event>,
) -> tokio::task::JoinHandle<Result<(), Failure>> {
    tokio::spawn(async move {
        let _slot = decode_slots()
            .acquire_owned()
            .await
            .map_err(|e| (e.to_string(), Blame::Request))?;
        tokio::task::spawn_blocking(move || {
            if let Some((want, from)) = check
                && tessera_shared::format::checksum(&record) != want
            {
                let _ = tx.send(Event::Corrupt {
                    tile,
                    error: format!(
                        "{from}: {tile}: record fails its checksum in the index (corrupt in the file, or damaged on the way)"
                    ),
                });
                return Ok(());
            }
            let rec = codec::decode_record(&record, layout)
                .map_err(|e| (format!("{tile}: {e}"), Blame::Tile(tile)))?;
            let _ = tx.send(Event::Tile(Box::new(Decoded::new(tile, rec))));
            Ok::<(), Failure>(())
        })
        .await
        .map_err(|e| (e.to_string(), Blame::Tile(tile)))?
    })
}

/// One range request for tiles of `level`: streams the body through the frame
/// decoder and decodes each record as it completes, off the frame thread. With
/// `record`, the request is recorded, and completed with the digest of its frames
/// once the stream has ended well-formed ([`crate::loadtest::record`]).
#[allow(clippy::too_many_arguments)]
pub(super) async fn fetch(
    client: reqwest::Client,
    url: String,
    level: Level,
    id: u64,
    layout: RecordLayout,
    tx: mpsc::Sender<Event>,
    record: Option<RecordHook>,
) {
    let sent = Instant::now();
    let recording = record.map(|r| r.sent(RequestKind::Tiles, &url, Some(level)));
    let mut digest = recording.as_ref().map(|_| StreamDigest::new());
    let mut decodes = Vec::new();
    let whole = |e: &dyn std::fmt::Display| (format!("{url}: {e}"), Blame::Request);
    let result = async {
        let mut resp = client.get(&url).send().await.map_err(|e| whole(&e))?;
        let status = resp.status();
        if !status.is_success() {
            return Err(whole(&format!("HTTP {status}")));
        }
        let mut dec = FrameDecoder::new();
        let mut bytes = 0u64;
        while let Some(chunk) = resp.chunk().await.map_err(|e| whole(&e))? {
            bytes += chunk.len() as u64;
            dec.push(&chunk);
            while let Some(frame) = dec.next_frame().map_err(|e| {
                let blame = match e {
                    WireError::Checksum { level, morton, .. } => Level::new(level)
                        .and_then(|l| TileId::from_morton(l, Morton::from_raw(morton)))
                        .map_or(Blame::Request, Blame::Tile),
                    _ => Blame::Request,
                };
                (format!("{url}: {e}"), blame)
            })? {
                if let Some(d) = &mut digest {
                    d.push(&frame);
                }
                match frame {
                    Frame::Tile {
                        level: frame_level,
                        morton,
                        record,
                        ..
                    } => {
                        let tile = TileId::from_morton(frame_level, morton)
                            .ok_or_else(|| whole(&"tile outside its level"))?;
                        // The wire decoder has checked the frame's checksum.
                        decodes.push(spawn_decode(tile, record, None, layout, tx.clone()));
                    }
                    Frame::Error {
                        level,
                        morton,
                        message,
                    } => {
                        if let Some(tile) = TileId::from_morton(level, morton) {
                            let _ = tx.send(Event::Corrupt {
                                tile,
                                error: corrupt_error(&url, tile, &message),
                            });
                        }
                    }
                    Frame::Trailer { outside, .. } => {
                        // The requested codes that hold no tile (one level per request).
                        if !outside.is_empty() {
                            let _ = tx.send(Event::Absent {
                                level,
                                ranges: outside,
                            });
                        }
                    }
                    Frame::ErrorTable { .. } => {}
                }
            }
        }
        dec.finish()
            .map_err(|e| (format!("{url}: {e}"), Blame::Truncated))?;
        Ok((status.as_u16(), bytes))
    }
    .await;
    // Read in full and well-formed: the answer a replay expects (a record that then
    // fails to decode is the client's trouble, not the stream's).
    if let (Some(r), Some(d), Ok((status, bytes))) = (recording, &digest, &result) {
        r.complete_stream(*status, *bytes, d);
    }
    let result = result.map(|(_, bytes)| bytes);
    // Latency is to the last byte; the flight is finished once every tile is decoded.
    finish_decoded(&tx, id, sent.elapsed(), result, decodes, &url).await;
}

/// Reports a request once its decodes are done: the first failure (the request's
/// own, else the first decode's) is the one reported and blamed.
async fn finish_decoded(
    tx: &mpsc::Sender<Event>,
    id: u64,
    latency: Duration,
    mut result: Result<u64, Failure>,
    decodes: Vec<tokio::task::JoinHandle<Result<(), Failure>>>,
    from: &str,
) {
    for d in decodes {
        let failed = match d.await {
            Ok(Ok(())) => continue,
            Ok(Err((e, blame))) => (format!("{from}: {e}"), blame),
            Err(e) => (format!("{from}: decoding task failed: {e}"), Blame::Request),
        };
        if result.is_ok() {
            result = Err(failed);
        }
    }
    finish_after(tx, id, latency, result);
}

/// What [`super::Streamer::last_error`] says of a record the server reports corrupt: the
/// request, and the server's own words (naming the tile unless they already do).
fn corrupt_error(url: &str, tile: TileId, message: &str) -> String {
    let name = tile.to_string();
    if message.contains(&name) {
        format!("{url}: corrupt record on the server: {message}")
    } else {
        format!("{url}: corrupt record on the server: {name}: {message}")
    }
}

fn finish(tx: &mpsc::Sender<Event>, id: u64, sent: Instant, result: Result<u64, Failure>) {
    finish_after(tx, id, sent.elapsed(), result);
}

fn finish_after(
    tx: &mpsc::Sender<Event>,
    id: u64,
    latency: Duration,
    result: Result<u64, Failure>,
) {
    let _ = tx.send(match result {
        Ok(bytes) => Event::Finished {
            id,
            bytes,
            latency_ms: latency.as_secs_f64() * 1e3,
        },
        Err((error, blame)) => Event::Failed { id, error, blame },
    });
}

/// One single-tile request: the body is the stored record; its checksum must match
/// the one the server sends in `X-Tessera-Checksum`. With `record`, the request is
/// recorded, and completed once a record or a 404 (absent) has been read.
#[allow(clippy::too_many_arguments)]
pub(super) async fn fetch_one(
    client: reqwest::Client,
    url: String,
    tile: TileId,
    id: u64,
    layout: RecordLayout,
    tx: mpsc::Sender<Event>,
    record: Option<RecordHook>,
) {
    let sent = Instant::now();
    let mut recording = record.map(|r| r.sent(RequestKind::Tile, &url, Some(tile.level())));
    let whole = |e: &dyn std::fmt::Display| (format!("{url}: {e}"), Blame::Request);
    let result = async {
        let resp = client.get(&url).send().await.map_err(|e| whole(&e))?;
        if resp.status() == reqwest::StatusCode::INTERNAL_SERVER_ERROR {
            let status = resp.status();
            let body = resp.text().await.unwrap_or_default();
            let reason = body.trim().chars().take(200).collect::<String>();
            let _ = tx.send(Event::Corrupt {
                tile,
                error: corrupt_error(&url, tile, &format!("HTTP {status} {reason}")),
            });
            return Ok(0);
        }
        if resp.status() == reqwest::StatusCode::NOT_FOUND {
            // API.md: 404 for an absent tile (outside the DEM or wholly no-data); the
            // dataset and level were known from its document. Its short body is read,
            // so the connection goes back to the pool (and a recording digests it).
            if let (Ok(body), Some(r)) = (resp.bytes().await, recording.take()) {
                r.complete_body(404, &body);
            }
            let _ = tx.send(Event::Absent {
                level: tile.level(),
                ranges: vec![MortonRange::single(tile.morton())],
            });
            return Ok(0);
        }
        let status = resp.status();
        if !status.is_success() {
            return Err(whole(&format!("HTTP {status}")));
        }
        let want = resp
            .headers()
            .get("x-tessera-checksum")
            .and_then(|v| u64::from_str_radix(v.to_str().ok()?, 16).ok());
        let body = resp.bytes().await.map_err(|e| whole(&e))?;
        if want != Some(tessera_shared::format::checksum(&body)) {
            return Err((
                format!("{url}: record fails its checksum"),
                Blame::Tile(tile),
            ));
        }
        if let Some(r) = recording.take() {
            r.complete_body(status.as_u16(), &body);
        }
        let rec = codec::decode_record(&body, layout)
            .map_err(|e| (format!("{url}: {e}"), Blame::Tile(tile)))?;
        let _ = tx.send(Event::Tile(Box::new(Decoded::new(tile, rec))));
        Ok(body.len() as u64)
    }
    .await;
    finish(&tx, id, sent, result);
}

/// Splits the bytes of one byte range into the records the index says it holds, in
/// order (a level's records are contiguous: FORMAT.md "Layout").
struct Splitter {
    records: std::collections::VecDeque<(TileId, IndexEntry)>,
    buf: Vec<u8>,
}

impl Splitter {
    fn new(records: &[(TileId, IndexEntry)]) -> Self {
        Self {
            records: records.iter().copied().collect(),
            buf: Vec::new(),
        }
    }

    /// Adds received bytes; every record they complete, with its index entry.
    fn push(&mut self, bytes: &[u8]) -> Vec<(TileId, IndexEntry, Vec<u8>)> {
        self.buf.extend_from_slice(bytes);
        let mut done = Vec::new();
        while let Some(&(tile, e)) = self.records.front() {
            let len = e.length as usize;
            if self.buf.len() < len {
                break;
            }
            let rest = self.buf.split_off(len);
            done.push((tile, e, std::mem::replace(&mut self.buf, rest)));
            self.records.pop_front();
        }
        done
    }

    fn is_done(&self) -> bool {
        self.records.is_empty()
    }
}

/// One Range request for a run of records contiguous in a static pyramid file
/// (serverless reads, [`super::static_file`]): the body is split into records at the
/// index's boundaries as it arrives, and each is checked against its index checksum
/// and decoded off the frame thread, as [`fetch`] does with a server's frames.
///
/// The answer must be `206` with the range asked for, from the file the client
/// opened (its validators, its length, compared before the body is read); a `200`
/// (the host stopped honouring `Range`), a `416` (the file is shorter than its index
/// says), another range, a changed `ETag`/`Last-Modified`/length or a short body
/// fail the request and name the cause. A short body blames the first record not
/// received; the records before it are delivered.
pub(super) async fn fetch_range(
    client: reqwest::Client,
    file: Arc<StaticFile>,
    records: Vec<(TileId, IndexEntry)>,
    id: u64,
    layout: RecordLayout,
    tx: mpsc::Sender<Event>,
) {
    let sent = Instant::now();
    let (Some(first), Some(last)) = (records.first(), records.last()) else {
        finish(&tx, id, sent, Ok(0));
        return;
    };
    let (start, end) = (first.1.offset, last.1.end());
    let len = end - start;
    let from = format!("{} bytes={start}-{}", file.url, end - 1);
    let whole = |e: &dyn std::fmt::Display| (format!("{from}: {e}"), Blame::Request);
    let mut split = Splitter::new(&records);
    let mut decodes = Vec::new();
    let take = |split: &mut Splitter, bytes: &[u8], decodes: &mut Vec<_>| {
        for (tile, e, record) in split.push(bytes) {
            let check = Some((e.checksum, from.clone()));
            decodes.push(spawn_decode(tile, record, check, layout, tx.clone()));
        }
    };
    let result = async {
        match &file.transport {
            Transport::Http(validators) => {
                let mut resp = client
                    .get(&file.url)
                    .header(reqwest::header::RANGE, format!("bytes={start}-{}", end - 1))
                    .send()
                    .await
                    .map_err(|e| whole(&e))?;
                let range = super::static_file::content_range(resp.headers());
                let now = Validators::of_response(resp.headers(), range.and_then(|r| r.2));
                if let Some(what) = validators.changed(&now) {
                    return Err(whole(&format!(
                        "the pyramid changed under the client ({what}); open it again"
                    )));
                }
                match resp.status() {
                    reqwest::StatusCode::PARTIAL_CONTENT => {}
                    reqwest::StatusCode::OK => {
                        return Err(whole(
                            &"HTTP 200 to a Range request: the host stopped honouring Range",
                        ));
                    }
                    reqwest::StatusCode::RANGE_NOT_SATISFIABLE => {
                        return Err(whole(
                            &"HTTP 416: the file is shorter than its index says (the pyramid changed under the client, or was truncated)",
                        ));
                    }
                    status => return Err(whole(&format!("HTTP {status}"))),
                }
                if range.map(|r| (r.0, r.1)) != Some((start, end - 1)) {
                    return Err(whole(&format!(
                        "the host answered another range ({:?})",
                        resp.headers().get(reqwest::header::CONTENT_RANGE)
                    )));
                }
                let mut bytes = 0u64;
                while let Some(chunk) = resp.chunk().await.map_err(|e| {
                    // A body cut short: blame the first record still missing.
                    (format!("{from}: {e}"), Blame::Truncated)
                })? {
                    bytes += chunk.len() as u64;
                    if bytes > len {
                        return Err(whole(&format!("more than the {len} bytes asked for")));
                    }
                    take(&mut split, &chunk, &mut decodes);
                }
                if !split.is_done() {
                    return Err((
                        format!("{from}: short body: {bytes} of {len} bytes"),
                        Blame::Truncated,
                    ));
                }
                Ok(bytes)
            }
            Transport::Memory(body) => {
                let bytes = usize::try_from(start)
                    .ok()
                    .zip(usize::try_from(end).ok())
                    .and_then(|(a, b)| body.get(a..b))
                    .ok_or_else(|| whole(&"the file is shorter than its index says"))?;
                take(&mut split, bytes, &mut decodes);
                Ok(len)
            }
            Transport::File(src) => {
                let src = src.clone();
                let bytes = tokio::task::spawn_blocking(move || src.read_vec(start, len as usize))
                .await
                .map_err(|e| whole(&e))?
                .map_err(|e| whole(&e))?;
                take(&mut split, &bytes, &mut decodes);
                Ok(len)
            }
        }
    }
    .await;
    finish_decoded(&tx, id, sent.elapsed(), result, decodes, &from).await;
}
