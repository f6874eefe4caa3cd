//! Tile records: Morton-range streams, error tables only, and single tiles.
//!
//! The range stream is assembled from `Bytes` views of the memory-mapped file (the
//! stored records, never re-encoded) interleaved with 32-byte frame headers, so its
//! exact length is known up front and sent as `Content-Length`.

use super::{Params, Segments, dataset, level, pinned, stored_record, tile, unavailable};
use crate::serve::error::{ApiError, ApiResult};
use crate::serve::{AppState, TilesServed, cache};
use axum::body::Body;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, header};
use axum::response::Response;
use bytes::Bytes;
use std::collections::HashMap;
use std::convert::Infallible;
use std::sync::Arc;
use tessera_shared::range_query;
use tessera_shared::wire::{self, CONTENT_TYPE};
use tessera_shared::{ErrorTable, Level, Morton, MortonRange};

/// What to put in each frame: whole records or their error tables only.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Payload {
    Records,
    ErrorTables,
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

async fn stream(
    state: &AppState,
    name: &str,
    level_raw: &str,
    query: &HashMap<String, String>,
    headers: &HeaderMap,
    payload: Payload,
) -> ApiResult<Response> {
    let ds = dataset(state, name)?;
    let level: Level = level(&ds, level_raw)?;
    let ranges = range_query::parse(query.get("ranges").map(String::as_str), level, state.limits)
        .map_err(|e| ApiError::bad_request(e.to_string()))?;
    let pin = pinned(&ds, query);
    let canonical: Vec<String> = ranges.iter().map(ToString::to_string).collect();
    let kind = if payload == Payload::Records {
        "tiles"
    } else {
        "errors"
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
    let table_len = ErrorTable::byte_len(ds.pyramid.geometry().tile_log2());
    let mut chunks: Vec<Bytes> = Vec::new();
    let (mut tiles, mut errors) = (0u64, 0u64);
    let mut outside = Outside::default();
    let mut found = ds
        .records(level, &ranges)
        .await
        .map_err(|reason| unavailable(&reason))?
        .into_iter();
    for r in &ranges {
        for m in r.iter() {
            let got = found.next().expect("one result per requested code");
            debug_assert_eq!(got.tile.morton(), m);
            match got.record {
                Some(Ok((e, bytes))) => {
                    outside.close();
                    match payload {
                        Payload::Records => {
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
    chunks.push(Bytes::from(wire::trailer_frame(
        level,
        tiles,
        errors,
        &outside.ranges,
    )));
    let len: usize = chunks.iter().map(Bytes::len).sum();
    let body = Body::from_stream(futures_util::stream::iter(
        chunks.into_iter().map(Ok::<_, Infallible>),
    ));
    let mut r = Response::new(body);
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
    if payload == Payload::Records {
        r.extensions_mut().insert(TilesServed(tiles));
    }
    Ok(r)
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
