//! A level's samples over a window, and the surface `F` they define: every cell
//! split from its north-west to its south-east corner (`tessera_shared::triangulation`,
//! what the error tables measure). A tile's sides ([`super::side`]) follow `F`'s
//! profile, and the greedy mesher ([`super::greedy`]) walks its edges across `F`.
//!
//! Coordinates are the level's global sample coordinates (column east, row south),
//! as `f64`, so two tiles that evaluate `F` at the same point get the same bits.

/// Heights of a rectangle of a level's samples, `[x0, x0 + w) × [y0, y0 + h)`.
#[derive(Debug, Clone)]
pub struct HeightGrid {
    x0: u32,
    y0: u32,
    w: u32,
    h: u32,
    heights: Vec<f64>,
}

impl HeightGrid {
    /// The samples `[x0, x1] × [y0, y1]` (inclusive), read through `height(x, y)`;
    /// `None` for an empty rectangle.
    pub fn new(
        [x0, y0, x1, y1]: [u32; 4],
        mut height: impl FnMut(u32, u32) -> f64,
    ) -> Option<Self> {
        if x1 < x0 || y1 < y0 {
            return None;
        }
        let (w, h) = (x1 - x0 + 1, y1 - y0 + 1);
        let mut heights = Vec::with_capacity(w as usize * h as usize);
        for y in y0..=y1 {
            for x in x0..=x1 {
                heights.push(height(x, y));
            }
        }
        Some(Self {
            x0,
            y0,
            w,
            h,
            heights,
        })
    }

    /// The first sample (global) and the samples per side.
    pub fn frame(&self) -> [u32; 4] {
        [self.x0, self.y0, self.w, self.h]
    }

    /// The height of sample `(x, y)` (global; inside the grid).
    pub fn at(&self, x: u32, y: u32) -> f64 {
        self.heights[self.index(x, y)]
    }

    /// Every height, row-major from `(x0, y0)`.
    pub fn samples(&self) -> &[f64] {
        &self.heights
    }

    /// The index of sample `(x, y)` in row-major order.
    pub fn index(&self, x: u32, y: u32) -> usize {
        (y - self.y0) as usize * self.w as usize + (x - self.x0) as usize
    }

    /// The cell holding `(x, y)`, a point inside the grid's samples: its north-west
    /// and south-east corners and the point's offset from the first. The cell whose
    /// north-west corner is at or before the point; a point on the grid's last line
    /// belongs to the cell before it.
    fn cell(&self, x: f64, y: f64) -> ([u32; 4], f64, f64) {
        let last_x = self.x0 + self.w - 1;
        let last_y = self.y0 + self.h - 1;
        let i = (x.floor() as u32).clamp(self.x0, last_x.saturating_sub(1).max(self.x0));
        let j = (y.floor() as u32).clamp(self.y0, last_y.saturating_sub(1).max(self.y0));
        let (a, b) = (x - f64::from(i), y - f64::from(j));
        ([i, j, (i + 1).min(last_x), (j + 1).min(last_y)], a, b)
    }

    /// `F` at `(x, y)`, a point inside the grid's samples (its cell's triangle's plane).
    pub fn surface(&self, x: f64, y: f64) -> f64 {
        let ([i, j, i1, j1], a, b) = self.cell(x, y);
        let q00 = self.at(i, j);
        let q11 = self.at(i1, j1);
        if a >= b {
            let q10 = self.at(i1, j);
            q00 + (q10 - q00) * a + (q11 - q10) * b
        } else {
            let q01 = self.at(i, j1);
            q00 + (q11 - q01) * a + (q01 - q00) * b
        }
    }

