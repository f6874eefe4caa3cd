//! Tile records: Morton-range streams, error tables only, a dataset's imagery
//! records, and single tiles.
//!
//! The imagery stream (`GET /v1/datasets/{name}/imagery/levels/{level}/tiles?ranges=…`)
//! sends a dataset's imagery records (JPEG, FORMAT.md "Imagery pyramids") framed
//! exactly as the height records are (`tessera_shared::wire`), with the same limits,
//! ETags (from the imagery's own content hash) and caching; 404 for a dataset
//! without imagery.
//!
//! A range stream is the stored records (never re-encoded), each behind its 32-byte
//! frame header, then a trailer; its exact length comes from the index, so it is
//! sent with `Content-Length`. From a local file whose records in the ranges have
//! all passed their checksum (the steady state), each frame (header and record in
//! one buffer) is read as hyper asks for the next body chunk, into a reused buffer
//! ([`Storage::framed`](crate::storage::Storage::framed)): the record is
//! copied from the page cache into a buffer still in the CPU's cache and from there
//! into the socket, instead of every record of the response being read up front into
//! megabytes of fresh memory (BENCHMARKS.md "Serving"). Otherwise (object storage, a
//! record not yet checked) the ranges are read up front, one read per range, and
//! checked, as [`Dataset::records`](crate::serve::dataset::Dataset::records) does.

use super::{Params, Segments, dataset, level, pinned, stored_record, tile, unavailable};
use crate::http::cache;
use crate::http::error::{ApiError, ApiResult, requoted};
use crate::serve::dataset::Dataset;
use crate::serve::{AppState, TilesServed};
use axum::body::Body;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, header};
use axum::response::Response;
use bytes::Bytes;
use futures_util::StreamExt;
use std::collections::HashMap;
use std::sync::Arc;
use tessera_shared::range_query;
use tessera_shared::wire::{self, CONTENT_TYPE, FRAME_HEADER_LEN};
use tessera_shared::{ErrorTable, Level, Morton, MortonRange, TileId};

/// What to put in each frame: whole records or their error tables only, or the
/// records of the dataset's imagery pyramid ([`imagery`]).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Payload {
    Records,
    ErrorTables,
    Imagery,
}

/// Collects the requested codes that hold no tile into maximal sub-ranges.
#[derive(Default)]
struct Outside {
    ranges: Vec<MortonRange>,
    open: Option<(u64, u64)>,
}

impl Outside {
    fn absent(&mut self, m: u64) {
        self.open = Some(match self.open {
            Some((a, b)) if b + 1 == m => (a, m),
            Some(run) => {
                self.close_run(run);
                (m, m)
            }
            None => (m, m),
        });
    }

    fn close(&mut self) {
        if let Some(run) = self.open.take() {
            self.close_run(run);
        }
    }

    fn close_run(&mut self, (a, b): (u64, u64)) {
        self.ranges
            .push(MortonRange::new(Morton::from_raw(a), Morton::from_raw(b)).expect("a <= b"));
    }
}

/// A piece of a range stream: bytes at hand, or a checked record to read, behind its
/// frame header, when hyper asks for it.
enum Frame {
    Ready(Bytes),
    Record {
        head: [u8; FRAME_HEADER_LEN],
        offset: u64,
        len: u32,
    },
}

impl Frame {
    fn len(&self) -> usize {
        match self {
            Frame::Ready(b) => b.len(),
            Frame::Record { len, .. } => FRAME_HEADER_LEN + *len as usize,
        }
    }
}

/// A range stream of `frames`, each record read (into a reused buffer) only when
/// hyper asks for the next chunk. A read that fails (the file truncated since the
/// request started) cuts the body short, which the client sees as a truncated
/// stream: the head with its `Content-Length` is already sent.
fn body(ds: &Dataset, frames: Vec<Frame>) -> Body {
    let storage = ds.storage.clone();
    let name = ds.name.clone();
    Body::from_stream(futures_util::stream::iter(frames).map(move |f| match f {
        Frame::Ready(b) => Ok(b),
        Frame::Record { head, offset, len } => storage
            .framed(&head, offset, u64::from(len))
            .inspect_err(|e| {
                tracing::warn!(dataset = %name, error = %e, "a record could not be read while streaming; response cut short");
            }),
    }))
}

