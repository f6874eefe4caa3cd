//! The raster an update measures tiles on: the new inputs' samples inside the changed
//! area (read into a sparse spool), the old pyramid's finest records elsewhere (the
//! same quantized samples a whole build of the new inputs would read there).

use crate::ingest::raster::{DepthCounts, Raster, all_valid_depth_counts};
use anyhow::Context;
use std::collections::HashMap;
use std::sync::Mutex;
use tessera_shared::reader::{FileSource, Pyramid};
use tessera_shared::{TileGeometry, TileId};

/// A decoded finest record's `(T+1)²` heights.
type Heights = std::sync::Arc<Vec<u16>>;

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
    cache: Mutex<HashMap<(u32, u32), Heights>>,
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

    /// The old finest tile holding sample `(x, y)` as its `(T+1)²` heights.
    fn old_tile(&self, tx: u32, ty: u32) -> anyhow::Result<Heights> {
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

    /// The old finest tile whose record holds sample column (row) `v`: the last
    /// column (row) of a DEM whose cells are a multiple of T is the last tile's
    /// shared edge, where no tile starts.
    fn owner(&self, v: u32, n: u32) -> u32 {
        let t = self.g.tile_size();
        (v / t).min(n.saturating_sub(2) / t)
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
        let (x1, y1) = (x0 + w, y0 + h);
        let inside = self
            .changed
            .iter()
            .any(|&[a, b, c, d]| a <= x0 && b <= y0 && x1 <= c && y1 <= d);
        if inside {
            return self.new.read_window(x0, y0, w, h, out);
        }
        // The old records' samples, tile by tile (a record holds its shared east and
        // south edges too, so a finest tile's window is one record) ...
        let t = self.g.tile_size();
        let side = t as usize + 1;
        let (ox, oy) = (
            self.owner(x0, self.g.width()),
            self.owner(y0, self.g.height()),
        );
        if x1 - 1 <= ox * t + t && y1 - 1 <= oy * t + t {
            let heights = self.old_tile(ox, oy)?;
            for y in y0..y1 {
                let src = (y - oy * t) as usize * side + (x0 - ox * t) as usize;
                let dst = ((y - y0) * w) as usize;
                out[dst..dst + w as usize].copy_from_slice(&heights[src..src + w as usize]);
            }
            return self.overlay_changed(x0, y0, w, h, out);
        }
        let (tx0, tx1) = (
            self.owner(x0, self.g.width()),
            self.owner(x1 - 1, self.g.width()),
        );
        let (ty0, ty1) = (
            self.owner(y0, self.g.height()),
            self.owner(y1 - 1, self.g.height()),
        );
        for ty in ty0..=ty1 {
            let rows = y0.max(ty * t)..if ty == ty1 { y1 } else { y1.min((ty + 1) * t) };
            for tx in tx0..=tx1 {
                let cols = x0.max(tx * t)..if tx == tx1 { x1 } else { x1.min((tx + 1) * t) };
                let heights = self.old_tile(tx, ty)?;
                for y in rows.clone() {
                    let src = (y - ty * t) as usize * side + (cols.start - tx * t) as usize;
                    let dst = ((y - y0) * w + (cols.start - x0)) as usize;
                    out[dst..dst + cols.len()].copy_from_slice(&heights[src..src + cols.len()]);
                }
            }
        }
        self.overlay_changed(x0, y0, w, h, out)
    }

    fn depth_counts(&self) -> DepthCounts {
        all_valid_depth_counts(self.g.width(), self.g.height())
    }
}

impl Composite<'_> {
    /// Writes the new samples over `out` (the window `x0, y0, w, h`) where they may
    /// have changed.
    fn overlay_changed(
        &self,
        x0: u32,
        y0: u32,
        w: u32,
        h: u32,
        out: &mut [u16],
    ) -> anyhow::Result<()> {
        let (x1, y1) = (x0 + w, y0 + h);
        let mut part = Vec::new();
        for &[a, b, c, d] in self.changed {
            let (ax, ay, cx, cy) = (a.max(x0), b.max(y0), c.min(x1), d.min(y1));
            if ax >= cx || ay >= cy {
                continue;
            }
            let pw = cx - ax;
            part.resize((pw * (cy - ay)) as usize, 0);
            self.new.read_window(ax, ay, pw, cy - ay, &mut part)?;
            for (r, row) in part.chunks_exact(pw as usize).enumerate() {
                let dst = ((ay - y0 + r as u32) * w + (ax - x0)) as usize;
                out[dst..dst + pw as usize].copy_from_slice(row);
            }
        }
        Ok(())
    }
}
