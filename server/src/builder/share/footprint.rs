//! What a part of a distributed build reads of its input: the samples its subtrees
//! cover, and the few samples beyond them that its error tables measure against.
//!
//! - **Windows.** Each of the part's split-level tiles covers `F + 1` samples a side
//!   (`F = T · 2^(L − S)` cells, the last row and column shared with the neighbour),
//!   clipped to the DEM. Every finest tile of the subtree reads inside it.
//! - **Points.** A finest tile's errors are measured against the corners of the
//!   coarse cells (spacings `2T … 2^(T + L)`) around it (Kang §4.1, `finest.rs`). Cells
//!   no larger than `F` have their corners inside the window; a larger cell holds the
//!   whole subtree, so its four corners (clamped to the DEM's last sample, as the tiler
//!   clamps them) are the same for every tile of the subtree. Those outside the
//!   windows are read one sample each.
//! - **Runs.** Read top to bottom: between consecutive window edges the same set of
//!   column ranges is read, so the reader is told the columns once per run and skips
//!   the rows no window covers.

use std::collections::BTreeSet;
use std::ops::Range;
use tessera_shared::{Level, Morton, TileGeometry, TileId};

/// A rectangle of samples: columns `x`, rows `y`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Window {
    pub x: Range<u32>,
    pub y: Range<u32>,
}

impl Window {
    fn contains(&self, (x, y): (u32, u32)) -> bool {
        self.x.contains(&x) && self.y.contains(&y)
    }

    fn samples(&self) -> u64 {
        u64::from(self.x.len() as u32) * u64::from(self.y.len() as u32)
    }
}

/// Rows `rows`, of which the columns `columns` (sorted, disjoint) are read.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Run {
    pub rows: Range<u32>,
    pub columns: Vec<Range<u32>>,
}

/// The samples a part reads ([`Footprint::of`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Footprint {
    pub windows: Vec<Window>,
    /// Coarse-cell corners outside every window.
    pub points: Vec<(u32, u32)>,
}

impl Footprint {
    /// The samples the subtrees of the level-`split` tiles `tops` read.
    pub fn of(g: &TileGeometry, split: Level, tops: Range<u64>) -> Self {
        Self::of_tiles(g, split, tops)
    }

    /// The samples the subtrees of the level-`split` tiles with Morton codes `codes`
    /// read (for the finest level: those tiles, for `build --update`).
    pub fn of_tiles(g: &TileGeometry, split: Level, codes: impl IntoIterator<Item = u64>) -> Self {
        let t = g.tile_log2();
        let below = u32::from(g.finest().get() - split.get());
        // Cells of a split-level tile, a side.
        let f = 1u64 << (t + below);
        let (w, h) = (u64::from(g.width()), u64::from(g.height()));
        let (last_x, last_y) = (w - 1, h - 1);
        let mut windows = Vec::new();
        let mut corners = BTreeSet::new();
        for m in codes {
            let tile = TileId::from_morton(split, Morton::from_raw(m)).expect("m < 4^S");
            let (x0, y0) = (u64::from(tile.x()) * f, u64::from(tile.y()) * f);
            if x0 >= w || y0 >= h {
                continue;
            }
            windows.push(Window {
                x: x0 as u32..(x0 + f + 1).min(w) as u32,
                y: y0 as u32..(y0 + f + 1).min(h) as u32,
            });
            // Spacings the pyramid measures: 2^0 ..= 2^(t + L); those above `f`.
            for k in t + below + 1..=t + u32::from(g.finest().get()) {
                let s = 1u64 << k;
                let (cx, cy) = (x0 / s * s, y0 / s * s);
                for (x, y) in [(cx, cy), (cx + s, cy), (cx, cy + s), (cx + s, cy + s)] {
                    corners.insert((x.min(last_x) as u32, y.min(last_y) as u32));
                }
            }
        }
        let points = corners
            .into_iter()
            .filter(|&p| !windows.iter().any(|w| w.contains(p)))
            .collect();
        Self { windows, points }
    }

    /// Samples read in all (windows may share their edge rows and columns).
    pub fn samples(&self) -> u64 {
        self.windows.iter().map(Window::samples).sum::<u64>() + self.points.len() as u64
    }