/// The tile frames of `ranges` as records to read while the response is written,
/// and the sub-ranges that hold no tile; `None` unless the storage is a local file
/// and every present record has already passed its checksum (a first read checks
/// it, up front).
fn deferred(ds: &Dataset, level: Level, ranges: &[MortonRange]) -> Option<(Vec<Frame>, Outside)> {
    if !ds.storage.reads_while_writing() {
        return None;
    }
    let mut frames = Vec::new();
    let mut outside = Outside::default();
    for r in ranges {
        for m in r.iter() {
            let tile = TileId::from_morton(level, m).expect("ranges are checked against the level");
            let Some(e) = ds.pyramid.entry(tile) else {
                outside.absent(m.get());
                continue;
            };
            if !ds.verified(tile) {
                return None;
            }
            outside.close();
            frames.push(Frame::Record {
                head: wire::tile_header(level, m, e.checksum, e.min, e.max, e.length),
                offset: e.offset,
                len: e.length,
            });
        }
        outside.close();
    }
    Some((frames, outside))
}

/// A refused `ranges=` value's message, with the range it quotes bounded (a range
/// can be as long as the query string).
fn range_message(e: &range_query::RangeQueryError) -> String {
    use range_query::RangeQueryError as E;
    match e {
        E::Malformed(range) | E::Invalid(range, _) | E::OutsideLevel { range, .. } => {
            requoted(&e.to_string(), range)
        }
        _ => e.to_string(),
    }
}

async fn stream(
    state: &AppState,
    name: &str,
    level_raw: &str,
    query: &HashMap<String, String>,
    headers: &HeaderMap,
    payload: Payload,
) -> ApiResult<Response> {
    let mut ds = dataset(state, name)?;
    if payload == Payload::Imagery {
        ds = imagery_of(&ds)?;
    }
    let level: Level = level(&ds, level_raw)?;
    let ranges = range_query::parse(query.get("ranges").map(String::as_str), level, state.limits)
        .map_err(|e| ApiError::bad_request(range_message(&e)))?;
    let pin = pinned(&ds, query);
    let canonical: Vec<String> = ranges.iter().map(ToString::to_string).collect();
    let kind = match payload {
        Payload::Records => "tiles",
        Payload::ErrorTables => "errors",
        Payload::Imagery => "imagery",
    };
    let etag = cache::etag(
        ds.content_hash(),
        &format!("{kind} {level} {}", canonical.join(",")),
    );
    if cache::not_modified(headers, &etag, ds.last_modified) {
        return Ok(cache::not_modified_response(
            &etag,
            ds.last_modified,
            pin,
            state.cache_max_age,
        ));
    }
    let deferred = match payload {
        Payload::Records | Payload::Imagery => deferred(&ds, level, &ranges),
        Payload::ErrorTables => None,
    };
    let (mut frames, tiles, errors, outside) = match deferred {
        Some((frames, outside)) => {
            let tiles = frames.len() as u64;
            (frames, tiles, 0, outside)
        }
        None => read_up_front(state, &ds, level, &ranges, payload).await?,
    };
    frames.push(Frame::Ready(Bytes::from(wire::trailer_frame(
        level,
        tiles,
        errors,
        &outside.ranges,
    ))));
    let len: usize = frames.iter().map(Frame::len).sum();
    let mut r = Response::new(body(&ds, frames));
    let h = r.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static(CONTENT_TYPE));
    h.insert(header::CONTENT_LENGTH, HeaderValue::from(len));
    if errors == 0 {
        cache::set_headers(h, &etag, ds.last_modified, pin, state.cache_max_age);
    } else {
        // A body with Error frames is not the dataset's content (whose hash comes from
        // the checksums the records should have): no cache may keep it or revalidate it.
        h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    }
    if payload != Payload::ErrorTables {
        r.extensions_mut().insert(TilesServed(tiles));
    }
    Ok(r)
}

