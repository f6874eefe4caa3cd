//! An adaptive triangulation of one pyramid level's samples with a guaranteed error
//! bound, whose choices near any line between two squares depend only on the samples
//! around that line — so two Cesium tiles that both hold the line choose the same
//! vertices on it (DECISIONS.md "Cesium terrain").
//!
//! The mesh is a right-triangulated irregular network (RTIN, the "4-8" longest-edge
//! bisection of Evans et al., as Martini builds it) over the level's global sample
//! grid, in three steps:
//!
//! 1. **Forced base.** The grid is cut into squares of `S = 2^j` cells, aligned to
//!    multiples of `S`; every square's corners and centre are vertices. That gives
//!    four triangles per square whose hypotenuses are the square's edges.
//! 2. **Vertex errors, bottom up.** Each further vertex `m` is the midpoint of the
//!    hypotenuse shared by a "diamond" of two triangles. Its error `V(m)` bounds the
//!    vertical distance between either triangle's plane and the finer surface under
//!    it: `V(m) = d(m) + max V(children)`, where `d(m)` is `m`'s distance from the
//!    hypotenuse's midpoint height and the children are the four vertices the two
//!    triangles split into next. It is a *sum*, not Martini's max: for a point `p` in a
//!    child `c` of `T`, `|T(p) − F(p)| ≤ |T(p) − c(p)| + |c(p) − F(p)| ≤ d(m) + err(c)`,
//!    so the bound is conservative rather than a heuristic. `V` only grows towards the
//!    root, which makes "split when `V(m) > τ`" conforming (no T-junctions), as in
//!    Martini. A diamond on a square's edge reaches half a square into each
//!    neighbour, and nothing else: a tile that reads one ring of squares around the
//!    ones it draws knows every `V` it uses exactly.
//! 3. **Top down.** From the four base triangles of each square, split while the
//!    hypotenuse midpoint's `V` exceeds `τ`.
//!
//! The surface `F` the bound is measured against is the level's samples
//! triangulated as the error tables measure them (`tessera_shared::triangulation`:
//! every cell split north-west to south-east). RTIN's own cells alternate their
//! diagonals, so where a cell's RTIN diagonal is the other one, the smallest
//! triangles differ from `F` by up to half the cell's twist
//! `|q00 + q11 − q10 − q01| / 2`; that is each leaf's error. At the finest level
//! the truth is the samples themselves and every leaf is exact at them.

/// A sample of the level's global grid: column east, row south, from the north-west.
pub type Lattice = [u32; 2];

/// The level's heights over a window of whole squares, and the errors computed there.
#[derive(Debug)]
pub struct Window {
    /// Square size `S` in cells (a power of two, at least 2).
    square: u32,
    /// First sample (global) and samples per side.
    x0: u32,
    y0: u32,
    w: u32,
    h: u32,
    /// Cells per side of the whole level grid (squares never reach beyond it).
    grid: u32,
    heights: Vec<f64>,
    /// Vertex errors, `f64::INFINITY` for forced vertices; NaN where not computed.
    errors: Vec<f64>,
}

/// How leaves are measured (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Truth {
    /// The level is the finest: the samples are the data; every leaf is exact.
    Samples,
    /// A coarser level: measured against its north-west-diagonal triangulation.
    NorthWestDiagonal,
}

impl Window {
    /// A window of squares `[sx0, sx1) × [sy0, sy1)` (square units) of a level grid
    /// with `grid` cells per side, heights read through `height(x, y)`.
    ///
    /// `None` when the square size is not a power of two ≥ 2 dividing the grid, or
    /// the squares are empty or leave the grid.
    pub fn new(
        square: u32,
        grid: u32,
        squares: [u32; 4],
        mut height: impl FnMut(u32, u32) -> f64,
    ) -> Option<Self> {
        let [sx0, sy0, sx1, sy1] = squares;
        let ok = square >= 2
            && square.is_power_of_two()
            && grid.is_multiple_of(square)
            && sx0 < sx1
            && sy0 < sy1
            && sx1 * square <= grid
            && sy1 * square <= grid;
        if !ok {
            return None;
        }
        let (x0, y0) = (sx0 * square, sy0 * square);
        let (w, h) = ((sx1 - sx0) * square + 1, (sy1 - sy0) * square + 1);
        let mut heights = Vec::with_capacity((w * h) as usize);
        for y in y0..y0 + h {
            for x in x0..x0 + w {
                heights.push(height(x, y));
            }
        }
        Some(Self {
            square,
            x0,
            y0,
            w,
            h,
            grid,
            heights,
            errors: vec![f64::NAN; (w * h) as usize],
        })
    }

