//! How a build divides its `--memory` budget (`--memory` bounds every allocation of a
//! build: docs/ARCHITECTURE.md#bad-input-is-an-error).
//!
//! A build runs in two phases that never overlap: spooling the input (one band of
//! rows) and tiling (finest tiles in flight, waiting siblings per level, write
//! buffers). Everything that does not shrink with the budget is counted as fixed;
//! what is left sets the band height and the batch of finest tiles in flight. A
//! budget that cannot hold the fixed part is refused before anything is allocated,
//! naming what it would take.

use super::spool::{BAND_BYTES_PER_SAMPLE, SPOOL_BUFFER};
use super::writer::{INDEX_RUN_BYTES, SINK_BUFFER};
use anyhow::bail;
use tessera_shared::TileGeometry;

/// Allocator slack, stacks, the progress bars and the finishing passes' 2 MiB chunks:
/// what the process needs beyond the counted buffers.
pub const OVERHEAD: u64 = 16 << 20;
/// Most finest tiles in flight; more buys no parallelism on the machines we target.
const MAX_BATCH: u64 = 64;

/// The budget's division for one build.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Plan {
    /// Bytes for one band of spooled rows.
    pub band_bytes: usize,
    /// Finest tiles per batch (three batches are alive at once: queued, being made,
    /// being written).
    pub batch: usize,
    /// Bytes the tiling phase needs whatever the batch.
    pub fixed_bytes: u64,
}

fn mib(bytes: u64) -> u64 {
    bytes.div_ceil(1 << 20)
}

impl Plan {
    /// `input_bytes`: what the input itself holds in memory (the synthetic terrain's
    /// coarse grid; 0 for spooled files).
    pub fn new(geometry: &TileGeometry, input_bytes: u64, budget: u64) -> anyhow::Result<Self> {
        let side = geometry.tile_samples() as u64;
        let levels = u64::from(geometry.level_count());
        let spacings = u64::from(geometry.tile_log2()) + levels;
        // A tile in memory: heights, block errors for every spacing, block ranges,
        // and its validity mask (one bit per cell).
        let node = side * side * 2 + spacings * 64 * 8 + 64 * 4 + (side - 1) * (side - 1) / 8 + 8;
        // One in flight: its node and its encoded record (at most the raw heights).
        let in_flight = node + side * side * 2 + 1024;
        // Per worker thread while making a tile: the read window, scratch rows, and
        // the codec's buffers (about two tiles' worth), and the window's validity
        // flags (one byte per sample) where the input had no-data.
        let threads = rayon::current_num_threads() as u64;
        let worker = side * side * 7;
        // Up to three waiting siblings at every level but the root, plus, where a
        // parent is being made, its four children and itself.
        let pending = (3 * levels + 2) * node;
        let writer = levels * (SINK_BUFFER as u64 + INDEX_RUN_BYTES as u64);
        let fixed_bytes = OVERHEAD + input_bytes + pending + writer + threads * worker;
        let at_least = fixed_bytes + 3 * in_flight;
        if budget < at_least {
            bail!(
                "--memory {} MiB is too small for --tile-size {} on a {}×{} DEM: the build \
                 needs at least {} MiB (raise --memory or use a smaller --tile-size)",
                budget >> 20,
                geometry.tile_size(),
                geometry.width(),
                geometry.height(),
                mib(at_least)
            );
        }
        let batch = ((budget - fixed_bytes) / (3 * in_flight)).clamp(1, MAX_BATCH);
        // Spooling: the band, the spool's write buffer, the (already open) writer's
        // buffers and the same overhead.
        let spool_fixed = OVERHEAD + input_bytes + writer + SPOOL_BUFFER as u64;
        let band_bytes = budget.saturating_sub(spool_fixed);
        let row = u64::from(geometry.width()) * BAND_BYTES_PER_SAMPLE as u64;
        // Two rows at least: the row above the band is kept as context for the fill.
        if band_bytes < 2 * row {
            bail!(
                "--memory {} MiB is too small for rows of {} samples: spooling needs at \
                 least {} MiB",
                budget >> 20,
                geometry.width(),
                mib(spool_fixed + 2 * row)
            );
        }
        Ok(Self {
            band_bytes: usize::try_from(band_bytes).unwrap_or(usize::MAX),
            batch: batch as usize,
            fixed_bytes,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_budget_too_small_for_big_tiles_is_refused_with_what_it_needs() {
        let g = TileGeometry::new(65_537, 65_537, 4096).unwrap();
        let err = Plan::new(&g, 0, 256 << 20).unwrap_err().to_string();
        assert!(
            err.contains("--memory 256 MiB is too small for --tile-size 4096"),
            "{err}"
        );
        let needed: u64 = err
            .split("at least ")
            .nth(1)
            .and_then(|r| r.split(' ').next())
            .and_then(|n| n.parse().ok())
            .expect("the error names the memory needed");
        // What it names is enough.
        assert!(Plan::new(&g, 0, needed << 20).is_ok());
        assert!(Plan::new(&g, 0, (needed - 1) << 20).is_err());
    }

    #[test]
    fn the_batch_grows_with_the_budget_and_stays_inside_it() {
        let g = TileGeometry::new(8193, 8193, 512).unwrap();
        let small = Plan::new(&g, 0, 64 << 20).unwrap();
        let big = Plan::new(&g, 0, 512 << 20).unwrap();
        assert!(small.batch >= 1 && big.batch > small.batch);
        let side = g.tile_samples() as u64;
        for (p, budget) in [(small, 64u64 << 20), (big, 512 << 20)] {
            let in_flight = 3 * p.batch as u64 * (side * side * 4);
            assert!(p.fixed_bytes + in_flight <= budget, "{p:?}");
            assert!(p.band_bytes as u64 <= budget);
        }
    }
}