    /// The rows to read, top to bottom, with their columns; rows between runs are
    /// skipped.
    pub fn runs(&self) -> Vec<Run> {
        let rects: Vec<Window> = self
            .windows
            .iter()
            .cloned()
            .chain(self.points.iter().map(|&(x, y)| Window {
                x: x..x + 1,
                y: y..y + 1,
            }))
            .collect();
        let edges: BTreeSet<u32> = rects.iter().flat_map(|r| [r.y.start, r.y.end]).collect();
        let edges: Vec<u32> = edges.into_iter().collect();
        let mut runs: Vec<Run> = Vec::new();
        for pair in edges.windows(2) {
            let rows = pair[0]..pair[1];
            let mut spans: Vec<Range<u32>> = rects
                .iter()
                .filter(|r| r.y.start <= rows.start && rows.end <= r.y.end)
                .map(|r| r.x.clone())
                .collect();
            if spans.is_empty() {
                continue;
            }
            spans.sort_by_key(|r| r.start);
            let mut columns: Vec<Range<u32>> = Vec::new();
            for s in spans {
                match columns.last_mut() {
                    Some(last) if s.start <= last.end => last.end = last.end.max(s.end),
                    _ => columns.push(s),
                }
            }
            // Adjacent runs over the same columns read as one.
            match runs.last_mut() {
                Some(last) if last.rows.end == rows.start && last.columns == columns => {
                    last.rows.end = rows.end;
                }
                _ => runs.push(Run { rows, columns }),
            }
        }
        runs
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every sample the tiler reads for one finest tile: the tile (its padding clamped
    /// to the DEM) and the coarse corners around it, as `finest.rs` reads them.
    fn tiler_reads(g: &TileGeometry, tile: TileId) -> Vec<(u32, u32)> {
        let side = g.tile_samples() as u64;
        let (gx0, gy0) = g.origin(tile);
        let (w, h) = (u64::from(g.width()), u64::from(g.height()));
        let mut out = Vec::new();
        for y in gy0..(gy0 + side).min(h) {
            for x in gx0..(gx0 + side).min(w) {
                out.push((x as u32, y as u32));
            }
        }
        let spacings = g.tile_log2() + u32::from(g.finest().get()) + 1;
        for k in g.tile_log2() + 1..spacings {
            let s = 1u64 << k;
            let (cx, cy) = (gx0 / s * s, gy0 / s * s);
            for (x, y) in [(cx, cy), (cx + s, cy), (cx, cy + s), (cx + s, cy + s)] {
                out.push(((x.min(w - 1)) as u32, (y.min(h - 1)) as u32));
            }
        }
        out
    }

    #[test]
    fn a_part_reads_every_sample_its_tiles_read_and_little_else() {
        for (w, h, t, n) in [
            (1025, 1025, 64, 16u32),
            (1201, 700, 64, 4),
            (300, 1000, 64, 7),
        ] {
            let g = TileGeometry::new(w, h, t).unwrap();
            // As a distributed build splits: the smallest level with 4^S ≥ 4N, its codes
            // cut into N runs (here evenly; the build balances present tiles).
            let s = (1..=g.finest().get())
                .find(|&l| 1u64 << (2 * u32::from(l)) >= 4 * u64::from(n))
                .unwrap_or(g.finest().get());
            let level = Level::new(s).unwrap();
            let codes = 1u64 << (2 * u32::from(s));
            let mut total = 0;
            for k in 0..n {
                let tops =
                    codes * u64::from(k) / u64::from(n)..codes * u64::from(k + 1) / u64::from(n);
                let fp = Footprint::of(&g, level, tops.clone());
                let runs = fp.runs();
                let read = |(x, y): (u32, u32)| {
                    runs.iter()
                        .any(|r| r.rows.contains(&y) && r.columns.iter().any(|c| c.contains(&x)))
                };
                let finest = g.finest();
                let depth = 2 * u32::from(finest.get() - level.get());
                for m in tops.start << depth..tops.end << depth {
                    let tile = TileId::from_morton(finest, Morton::from_raw(m)).unwrap();
                    if !g.is_present(tile) {
                        continue;
                    }
                    for p in tiler_reads(&g, tile) {
                        assert!(read(p), "{w}×{h} part {k}/{n}: {p:?} of {tile:?} not read");
                    }
                }
                // Runs are ordered, disjoint, and their columns sorted and apart.
                for pair in runs.windows(2) {
                    assert!(pair[0].rows.end <= pair[1].rows.start);
                }
                for r in &runs {
                    for c in r.columns.windows(2) {
                        assert!(c[0].end < c[1].start);
                    }
                }
                total += fp.samples();
            }
            // All parts together read the DEM once, plus the shared edges and a few
            // corner samples.
            let whole = u64::from(w) * u64::from(h);
            assert!(total >= whole, "{w}×{h}/{n}: {total} < {whole}");
            assert!(
                total * 10 < whole * 12,
                "{w}×{h}/{n}: {total} read of {whole}"
            );
        }
    }

    #[test]
    fn coarse_corners_beyond_the_window_are_points() {
        // 1025² at tile 64: L = 4. Split at level 2 (n = 4): windows of 257 samples.
        let g = TileGeometry::new(1025, 1025, 64).unwrap();
        let fp = Footprint::of(&g, Level::new(2).unwrap(), 5..6);
        // Tile 5 at level 2 is (3, 0): columns 768..1025, rows 0..257.
        assert_eq!(
            fp.windows,
            vec![Window {
                x: 768..1025,
                y: 0..257
            }]
        );
        // Cells of 512 and 1024 around it: corners (512, 0), (1024, 0), (512, 512),
        // (1024, 512), (0, 0), (0, 1024), (1024, 1024); those in the window dropped.
        assert_eq!(
            fp.points,
            vec![
                (0, 0),
                (0, 1024),
                (512, 0),
                (512, 512),
                (1024, 512),
                (1024, 1024)
            ]
        );
    }
}