/// The frames of `ranges` read now, one read per range, each record checked: tile
/// (or error-table) frames, error frames for records that fail their checksum, and
/// the counts of both with the sub-ranges that hold no tile.
async fn read_up_front(
    state: &AppState,
    ds: &Dataset,
    level: Level,
    ranges: &[MortonRange],
    payload: Payload,
) -> ApiResult<(Vec<Frame>, u64, u64, Outside)> {
    let table_len = ErrorTable::byte_len(ds.pyramid.geometry().tile_log2());
    let mut chunks: Vec<Bytes> = Vec::new();
    let (mut tiles, mut errors) = (0u64, 0u64);
    let mut outside = Outside::default();
    let mut found = ds
        .records(level, ranges)
        .await
        .map_err(|reason| unavailable(&reason))?
        .into_iter();
    for r in ranges {
        for m in r.iter() {
            let got = found.next().expect("one result per requested code");
            debug_assert_eq!(got.tile.morton(), m);
            match got.record {
                Some(Ok((e, bytes))) => {
                    outside.close();
                    match payload {
                        Payload::Records | Payload::Imagery => {
                            let h = wire::tile_header(level, m, e.checksum, e.min, e.max, e.length);
                            chunks.push(Bytes::copy_from_slice(&h));
                            chunks.push(bytes);
                        }
                        Payload::ErrorTables => {
                            let f = wire::error_table_frame(
                                level,
                                m,
                                e.min,
                                e.max,
                                &bytes[..table_len],
                            );
                            chunks.push(Bytes::from(f));
                        }
                    }
                    tiles += 1;
                }
                None => outside.absent(m.get()),
                Some(Err(c)) => {
                    outside.close();
                    state.metrics.corrupt_read(c.first);
                    let msg = format!("{}: record fails its checksum; not sent", c.tile);
                    chunks.push(Bytes::from(wire::error_frame(
                        level,
                        m,
                        c.entry.checksum,
                        &msg,
                    )));
                    errors += 1;
                }
            }
        }
        outside.close();
    }
    let frames = chunks.into_iter().map(Frame::Ready).collect();
    Ok((frames, tiles, errors, outside))
}

/// `GET /v1/datasets/{name}/levels/{level}/tiles?ranges=…`
pub async fn ranges(
    State(state): State<Arc<AppState>>,
    Segments((name, level)): Segments<(String, String)>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    stream(&state, &name, &level, &query, &headers, Payload::Records).await
}

/// `GET /v1/datasets/{name}/levels/{level}/errors?ranges=…`
pub async fn errors(
    State(state): State<Arc<AppState>>,
    Segments((name, level)): Segments<(String, String)>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    stream(
        &state,
        &name,
        &level,
        &query,
        &headers,
        Payload::ErrorTables,
    )
    .await
}

/// `GET /v1/datasets/{name}/imagery/levels/{level}/tiles?ranges=…`
pub async fn imagery(
    State(state): State<Arc<AppState>>,
    Segments((name, level)): Segments<(String, String)>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    stream(&state, &name, &level, &query, &headers, Payload::Imagery).await
}

/// The imagery dataset of `ds`, or 404 saying it has none.
fn imagery_of(ds: &Dataset) -> ApiResult<Arc<Dataset>> {
    let imagery = ds.imagery.clone().ok_or_else(|| {
        ApiError::not_found(format!(
            "dataset {:?} has no imagery (build it with --imagery)",
            ds.name
        ))
    })?;
    imagery.available().map_err(|r| unavailable(&r))?;
    Ok(imagery)
}

/// `GET /v1/datasets/{name}/tiles/{level}/{x}/{y}`: one stored record.
pub async fn single(
    State(state): State<Arc<AppState>>,
    Segments((name, level_raw, x, y)): Segments<(String, String, String, String)>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    let level = level(&ds, &level_raw)?;
    let tile = tile(level, &x, &y)?;
    let (entry, bytes) = stored_record(&state, &ds, tile).await?;
    let pin = pinned(&ds, &query);
    // The record's own checksum identifies its bytes: the strongest possible ETag.
    let etag = format!("\"{:016x}\"", entry.checksum);
    if let Some(r) = cache::revalidate(&headers, &etag, ds.last_modified, pin, state.cache_max_age)
    {
        return Ok(r);
    }
    let mut r = Response::new(Body::from(bytes));
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/vnd.tessera.tile"),
    );
    h.insert(header::CONTENT_LENGTH, HeaderValue::from(entry.length));
    h.insert(
        "x-tessera-checksum",
        HeaderValue::from_str(&format!("{:016x}", entry.checksum)).expect("hex"),
    );
    h.insert("x-tessera-min", HeaderValue::from(entry.min));
    h.insert("x-tessera-max", HeaderValue::from(entry.max));
    cache::set_headers(h, &etag, ds.last_modified, pin, state.cache_max_age);
    r.extensions_mut().insert(TilesServed(1));
    Ok(r)
}