    fn contains(&self, x: i64, y: i64) -> bool {
        x >= i64::from(self.x0)
            && y >= i64::from(self.y0)
            && x < i64::from(self.x0 + self.w)
            && y < i64::from(self.y0 + self.h)
    }

    fn idx(&self, x: u32, y: u32) -> usize {
        ((y - self.y0) * self.w + (x - self.x0)) as usize
    }

    /// The height of a sample inside the window.
    pub fn height(&self, [x, y]: Lattice) -> f64 {
        self.heights[self.idx(x, y)]
    }

    /// The error of the cell whose north-west corner is `(x, y)` as a leaf: zero where
    /// RTIN splits it north-west to south-east (or the truth is the samples), else half
    /// its twist. RTIN's cell diagonals all pass through the centre of their 2×2 square.
    fn leaf(&self, truth: Truth, x: u32, y: u32) -> f64 {
        if truth == Truth::Samples || (x % 2) == (y % 2) {
            return 0.0;
        }
        let q = |dx, dy| self.heights[self.idx(x + dx, y + dy)];
        0.5 * (q(0, 0) + q(1, 1) - q(1, 0) - q(0, 1)).abs()
    }

    /// `V` of a vertex: its stored error, or 0 outside the window (a child that does
    /// not exist because it is beyond the grid contributes nothing).
    fn v(&self, x: i64, y: i64) -> f64 {
        if self.contains(x, y) {
            self.errors[self.idx(x as u32, y as u32)]
        } else {
            0.0
        }
    }

    /// Computes every vertex error in the window (step 2 of the module doc), finest
    /// first: `E(2), C(2), E(4), C(4), …, E(S)`, where `E(s)` are the midpoints of the
    /// edges of `s`-squares and `C(s)` their centres.
    ///
    /// Values near the window's outer edge are incomplete (their diamonds leave the
    /// window); only those of vertices in squares with a full ring of window squares
    /// around them (or the grid's edge) are exact, and only those may be used.
    pub fn compute_errors(&mut self, truth: Truth) {
        let mut s = 2;
        while s <= self.square {
            self.edge_midpoints(s, truth);
            if s < self.square {
                self.centres(s);
            }
            s *= 2;
        }
        // The forced base: corners and centres of the S-squares.
        let big = self.square;
        for y in (self.y0..self.y0 + self.h).step_by(big as usize / 2) {
            for x in (self.x0..self.x0 + self.w).step_by(big as usize / 2) {
                let (cx, cy) = ((x - self.x0) % big, (y - self.y0) % big);
                let corner = cx == 0 && cy == 0;
                let centre = cx == big / 2 && cy == big / 2;
                if corner || centre {
                    let i = self.idx(x, y);
                    self.errors[i] = f64::INFINITY;
                }
            }
        }
    }

