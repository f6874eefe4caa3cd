//! Waiting for tiles: a settled frame (everything its selection asks for resident
//! before it is drawn) and the reference's finest tiles are fetched until they are
//! all in the pool, or a limit passes.

use crate::select::Wanted;
use crate::stream::Streamer;
use crate::stream::pool::TilePool;
use std::time::{Duration, Instant};
use tessera_shared::TileId;

/// How long a settled frame may wait for its tiles, and the reference for its
/// finest tiles.
pub(crate) const SETTLE_TIMEOUT: Duration = Duration::from_secs(120);

/// Fetches `tiles` into the pool, waiting up to `timeout` for all of them but
/// those the server says are absent (no record: wholly no-data).
pub fn fetch_tiles(
    tiles: &[TileId],
    pool: &mut TilePool,
    streamer: &mut Streamer,
    timeout: Duration,
) -> anyhow::Result<()> {
    let started = Instant::now();
    loop {
        let missing: Vec<Wanted> = tiles
            .iter()
            .filter(|t| !pool.contains(**t) && !pool.is_absent(**t))
            .map(|&tile| Wanted { tile, rho: 1.0 })
            .collect();
        if missing.is_empty() {
            pool.touch(tiles);
            return Ok(());
        }
        if let Some(w) = missing.iter().find(|w| streamer.written_off(w.tile)) {
            anyhow::bail!(
                "{} was written off as corrupt{}",
                w.tile,
                streamer
                    .last_error
                    .as_ref()
                    .map(|e| format!(" (last error: {e})"))
                    .unwrap_or_default()
            );
        }
        anyhow::ensure!(
            started.elapsed() < timeout,
            "{} tiles still missing after {timeout:?}{}",
            missing.len(),
            streamer
                .last_error
                .as_ref()
                .map(|e| format!(" (last error: {e})"))
                .unwrap_or_default()
        );
        streamer.frame(pool, &missing, &[]);
        pool.touch(tiles);
        std::thread::sleep(Duration::from_millis(5));
    }
}
