//! `GET /v1/datasets/{name}/bootstrap`: the dataset's document, the records of its
//! coarsest levels and the error tables of the next ones in one response, so that a
//! client draws its first frame after one round trip
//! (DECISIONS.md "The first view in one round trip"; the layout is
//! [`tessera_shared::bootstrap`]'s, API.md).
//!
//! The records are read and checked as the Morton-range stream reads them
//! ([`Dataset::records`]: one read per level, each record checked against its
//! checksum once), and framed with the same [`wire`] headers, so a record in the
//! bootstrap is byte for byte the one the range stream sends. A body holds at most
//! [`bootstrap::RECORD_BUDGET`] plus the root level plus [`bootstrap::TABLE_BUDGET`]
//! (and, with `?focus=U,V`, the records around a point, [`tessera_shared::focus`],
//! within [`bootstrap::FOCUS_BUDGET`]), so it is built in memory: admitted like any
//! computed response (serve/compute/: one build per distinct body at a time, its
//! size reserved on the memory budget, up front from the index, for as long as a
//! response holds it), and the last few kept (`KEPT_BYTES`), since a body is the
//! same for every client of a dataset version and focus.

use super::datasets::describe_served;
use super::{Params, Segments, dataset, pinned, unavailable};
use crate::http::cache;
use crate::http::error::{ApiError, ApiResult, requoted};
use crate::serve::compute::{Kind, Stop, Ticket};
use crate::serve::dataset::Dataset;
use crate::serve::{AppState, TilesServed};
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, header};
use axum::response::Response;
use bytes::Bytes;
use std::collections::HashSet;
use std::sync::{Arc, Mutex, PoisonError};
use tessera_shared::bootstrap::{self, encode_head};
use tessera_shared::focus::Focus;
use tessera_shared::{ErrorTable, Level, Morton, MortonRange, TileId, morton, wire};

/// The most a body's buffer is allocated up front (it grows past it if need be).
const MAX_PLANNED_CAPACITY: u64 = 64 << 20;

/// Built bodies kept, most recent last: one per dataset version (and focus) asked for
/// lately, at most this many bytes in all.
const KEPT_BYTES: usize = 32 << 20;

/// A built bootstrap: its bytes and the records (and tables) it carries.
#[derive(Clone)]
struct Built {
    key: String,
    body: Bytes,
    tiles: u64,
}

fn kept() -> &'static Mutex<Vec<Built>> {
    static KEPT_BODIES: Mutex<Vec<Built>> = Mutex::new(Vec::new());
    &KEPT_BODIES
}

/// The whole of `level` as one Morton range.
fn whole(level: Level) -> MortonRange {
    MortonRange::new(
        Morton::from_raw(0),
        Morton::from_raw(level.tile_slots() - 1),
    )
    .expect("0 <= slots - 1")
}

/// The tiles a focus adds, level by level from the first level not carried whole
/// (`record_levels`) to the finest, coarsest first, while their records fit
/// [`bootstrap::FOCUS_BUDGET`] (sized from the index, before any read); a level
/// that does not fit ends the list, since the finer ones are reached through it.
fn focus_levels(ds: &Dataset, focus: Option<Focus>, record_levels: u8) -> Vec<Vec<TileId>> {
    let Some(focus) = focus else {
        return Vec::new();
    };
    let g = *ds.pyramid.geometry();
    let mut total = 0u64;
    let mut out = Vec::new();
    for level in g.levels().skip(usize::from(record_levels)) {
        let tiles = focus.tiles(&g, level);
        let bytes: u64 = tiles
            .iter()
            .filter_map(|t| ds.pyramid.entry(*t))
            .map(|e| u64::from(e.length))
            .sum();
        if total + bytes > bootstrap::FOCUS_BUDGET {
            break;
        }
        total += bytes;
        out.push(tiles);
    }
    out
}

/// The body's size from the index (frame headers, records and tables), before any
/// read: what its build reserves.
fn planned_bytes(
    ds: &Dataset,
    record_levels: u8,
    table_levels: u8,
    focused: &[Vec<TileId>],
) -> u64 {
    let g = *ds.pyramid.geometry();
    let table_len = ErrorTable::byte_len(g.tile_log2()) as u64;
    let frame = wire::FRAME_HEADER_LEN as u64;
    let mut total = 64 << 10; // the document and the trailer
    for level in g.levels().take(usize::from(table_levels)) {
        for t in g.present_tiles(level) {
            if let Some(e) = ds.pyramid.entry(t).filter(|e| e.length > 0) {
                total += frame
                    + if level.get() < record_levels {
                        u64::from(e.length)
                    } else {
                        table_len
                    };
            }
        }
    }
    let near = focused
        .iter()
        .flatten()
        .filter_map(|t| ds.pyramid.entry(*t))
        .map(|e| frame + u64::from(e.length));
    total + near.sum::<u64>()
}