    /// `E(s)`: midpoints of horizontal and vertical `s`-edges.
    fn edge_midpoints(&mut self, s: u32, truth: Truth) {
        let half = s / 2;
        let quarter = i64::from(s / 4);
        for y in (self.y0..self.y0 + self.h).step_by(half as usize) {
            for x in (self.x0..self.x0 + self.w).step_by(half as usize) {
                let (rx, ry) = ((x - self.x0) % s, (y - self.y0) % s);
                // Horizontal edge: (x ± half, y); vertical: (x, y ± half).
                let horizontal = rx == half && ry == 0;
                let vertical = rx == 0 && ry == half;
                if !horizontal && !vertical {
                    continue;
                }
                let (ax, ay, bx, by) = if horizontal {
                    (x - half, y, x + half, y)
                } else {
                    (x, y - half, x, y + half)
                };
                let d = (self.height([x, y])
                    - 0.5 * (self.height([ax, ay]) + self.height([bx, by])))
                .abs();
                let (xi, yi) = (i64::from(x), i64::from(y));
                let grid = i64::from(self.grid);
                let mut worst = 0.0_f64;
                // The two triangles: apexes half an edge away on either side.
                for side in [-1_i64, 1] {
                    let (apx, apy) = if horizontal {
                        (xi, yi + side * i64::from(half))
                    } else {
                        (xi + side * i64::from(half), yi)
                    };
                    if apx < 0 || apy < 0 || apx > grid || apy > grid {
                        continue;
                    }
                    if s == 2 {
                        // Children are half-cells of the two cells between the edge
                        // and the apex.
                        let cells = if horizontal {
                            let cy = if side < 0 { yi - 1 } else { yi };
                            [(xi - 1, cy), (xi, cy)]
                        } else {
                            let cx = if side < 0 { xi - 1 } else { xi };
                            [(cx, yi - 1), (cx, yi)]
                        };
                        for (cx, cy) in cells {
                            if self.contains(cx, cy) && self.contains(cx + 1, cy + 1) {
                                worst = worst.max(self.leaf(truth, cx as u32, cy as u32));
                            }
                        }
                    } else {
                        // Children: centres of the two s/2-squares between edge and apex.
                        let kids = if horizontal {
                            let cy = yi + side * quarter;
                            [(xi - quarter, cy), (xi + quarter, cy)]
                        } else {
                            let cx = xi + side * quarter;
                            [(cx, yi - quarter), (cx, yi + quarter)]
                        };
                        for (kx, ky) in kids {
                            worst = worst.max(self.v(kx, ky));
                        }
                    }
                }
                let i = self.idx(x, y);
                self.errors[i] = d + worst;
            }
        }
    }

    /// `C(s)`, `s < S`: centres of `s`-squares; their diamond's hypotenuse is the
    /// square's diagonal through the parent `2s`-square's centre.
    fn centres(&mut self, s: u32) {
        let half = s / 2;
        for y in (self.y0 + half..self.y0 + self.h).step_by(s as usize) {
            for x in (self.x0 + half..self.x0 + self.w).step_by(s as usize) {
                let (i, j) = ((x - half) / s, (y - half) / s);
                // The parent's centre is this square's corner towards the parent's middle.
                let px = if i % 2 == 0 { x + half } else { x - half };
                let py = if j % 2 == 0 { y + half } else { y - half };
                let (qx, qy) = (2 * x - px, 2 * y - py);
                let d = (self.height([x, y])
                    - 0.5 * (self.height([px, py]) + self.height([qx, qy])))
                .abs();
                let (xi, yi, hi) = (i64::from(x), i64::from(y), i64::from(half));
                let worst = [(xi - hi, yi), (xi + hi, yi), (xi, yi - hi), (xi, yi + hi)]
                    .into_iter()
                    .map(|(a, b)| self.v(a, b))
                    .fold(0.0_f64, f64::max);
                let k = self.idx(x, y);
                self.errors[k] = d + worst;
            }
        }
    }

    /// The error of a vertex (after [`Window::compute_errors`]).
    pub fn error(&self, [x, y]: Lattice) -> f64 {
        self.errors[self.idx(x, y)]
    }

    /// Triangles of square `(sx, sy)` (square units) at threshold `tau`, as lattice
    /// triples `(a, b, apex)`; each is pushed to `out`.
    ///
    /// The square must have its ring of neighbours in the window (or lie at the grid's
    /// edge) for the choices on its edges to be exact (see [`Window::compute_errors`]).
    pub fn triangulate_square(&self, sx: u32, sy: u32, tau: f64, out: &mut Vec<[Lattice; 3]>) {
        let s = self.square;
        let (x0, y0) = (sx * s, sy * s);
        let c = [x0 + s / 2, y0 + s / 2];
        let nw = [x0, y0];
        let ne = [x0 + s, y0];
        let se = [x0 + s, y0 + s];
        let sw = [x0, y0 + s];
        for (a, b) in [(nw, ne), (ne, se), (se, sw), (sw, nw)] {
            self.split(a, b, c, tau, out);
        }
    }