    /// The bilinear surface of the samples at `(x, y)` (inside the grid), and its
    /// cell's twist `|q00 + q11 − q10 − q01|`.
    pub fn bilinear(&self, x: f64, y: f64) -> (f64, f64) {
        let ([i, j, i1, j1], a, b) = self.cell(x, y);
        let (q00, q10, q01, q11) = (
            self.at(i, j),
            self.at(i1, j),
            self.at(i, j1),
            self.at(i1, j1),
        );
        let top = q00 + a * (q10 - q00);
        let bottom = q01 + a * (q11 - q01);
        (top + b * (bottom - top), (q00 + q11 - q10 - q01).abs())
    }

    /// How far the segment from `p` (height `hp`) to `q` (height `hq`), linear in
    /// between, goes beyond a quarter of each cell's twist from the bilinear surface:
    /// the largest `|line − bilinear| − twist / 4` over the cells it crosses, and
    /// where. Exact: within a cell the difference is quadratic along the segment, so
    /// its largest size is at the piece's ends or its parabola's vertex. (Any
    /// triangulation of a cell's four samples is within a quarter of its twist of the
    /// bilinear surface, so this measures a mesh against every choice of diagonal.)
    pub fn bilinear_excess(&self, p: [f64; 2], hp: f64, q: [f64; 2], hq: f64) -> (f64, [f64; 2]) {
        let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
        let mut ts = vec![0.0, 1.0];
        crossings(p[0], dx, &mut |t| ts.push(t));
        crossings(p[1], dy, &mut |t| ts.push(t));
        ts.sort_by(f64::total_cmp);
        ts.dedup();
        let at = |t: f64| [p[0] + t * dx, p[1] + t * dy];
        let mut worst = (f64::NEG_INFINITY, p);
        for w in ts.windows(2) {
            let (ta, tb) = (w[0], w[1]);
            // The piece's cell is its middle's; the bilinear surface is continuous, so
            // its ends read the same from either side.
            let mid = at(0.5 * (ta + tb));
            let (i, j) = (mid[0].floor(), mid[1].floor());
            let twist = self.bilinear(mid[0], mid[1]).1;
            let in_cell = |t: f64| {
                let [x, y] = at(t);
                let line = hp + t * (hq - hp);
                // The cell's bilinear surface, extended to the piece's ends.
                line - self.bilinear(x.clamp(i, i + 1.0), y.clamp(j, j + 1.0)).0
            };
            let (d0, dm, d1) = (in_cell(ta), in_cell(0.5 * (ta + tb)), in_cell(tb));
            // d(s) = d0 + b·s + a·s² over the piece, s in 0..1.
            let a = 2.0 * d0 - 4.0 * dm + 2.0 * d1;
            let b = -3.0 * d0 + 4.0 * dm - d1;
            let mut candidates = vec![(d0.abs(), ta), (d1.abs(), tb)];
            if a != 0.0 {
                let s = -b / (2.0 * a);
                if s > 0.0 && s < 1.0 {
                    candidates.push(((d0 + b * s + a * s * s).abs(), ta + s * (tb - ta)));
                }
            }
            for (d, t) in candidates {
                let excess = d - twist / 4.0;
                if excess > worst.0 {
                    worst = (excess, at(t));
                }
            }
        }
        worst
    }

    /// The largest `|line − F|` along the segment from `p` (height `hp`) to `q`
    /// (height `hq`), where the line is linear in between, and where it is. Exact:
    /// both are linear between the points where the segment crosses `F`'s edges
    /// (grid lines and north-west diagonals), and those are the points measured.
    /// (The tests' measure of a side against `F`.)
    #[cfg(test)]
    pub(crate) fn segment_error(
        &self,
        p: [f64; 2],
        hp: f64,
        q: [f64; 2],
        hq: f64,
    ) -> (f64, [f64; 2]) {
        let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
        let mut worst = (0.0_f64, p);
        let mut at = |t: f64| {
            let (x, y) = (p[0] + t * dx, p[1] + t * dy);
            let line = hp + t * (hq - hp);
            let e = (line - self.surface(x, y)).abs();
            if e > worst.0 {
                worst = (e, [x, y]);
            }
        };
        crossings(p[0], dx, &mut at);
        crossings(p[1], dy, &mut at);
        // North-west diagonals: x − y is an integer.
        crossings(p[0] - p[1], dx - dy, &mut at);
        worst
    }
}