/// Builds the body: `(bytes, tiles and tables carried, error frames)`, within the
/// memory `ticket` reserves for it.
async fn build(
    state: &AppState,
    ds: &Dataset,
    focus: Option<Focus>,
    ticket: &Ticket,
) -> Result<(Vec<u8>, u64, u64), ApiError> {
    let p = &ds.pyramid;
    let g = *p.geometry();
    let (record_levels, table_levels) = bootstrap::plan(p);
    let focused = focus_levels(ds, focus, record_levels);
    let planned = planned_bytes(ds, record_levels, table_levels, &focused);
    // The body, and a level's records read before they are copied into it.
    let _memory = ticket
        .reserve_async(2 * planned)
        .await
        .map_err(Stop::into_error)?;
    // The first part of a record: its error table (FORMAT.md "Tile record").
    let table_len = ErrorTable::byte_len(g.tile_log2());
    // Allocated once at its planned size: a vector grown by doubling would hold up
    // to twice the body, unaccounted, for as long as a client holds the response.
    // (The budgets keep a body near 14 MB; the cap only guards against an index
    // whose lengths are wrong.)
    let capacity = planned.min(MAX_PLANNED_CAPACITY);
    let mut body = Vec::with_capacity(usize::try_from(capacity).unwrap_or(0));
    body.extend(encode_head(
        &describe_served(state, ds),
        record_levels,
        table_levels,
    ));
    let (mut tiles, mut errors) = (0u64, 0u64);
    for level in g.levels() {
        let l = level.get();
        let near: HashSet<TileId> = l
            .checked_sub(record_levels)
            .and_then(|k| focused.get(usize::from(k)))
            .map(|v| v.iter().copied().collect())
            .unwrap_or_default();
        let ranges = if l < table_levels {
            vec![whole(level)]
        } else if near.is_empty() {
            break;
        } else {
            morton::coalesce(near.iter().map(|t| t.morton()))
        };
        let read = ds
            .records(level, &ranges)
            .await
            .map_err(|r| unavailable(&r))?;
        for got in read {
            let m = got.tile.morton();
            match got.record {
                None => {}
                Some(Ok((e, bytes))) => {
                    tiles += 1;
                    if l < record_levels || near.contains(&got.tile) {
                        body.extend_from_slice(&wire::tile_header(
                            level, m, e.checksum, e.min, e.max, e.length,
                        ));
                        body.extend_from_slice(&bytes);
                    } else {
                        body.extend(wire::error_table_frame(
                            level,
                            m,
                            e.min,
                            e.max,
                            &bytes[..table_len],
                        ));
                    }
                }
                Some(Err(c)) => {
                    errors += 1;
                    state.metrics.corrupt_read(c.first);
                    let msg = format!("{}: record fails its checksum; not sent", c.tile);
                    body.extend(wire::error_frame(level, m, c.entry.checksum, &msg));
                }
            }
        }
    }
    let root = Level::new(0).expect("level 0");
    body.extend(wire::trailer_frame(root, tiles, errors, &[]));
    tracing::debug!(dataset = %ds.name, planned, bytes = body.len(), "bootstrap built");
    Ok((body, tiles, errors))
}

/// Keeps a clean body, dropping the oldest beyond [`KEPT_BYTES`].
fn keep(built: Built) {
    let mut k = kept().lock().unwrap_or_else(PoisonError::into_inner);
    k.retain(|b| b.key != built.key);
    if built.body.len() > KEPT_BYTES {
        return;
    }
    k.push(built);
    while k.iter().map(|b| b.body.len()).sum::<usize>() > KEPT_BYTES {
        k.remove(0);
    }
}

/// `GET /v1/datasets/{name}/bootstrap`
pub async fn get(
    State(state): State<Arc<AppState>>,
    Segments(name): Segments<String>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    // Parsed to the four decimals of its query form, so that the ETag, the kept
    // body and the tiles all follow the same point.
    let focus = query
        .get("focus")
        .map(|f| Focus::parse(f).map_err(|e| ApiError::bad_request(requoted(&e.to_string(), f))))
        .transpose()?;
    // The document inside names the viewer unless it is off (datasets.rs).
    let variant = super::datasets::document_variant(
        &state,
        &focus.map_or_else(|| "bootstrap".to_string(), |f| format!("bootstrap@{f}")),
    );
    let pin = pinned(&ds, &query);
    let etag = cache::etag(ds.content_hash(), &variant);
    if let Some(r) = cache::revalidate(&headers, &etag, ds.last_modified, pin, state.cache_max_age)
    {
        return Ok(r);
    }
    // The document names the dataset, so the key does too.
    let key = format!(
        "{}\0{}\0{}\0{variant}",
        ds.name,
        ds.path.display(),
        ds.content_hash()
    );
    let hit = kept()
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .iter()
        .find(|b| b.key == key)
        .cloned();
    let (made, clean) = if let Some(b) = hit {
        (state.compute.hit(Kind::Bootstrap, b.body, b.tiles)?, true)
    } else {
        let (st, d) = (state.clone(), ds.clone());
        let made = state
            .compute
            .run(Kind::Bootstrap, key.clone(), move |ticket| async move {
                let (body, tiles, errors) = build(&st, &d, focus, &ticket).await?;
                let made = ticket.made(Bytes::from(body), tiles);
                if errors == 0 {
                    keep(Built {
                        key,
                        body: made.bytes.clone(),
                        tiles,
                    });
                    Ok(made)
                } else {
                    Ok(made.not_cacheable())
                }
            })
            .await?;
        let clean = made.cacheable;
        (made, clean)
    };
    let tiles = made.tiles;
    let len = made.bytes.len();
    let mut r = Response::new(made.body());
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(bootstrap::CONTENT_TYPE),
    );
    h.insert(header::CONTENT_LENGTH, HeaderValue::from(len));
    if clean {
        cache::set_headers(h, &etag, ds.last_modified, pin, state.cache_max_age);
    } else {
        // Error frames are not the dataset's content: no cache may keep this body.
        h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    }
    r.extensions_mut().insert(TilesServed(tiles));
    Ok(r)
}
