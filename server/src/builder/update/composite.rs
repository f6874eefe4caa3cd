//! The raster an update measures tiles on: the new inputs' samples inside the changed
//! area (read into a sparse spool), the old pyramid's finest records elsewhere (the
//! same quantized samples a whole build of the new inputs would read there).

use crate::ingest::raster::{DepthCounts, Raster, all_valid_depth_counts};
use anyhow::Context;
use std::collections::HashMap;
use std::sync::Mutex;
use tessera_shared::reader::{FileSource, Pyramid};
use tessera_shared::{TileGeometry, TileId};

/// Decoded finest tiles kept at once (the tiler reads in Morton order, and each
/// tile's coarse corners from a few tiles around it).
const CACHED_TILES: usize = 64;

pub(super) struct Composite<'a> {
    pub(super) g: TileGeometry,
    /// The new samples: valid inside `changed`.
    pub(super) new: &'a dyn Raster,
    pub(super) old: &'a Pyramid<FileSource>,
    /// Rectangles `[x0, y0, x1, y1)` of samples that may have changed.
    pub(super) changed: &'a [[u32; 4]],
    cache: Mutex<HashMap<(u32, u32), std::sync::Arc<Vec<u16>>>>,
}

impl<'a> Composite<'a> {
    pub(super) fn new(
        g: TileGeometry,
        new: &'a dyn Raster,
        old: &'a Pyramid<FileSource>,
        changed: &'a [[u32; 4]],
    ) -> Self {
        Self {
            g,
            new,
            old,
            changed,
            cache: Mutex::new(HashMap::new()),
        }
    }

    fn is_changed(&self, x: u32, y: u32) -> bool {
        self.changed
            .iter()
            .any(|&[x0, y0, x1, y1]| (x0..x1).contains(&x) && (y0..y1).contains(&y))
    }

    /// The old finest tile holding sample `(x, y)` as its `(T+1)²` heights.
    fn old_tile(&self, tx: u32, ty: u32) -> anyhow::Result<std::sync::Arc<Vec<u16>>> {
        let mut cache = self
            .cache
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(t) = cache.get(&(tx, ty)) {
            return Ok(t.clone());
        }
        let tile = TileId::new(self.g.finest(), tx, ty).context("a sample beyond the grid")?;
        let rec = self
            .old
            .read_tile(tile)?
            .with_context(|| format!("the old pyramid has no finest tile {tx}, {ty}"))?;
        let heights = std::sync::Arc::new(rec.heights);
        if cache.len() >= CACHED_TILES {
            cache.clear();
        }
        cache.insert((tx, ty), heights.clone());
        Ok(heights)
    }

    fn sample(&self, x: u32, y: u32) -> anyhow::Result<u16> {
        if self.is_changed(x, y) {
            let mut v = [0u16];
            self.new.read_window(x, y, 1, 1, &mut v)?;
            return Ok(v[0]);
        }
        let t = self.g.tile_size();
        // The last column (row) of a DEM whose cells are a multiple of T is the last
        // tile's shared edge: no tile starts there.
        let last = |n: u32| n.saturating_sub(2) / t;
        let (tx, ty) = (
            (x / t).min(last(self.g.width())),
            (y / t).min(last(self.g.height())),
        );
        let side = t as usize + 1;
        let heights = self.old_tile(tx, ty)?;
        Ok(heights[(y - ty * t) as usize * side + (x - tx * t) as usize])
    }
}

impl Raster for Composite<'_> {
    fn width(&self) -> u32 {
        self.g.width()
    }

    fn height(&self) -> u32 {
        self.g.height()
    }

    fn read_window(&self, x0: u32, y0: u32, w: u32, h: u32, out: &mut [u16]) -> anyhow::Result<()> {
        let inside = self
            .changed
            .iter()
            .any(|&[a, b, c, d]| a <= x0 && b <= y0 && x0 + w <= c && y0 + h <= d);
        if inside {
            return self.new.read_window(x0, y0, w, h, out);
        }
        for r in 0..h {
            for c in 0..w {
                out[(r * w + c) as usize] = self.sample(x0 + c, y0 + r)?;
            }
        }
        Ok(())
    }

    fn depth_counts(&self) -> DepthCounts {
        all_valid_depth_counts(self.g.width(), self.g.height())
    }
}