/// Calls `at(t)` for each `t` strictly between 0 and 1 where `start + t·delta` is an
/// integer (where a segment crosses a family of grid lines).
fn crossings(start: f64, delta: f64, at: &mut dyn FnMut(f64)) {
    if delta == 0.0 {
        return;
    }
    let end = start + delta;
    let (lo, hi) = (start.min(end), start.max(end));
    let mut k = lo.floor() + 1.0;
    while k < hi {
        let t = (k - start) / delta;
        if t > 0.0 && t < 1.0 {
            at(t);
        }
        k += 1.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn saddle() -> HeightGrid {
        // q00 = 0, q10 = 10, q01 = 10, q11 = 0 on one cell, flat around.
        HeightGrid::new([0, 0, 1, 1], |x, y| if x == y { 0.0 } else { 10.0 }).unwrap()
    }

    #[test]
    fn the_surface_is_the_north_west_diagonal_triangulation() {
        let g = saddle();
        assert_eq!(g.surface(0.0, 0.0), 0.0);
        assert_eq!(g.surface(1.0, 0.0), 10.0);
        // On the diagonal: the mean of its ends, 0 (the other diagonal would give 10).
        assert_eq!(g.surface(0.5, 0.5), 0.0);
        assert_eq!(g.surface(0.75, 0.25), 5.0);
        // The grid's last line belongs to the cell before it.
        assert_eq!(g.surface(1.0, 1.0), 0.0);
        assert_eq!(g.surface(0.0, 1.0), 10.0);
        // Agrees with the shared integer triangulation.
        let c = tessera_shared::triangulation::Cell {
            q00: 0,
            q10: 10,
            q01: 10,
            q11: 0,
        };
        for (a, b) in [(1_i32, 3_i32), (3, 1), (2, 2), (0, 4)] {
            let want = c.scaled_height(4, a.into(), b.into()) as f64 / 4.0;
            assert_eq!(g.surface(f64::from(a) / 4.0, f64::from(b) / 4.0), want);
        }
    }

    #[test]
    fn bilinear_excess_finds_the_parabolas_vertex_beyond_the_twist() {
        let g = saddle();
        // Across the anti-diagonal the bilinear surface dips to 5 at the centre; a
        // line at 13 is 8 above it there, 3 beyond the cell's twist / 4 (20 / 4).
        let (e, at) = g.bilinear_excess([1.0, 0.0], 13.0, [0.0, 1.0], 13.0);
        assert!(
            (e - 3.0).abs() < 1e-12 && (at[0] - 0.5).abs() < 1e-12,
            "{e} at {at:?}"
        );
        // At the corners' heights it stays within the allowance.
        assert!(g.bilinear_excess([1.0, 0.0], 10.0, [0.0, 1.0], 10.0).0 <= 1e-12);
    }

    #[test]
    fn segment_error_finds_the_kink_between_samples() {
        let g = saddle();
        // Along the anti-diagonal from (1,0) to (0,1): the line stays at 10 while F
        // dips to 0 where it crosses the north-west diagonal, at (0.5, 0.5).
        let e = g.segment_error([1.0, 0.0], 10.0, [0.0, 1.0], 10.0);
        assert_eq!(e, (10.0, [0.5, 0.5]));
        // Along the diagonal itself F is linear: no error.
        assert_eq!(g.segment_error([0.0, 0.0], 0.0, [1.0, 1.0], 0.0).0, 0.0);
        // A segment along a grid line between samples: exact at its ends only.
        assert_eq!(g.segment_error([0.0, 0.0], 0.0, [1.0, 0.0], 10.0).0, 0.0);
    }
}
