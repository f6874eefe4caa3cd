//! Contour lines through a grid of heights by marching squares: each cell between
//! four samples holds a straight piece of every level its corners straddle, with the
//! point on each cell edge interpolated linearly between the edge's samples; pieces
//! sharing an edge point join into lines. A saddle cell (diagonal corners on the
//! same side) is decided by the mean of its corners, as `gdal_contour` decides it.
//!
//! A level `L = k · interval` separates samples at or above it from those below;
//! samples are classified once by `floor(h / interval)`, so the count of pieces
//! ([`Contouring::segments`]) and the tracing agree exactly.

use std::collections::HashMap;

/// The most line pieces a tile may hold (about one per cell of a 512-pixel tile's
/// grid, and a few MB of tile): more and the lines lie closer than a pixel apart.
pub const MAX_SEGMENTS: u64 = 300_000;

/// Heights on a `width × height` grid, row-major from the north-west; only samples
/// flagged `valid` (terrain) are contoured, and a cell only with four of them.
#[derive(Clone, Copy, Debug)]
pub struct Grid<'a> {
    pub width: usize,
    pub height: usize,
    pub heights: &'a [f64],
    pub valid: &'a [bool],
}

/// One contour line: its level index `k` (elevation `k · interval`) and its points in
/// grid coordinates (`[column, row]`, sample centres at whole numbers). A closed line
/// ends on its first point.
#[derive(Clone, Debug, PartialEq)]
pub struct Line {
    pub level: i64,
    pub points: Vec<[f64; 2]>,
}

impl Line {
    /// Whether the line is a ring.
    pub fn is_closed(&self) -> bool {
        self.points.len() > 2 && self.points.first() == self.points.last()
    }
}

/// A grid's samples classified by level, ready to count and trace.
#[derive(Debug)]
pub struct Contouring<'a> {
    grid: Grid<'a>,
    interval: f64,
    /// `floor(h / interval)` of each valid sample, `None` for the rest.
    step: Vec<Option<i64>>,
}

/// Edge ids: the horizontal edge east of sample `s` is `2s`, the vertical one south
/// of it `2s + 1`.
const fn east(s: usize) -> u32 {
    (2 * s) as u32
}
const fn south(s: usize) -> u32 {
    (2 * s + 1) as u32
}

impl<'a> Contouring<'a> {
    /// Lines every `interval` metres (positive) through `grid`.
    pub fn new(grid: Grid<'a>, interval: f64) -> Self {
        assert!(interval > 0.0, "a positive interval");
        assert_eq!(grid.heights.len(), grid.width * grid.height);
        assert_eq!(grid.valid.len(), grid.heights.len());
        let step = grid
            .heights
            .iter()
            .zip(grid.valid)
            .map(|(&h, &v)| (v && h.is_finite()).then(|| (h / interval).floor() as i64))
            .collect();
        Self {
            grid,
            interval,
            step,
        }
    }

    /// The four corners' steps of the cell south-east of sample `s` (north-west,
    /// north-east, south-east, south-west), when all are valid.
    fn corners(&self, s: usize) -> Option<[i64; 4]> {
        let w = self.grid.width;
        Some([
            self.step[s]?,
            self.step[s + 1]?,
            self.step[s + w + 1]?,
            self.step[s + w]?,
        ])
    }

