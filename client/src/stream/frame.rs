//! A streamer's per-frame work (the module documentation of `stream`): accepting
//! decoded tiles into the pool within the budget, cancelling what is no longer
//! wanted, retrying with backoff, and issuing the wanted tiles' requests.

use super::config::RequestMode;
use super::fetch::{Blame, Decoded, Event, fetch, fetch_one, fetch_range};
use super::pool::TilePool;
use super::static_file::{self, StaticFile};
use super::stats::FrameWork;
use super::streamer::{Backend, Flight, Streamer};
use crate::select::Wanted;
use std::collections::HashSet;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tessera_shared::{Level, Morton, TileId, api, morton, range_query};

/// Most codes one trailer may mark absent: far more than one request names
/// ([`StreamConfig::max_tiles_per_request`](super::StreamConfig::max_tiles_per_request)), so a hostile trailer cannot make the
/// frame thread walk a huge range.
const MAX_ABSENT_PER_TRAILER: usize = 1 << 16;

impl Streamer {
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
        for run in static_file::byte_runs(&present) {
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