    fn split(&self, a: Lattice, b: Lattice, c: Lattice, tau: f64, out: &mut Vec<[Lattice; 3]>) {
        let leaf = a[0].abs_diff(b[0]) == 1 && a[1].abs_diff(b[1]) == 1;
        if !leaf {
            let m = [u32::midpoint(a[0], b[0]), u32::midpoint(a[1], b[1])];
            if self.error(m) > tau {
                self.split(c, a, m, tau, out);
                self.split(b, c, m, tau, out);
                return;
            }
        }
        out.push([a, b, c]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::{HashMap, HashSet};

    /// A rough deterministic surface (xorshift noise plus a ridge).
    fn terrain(x: u32, y: u32) -> f64 {
        let mut s = (u64::from(x) * 0x9E37_79B9) ^ (u64::from(y) * 0x85EB_CA6B) ^ 0x1234_5678;
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        let noise = (s % 1000) as f64 / 100.0;
        let ridge = 200.0 - (f64::from(x) - f64::from(y)).abs() * 3.0;
        noise + ridge.max(0.0) + f64::from(x) * 0.5
    }

    /// The plane of triangle `t` at `p` (barycentric), or `None` outside it.
    fn plane_at(w: &Window, t: &[Lattice; 3], p: [f64; 2]) -> Option<f64> {
        let f = |v: Lattice| [f64::from(v[0]), f64::from(v[1])];
        let (a, b, c) = (f(t[0]), f(t[1]), f(t[2]));
        let det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
        let l1 = ((p[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (p[1] - a[1])) / det;
        let l2 = ((b[0] - a[0]) * (p[1] - a[1]) - (p[0] - a[0]) * (b[1] - a[1])) / det;
        let l0 = 1.0 - l1 - l2;
        let eps = -1e-12;
        (l0 >= eps && l1 >= eps && l2 >= eps)
            .then(|| l0 * w.height(t[0]) + l1 * w.height(t[1]) + l2 * w.height(t[2]))
    }

    fn window(square: u32, grid: u32) -> Window {
        let n = grid / square;
        let mut w = Window::new(square, grid, [0, 0, n, n], terrain).unwrap();
        w.compute_errors(Truth::Samples);
        w
    }

    #[test]
    fn every_sample_is_within_tau_of_the_mesh() {
        let w = window(16, 64);
        for tau in [0.5, 3.0, 10.0, 40.0] {
            let mut tris = Vec::new();
            for sy in 0..4 {
                for sx in 0..4 {
                    w.triangulate_square(sx, sy, tau, &mut tris);
                }
            }
            for y in 0..=64 {
                for x in 0..=64 {
                    let p = [f64::from(x), f64::from(y)];
                    let t = tris
                        .iter()
                        .find_map(|t| plane_at(&w, t, p))
                        .expect("the mesh covers the grid");
                    let err = (t - w.height([x, y])).abs();
                    assert!(err <= tau + 1e-9, "tau {tau}: error {err} at ({x}, {y})");
                }
            }
            // Adaptive: far fewer triangles than the full grid at a loose threshold.
            if tau >= 10.0 {
                assert!(tris.len() < 2 * 64 * 64 / 2, "{} triangles", tris.len());
            }
        }
    }

    #[test]
    fn the_mesh_is_conforming() {
        // Every edge is shared by two triangles or lies on the grid's border, and no
        // vertex lies inside another triangle's edge (a T-junction).
        let w = window(16, 64);
        let mut tris = Vec::new();
        for sy in 0..4 {
            for sx in 0..4 {
                w.triangulate_square(sx, sy, 4.0, &mut tris);
            }
        }
        let mut edges: HashMap<(Lattice, Lattice), u32> = HashMap::new();
        let verts: HashSet<Lattice> = tris.iter().flatten().copied().collect();
        for t in &tris {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *edges
                    .entry(if a < b { (a, b) } else { (b, a) })
                    .or_default() += 1;
                // No vertex strictly inside this edge.
                let (dx, dy) = (
                    i64::from(b[0]) - i64::from(a[0]),
                    i64::from(b[1]) - i64::from(a[1]),
                );
                let g = dx.abs().max(dy.abs());
                for s in 1..g {
                    let p = [
                        (i64::from(a[0]) + dx * s / g) as u32,
                        (i64::from(a[1]) + dy * s / g) as u32,
                    ];
                    let on = (dx * s) % g == 0 && (dy * s) % g == 0;
                    assert!(
                        !(on && verts.contains(&p)),
                        "T-junction at {p:?} on {a:?}-{b:?}"
                    );
                }
            }
        }
        for ((a, b), n) in edges {
            let border = |v: Lattice| v[0] == 0 || v[1] == 0 || v[0] == 64 || v[1] == 64;
            let on_border = border(a) && border(b) && (a[0] == b[0] || a[1] == b[1]);
            assert!(
                n == 2 || (n == 1 && on_border),
                "edge {a:?}-{b:?} used {n} times"
            );
        }
    }

    #[test]
    fn a_window_with_a_ring_agrees_with_the_whole_grid() {
        // The choices inside square (2, 2) from a 3×3 window of squares equal those
        // from the whole grid: the ring is all a tile needs.
        let whole = window(8, 64);
        let mut part = Window::new(8, 64, [1, 1, 4, 4], terrain).unwrap();
        part.compute_errors(Truth::Samples);
        for tau in [0.5, 2.0, 8.0] {
            let (mut a, mut b) = (Vec::new(), Vec::new());
            whole.triangulate_square(2, 2, tau, &mut a);
            part.triangulate_square(2, 2, tau, &mut b);
            assert_eq!(a, b, "tau {tau}");
        }
    }

    #[test]
    fn leaves_of_a_coarse_level_count_the_twist() {
        // A saddle cell: F (north-west diagonal) and RTIN's other diagonal differ by
        // half the twist at the cell centre; V of the cell's E(2) neighbours holds it.
        let saddle = |x: u32, y: u32| {
            if (x, y) == (1, 0) || (x, y) == (0, 1) {
                10.0
            } else {
                0.0
            }
        };
        let mut w = Window::new(2, 2, [0, 0, 1, 1], saddle).unwrap();
        w.compute_errors(Truth::NorthWestDiagonal);
        // Cell (0,0) is split NW-SE by RTIN: no twist error; the others are flat.
        assert_eq!(w.leaf(Truth::NorthWestDiagonal, 0, 0), 0.0);
        let twisted = |x: u32, y: u32| {
            if (x, y) == (2, 0) || (x, y) == (1, 1) {
                10.0
            } else {
                0.0
            }
        };
        let mut w2 = Window::new(2, 2, [0, 0, 1, 1], twisted).unwrap();
        // q00 = q11 = 0, q10 = q01 = 10: F is 0 at the centre, the other diagonal 10.
        assert_eq!(w2.leaf(Truth::NorthWestDiagonal, 1, 0), 10.0);
        assert_eq!(w2.leaf(Truth::Samples, 1, 0), 0.0);
        // The top edge's midpoint (1, 0): d = |0 − (0 + 10)/2| = 5, plus the twist.
        w2.compute_errors(Truth::NorthWestDiagonal);
        assert_eq!(w2.error([1, 0]), 15.0);
    }

    #[test]
    fn bad_windows_are_refused() {
        assert!(Window::new(3, 12, [0, 0, 1, 1], terrain).is_none());
        assert!(Window::new(8, 12, [0, 0, 1, 1], terrain).is_none());
        assert!(Window::new(4, 16, [0, 0, 5, 1], terrain).is_none());
        assert!(Window::new(4, 16, [1, 0, 1, 1], terrain).is_none());
    }
}