    /// The cells' north-west samples.
    fn cells(&self) -> impl Iterator<Item = usize> + '_ {
        let w = self.grid.width;
        (0..self.grid.height.saturating_sub(1))
            .flat_map(move |r| (0..w.saturating_sub(1)).map(move |c| r * w + c))
    }

    /// How many level crossings the grid's cells hold: the line pieces of tracing,
    /// less one per saddle. One pass, no allocation: what bounds a tile's work.
    pub fn segments(&self) -> u64 {
        self.cells()
            .filter_map(|s| self.corners(s))
            .map(|q| {
                let lo = q.iter().min().copied().unwrap_or_default();
                let hi = q.iter().max().copied().unwrap_or_default();
                (hi - lo) as u64
            })
            .sum()
    }

    /// The point where level `k` crosses edge `e`.
    fn point(&self, k: i64, e: u32) -> [f64; 2] {
        let w = self.grid.width;
        let s = (e / 2) as usize;
        let (r, c) = ((s / w) as f64, (s % w) as f64);
        let horizontal = e.is_multiple_of(2);
        let other = if horizontal { s + 1 } else { s + w };
        let (h0, h1) = (self.grid.heights[s], self.grid.heights[other]);
        let level = k as f64 * self.interval;
        let t = if h1 == h0 {
            0.5
        } else {
            ((level - h0) / (h1 - h0)).clamp(0.0, 1.0)
        };
        if horizontal { [c + t, r] } else { [c, r + t] }
    }

    /// The pieces of every level in every cell, as edge pairs.
    fn pieces(&self) -> Vec<(i64, u32, u32)> {
        let w = self.grid.width;
        let mut out = Vec::new();
        for s in self.cells() {
            let Some(q) = self.corners(s) else { continue };
            let lo = q.iter().min().copied().unwrap_or_default();
            let hi = q.iter().max().copied().unwrap_or_default();
            if lo == hi {
                continue;
            }
            // The cell's edges: north, east, south, west.
            let edges = [east(s), south(s + 1), east(s + w), south(s)];
            let h = self.grid.heights;
            let mean = (h[s] + h[s + 1] + h[s + w + 1] + h[s + w]) / 4.0;
            let centre = (mean / self.interval).floor() as i64;
            for k in lo + 1..=hi {
                let above = q.map(|v| v >= k);
                // Edge i joins corners i and i + 1.
                let cut: Vec<usize> = (0..4).filter(|&i| above[i] != above[(i + 1) % 4]).collect();
                if let [a, b] = cut.as_slice() {
                    out.push((k, edges[*a], edges[*b]));
                } else {
                    // A saddle: the corners on the centre's side connect through it;
                    // each other corner is cut off by the two edges at it (corner i
                    // lies between edges i - 1 and i).
                    let centre_above = centre >= k;
                    for i in (0..4).filter(|&i| above[i] != centre_above) {
                        out.push((k, edges[(i + 3) % 4], edges[i]));
                    }
                }
            }
        }
        out
    }

    /// The lines, each piece joined to its neighbours across shared edge points.
    pub fn lines(&self) -> Vec<Line> {
        let pieces = self.pieces();
        // Each edge point of a level belongs to at most two pieces.
        let mut at: HashMap<(i64, u32), [u32; 2]> = HashMap::with_capacity(pieces.len() * 2);
        for (i, &(k, a, b)) in pieces.iter().enumerate() {
            for e in [a, b] {
                at.entry((k, e))
                    .and_modify(|p| p[1] = i as u32)
                    .or_insert([i as u32, u32::MAX]);
            }
        }
        let mut used = vec![false; pieces.len()];
        // From piece `from` across edge `e`: the next piece and its far edge.
        let next = |used: &[bool], k: i64, e: u32, from: usize| -> Option<(usize, u32)> {
            let pair = at.get(&(k, e))?;
            let n = pair
                .iter()
                .map(|&p| p as usize)
                .find(|&p| p != from && p < used.len())?;
            if used[n] {
                return None;
            }
            let (_, a, b) = pieces[n];
            Some((n, if a == e { b } else { a }))
        };
        let walk = |used: &mut Vec<bool>, k: i64, start: usize, mut e: u32| -> Vec<u32> {
            let mut edges = Vec::new();
            let mut from = start;
            while let Some((n, far)) = next(used, k, e, from) {
                used[n] = true;
                edges.push(far);
                from = n;
                e = far;
            }
            edges
        };
        let mut lines = Vec::new();
        for i in 0..pieces.len() {
            if used[i] {
                continue;
            }
            used[i] = true;
            let (k, a, b) = pieces[i];
            let forward = walk(&mut used, k, i, b);
            let closed = forward.last() == Some(&a);
            let mut edges = Vec::with_capacity(forward.len() + 2);
            if !closed {
                let mut backward = walk(&mut used, k, i, a);
                backward.reverse();
                edges.extend(backward);
            }
            edges.push(a);
            edges.push(b);
            edges.extend(forward);
            lines.push(Line {
                level: k,
                points: edges.into_iter().map(|e| self.point(k, e)).collect(),
            });
        }
        lines
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(width: usize, heights: &[f64]) -> (usize, usize, Vec<f64>, Vec<bool>) {
        let valid = heights.iter().map(|h| h.is_finite()).collect();
        (width, heights.len() / width, heights.to_vec(), valid)
    }

    fn trace(width: usize, heights: &[f64], interval: f64) -> (u64, Vec<Line>) {
        let (w, h, heights, valid) = grid(width, heights);
        let g = Grid {
            width: w,
            height: h,
            heights: &heights,
            valid: &valid,
        };
        let c = Contouring::new(g, interval);
        (c.segments(), c.lines())
    }

    /// Bilinear height at grid point `p` of a `w`-wide grid.
    fn bilinear(w: usize, h: &[f64], p: [f64; 2]) -> f64 {
        let (c, r) = (p[0].floor().min((w - 2) as f64), p[1].floor());
        let (fx, fy) = (p[0] - c, p[1] - r);
        let s = r as usize * w + c as usize;
        let top = h[s] * (1.0 - fx) + h[s + 1] * fx;
        let bottom = h[s + w] * (1.0 - fx) + h[s + w + 1] * fx;
        top * (1.0 - fy) + bottom * fy
    }

    #[test]
    fn a_cone_gives_closed_rings_at_every_level_on_their_height() {
        let n = 41;
        let heights: Vec<f64> = (0..n * n)
            .map(|i| {
                let (x, y) = ((i % n) as f64 - 20.0, (i / n) as f64 - 20.0);
                (95.0 - 4.0 * (x * x + y * y).sqrt()).max(15.0)
            })
            .collect();
        let (segments, lines) = trace(n, &heights, 10.0);
        // Rings at 20, 30, … 90 m, the widest 18.75 samples from the peak.
        let mut levels: Vec<i64> = lines.iter().map(|l| l.level).collect();
        levels.sort_unstable();
        assert_eq!(levels, vec![2, 3, 4, 5, 6, 7, 8, 9]);
        for l in &lines {
            assert!(l.is_closed(), "level {} is a ring", l.level);
            for p in &l.points {
                let h = bilinear(n, &heights, *p);
                // On a cell edge, bilinear is the edge's linear interpolation.
                assert!((h - l.level as f64 * 10.0).abs() < 1e-9, "{p:?}: {h}");
            }
        }
        let pieces: usize = lines.iter().map(|l| l.points.len() - 1).sum();
        assert_eq!(pieces as u64, segments);
    }

    #[test]
    fn a_slope_gives_one_open_line_per_level_across_the_grid() {
        let (w, h) = (7, 5);
        // Rising 3 m per column eastward: levels at 5, 10, 15 m.
        let heights: Vec<f64> = (0..w * h).map(|i| 1.0 + 3.0 * (i % w) as f64).collect();
        let (_, lines) = trace(w, &heights, 5.0);
        assert_eq!(lines.len(), 3);
        for l in &lines {
            assert!(!l.is_closed());
            assert_eq!(l.points.len(), h, "one point per row");
            let x = (l.level as f64 * 5.0 - 1.0) / 3.0;
            assert!(l.points.iter().all(|p| (p[0] - x).abs() < 1e-12));
        }
    }

    #[test]
    fn saddles_follow_the_cell_mean_and_voids_break_lines() {
        // A saddle: high north-west and south-east, mean 7.
        let saddle = [10.0, 4.0, 4.0, 10.0];
        let cut = |lines: &[Line]| -> Vec<[f64; 2]> {
            let mut mids: Vec<[f64; 2]> = lines
                .iter()
                .map(|l| {
                    let [a, b] = [l.points[0], l.points[1]];
                    [f64::midpoint(a[0], b[0]), f64::midpoint(a[1], b[1])]
                })
                .collect();
            mids.sort_by(|a, b| a.partial_cmp(b).unwrap());
            mids
        };
        // Level 6 m (centre above): the high corners connect; pieces cut off the low
        // corners (north-east, south-west).
        let (_, l4) = trace(2, &saddle, 6.0);
        assert_eq!(l4.len(), 2);
        let m = cut(&l4);
        assert!(
            m[0][0] < 0.5 && m[0][1] > 0.5 && m[1][0] > 0.5 && m[1][1] < 0.5,
            "{m:?}"
        );
        // Level 8 m (centre below): pieces near the high corners (north-west, south-east).
        let (_, l6) = trace(2, &saddle, 8.0);
        assert_eq!(l6.len(), 2);
        let m = cut(&l6);
        assert!(
            m[0][0] < 0.5 && m[0][1] < 0.5 && m[1][0] > 0.5 && m[1][1] > 0.5,
            "{m:?}"
        );

        // A void column splits a slope's lines in two.
        let (w, h) = (7, 4);
        let heights: Vec<f64> = (0..w * h)
            .map(|i| {
                if i / w == 1 && i % w == 3 {
                    f64::NAN
                } else {
                    (i / w) as f64 * 3.0
                }
            })
            .collect();
        let (_, lines) = trace(w, &heights, 4.0);
        // Level 4 m crosses the cells between rows 1 and 2, two of which touch the void.
        assert_eq!(lines.iter().filter(|l| l.level == 1).count(), 2);
    }

    #[test]
    fn flat_and_void_grids_have_no_lines() {
        let (s, lines) = trace(3, &[5.0; 9], 1.0);
        assert_eq!((s, lines.len()), (0, 0));
        let (s, lines) = trace(3, &[f64::NAN; 9], 1.0);
        assert_eq!((s, lines.len()), (0, 0));
    }
}
