//! The fetch tasks: one request each, run on the streamer's runtime. A task
//! streams the response, decodes its records off the frame thread (no more decodes
//! at once than there are cores) and sends the frame thread what came of it
//! ([`Event`]): decoded tiles, records the server reports corrupt, the requested
//! tiles the server has no record of (absent), and how the request ended, with whom
//! to blame for a failure ([`Blame`]).

use std::sync::{Arc, OnceLock, mpsc};
use std::time::{Duration, Instant};
use tessera_shared::codec::RecordLayout;
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
    fn new(tile: TileId, rec: codec::TileRecord) -> Self {
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

/// One range request for tiles of `level`: streams the body through the frame
/// decoder and decodes each record as it completes, off the frame thread.
pub(super) async fn fetch(
    client: reqwest::Client,
    url: String,
    level: Level,
    id: u64,
    layout: RecordLayout,
    tx: mpsc::Sender<Event>,
) {
    let sent = Instant::now();
    let mut decodes = Vec::new();
    let whole = |e: &dyn std::fmt::Display| (format!("{url}: {e}"), Blame::Request);
    let result = async {
        let mut resp = client.get(&url).send().await.map_err(|e| whole(&e))?;
        if !resp.status().is_success() {
            return Err(whole(&format!("HTTP {}", resp.status())));
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
                match frame {
                    Frame::Tile {
                        level: frame_level,
                        morton,
                        record,
                        ..
                    } => {
                        let tile = TileId::from_morton(frame_level, morton)
                            .ok_or_else(|| whole(&"tile outside its level"))?;
                        // Decoding is CPU work: keep it off the I/O threads, and run
                        // no more decodes at once than there are cores, so that many
                        // clients in one process cannot starve the I/O threads. The
                        // read goes on meanwhile: latency is the network's.
                        let tx = tx.clone();
                        decodes.push(tokio::spawn(async move {
                            let _slot = decode_slots()
                                .acquire_owned()
                                .await
                                .map_err(|e| (e.to_string(), Blame::Request))?;
                            tokio::task::spawn_blocking(move || {
                                let rec = codec::decode_record(&record, layout)
                                    .map_err(|e| (format!("{tile}: {e}"), Blame::Tile(tile)))?;
                                let _ = tx.send(Event::Tile(Box::new(Decoded::new(tile, rec))));
                                Ok::<(), Failure>(())
                            })
                            .await
                            .map_err(|e| (e.to_string(), Blame::Tile(tile)))?
                        }));
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
        Ok(bytes)
    }
    .await;
    // Latency is to the last byte; the flight is finished once every tile is decoded.
    let latency = sent.elapsed();
    let mut result = result;
    for d in decodes {
        let failed = match d.await {
            Ok(Ok(())) => continue,
            Ok(Err((e, blame))) => (format!("{url}: {e}"), blame),
            Err(e) => (format!("{url}: decoding task failed: {e}"), Blame::Request),
        };
        // The first failure is the one reported and blamed.
        if result.is_ok() {
            result = Err(failed);
        }
    }
    finish_after(&tx, id, latency, result);
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
/// the one the server sends in `X-Tessera-Checksum`.
pub(super) async fn fetch_one(
    client: reqwest::Client,
    url: String,
    tile: TileId,
    id: u64,
    layout: RecordLayout,
    tx: mpsc::Sender<Event>,
) {
    let sent = Instant::now();
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
            // dataset and level were known from its document.
            let _ = tx.send(Event::Absent {
                level: tile.level(),
                ranges: vec![MortonRange::single(tile.morton())],
            });
            return Ok(0);
        }
        if !resp.status().is_success() {
            return Err(whole(&format!("HTTP {}", resp.status())));
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
        let rec = codec::decode_record(&body, layout)
            .map_err(|e| (format!("{url}: {e}"), Blame::Tile(tile)))?;
        let _ = tx.send(Event::Tile(Box::new(Decoded::new(tile, rec))));
        Ok(body.len() as u64)
    }
    .await;
    finish(&tx, id, sent, result);
}
