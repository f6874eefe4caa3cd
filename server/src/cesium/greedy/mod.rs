//! Greedy insertion into a Delaunay triangulation: Garland & Heckbert, "Fast
//! Polygonal Approximation of Terrains and Height Fields" (1995), §4 — the
//! algorithm Delatin and `hmm` implement. Start from a coarse triangulation, then
//! repeatedly insert the sample farthest (vertically) from the mesh and restore the
//! Delaunay property by edge flips (Lawson), until every sample is within `tau`.
//! Each triangle keeps its worst sample as a candidate in a max-heap, so an
//! insertion rescans only the triangles it changed (G&H §5, "candidate per
//! triangle").
//!
//! What is ours: the start is the tile's outline with the side points its
//! neighbours also choose ([`super::side`]), which insertions never move (a side is
//! a hull edge, and hull edges are never flipped); only samples strictly inside the
//! outline are candidates. The bound is at the samples, which is exact where the
//! samples are the data (the finest level: the only level this mesher is used at).
//! And between samples: G&H measure only samples, so a long edge can pass over a
//! cell far from it (3.6 m on a 1.18 m threshold at a landmark in the Alps). Each
//! inner edge is walked across the cells it crosses against the samples' bilinear
//! surface ([`HeightGrid::bilinear_excess`], exact: the difference is quadratic
//! along a piece), allowing a quarter of each cell's twist (what any choice of the
//! cell's diagonal differs from the bilinear surface by); where it strays by more
//! than `tau` beyond that, the nearest corner of that cell that is not yet a vertex
//! is inserted, until no edge strays. Inside a triangle the difference is a
//! hyperbolic paraboloid, largest on its edges, so the mesh is then within
//! `tau + twist / 4` of the bilinear surface everywhere but in the cells a side cuts or
//! touches, whose corners on or beyond the side are not candidates. Coarser levels,
//! where the level's north-west-diagonal surface is the truth everywhere and strays
//! at the sides cannot be left, keep the RTIN of [`super::mesh`].
//!
//! Positions are local to the grid (small numbers, exact for samples) and the
//! orientation and in-circle tests are Shewchuk's exact predicates (`robust`), so
//! a sample on an edge is on it for both triangles, and ties (a grid's cocircular
//! cells) never flip: the same input always gives the same mesh.

mod between;

use super::side::SidePoint;
use super::surface::HeightGrid;
use std::collections::BinaryHeap;

const NONE: u32 = u32::MAX;

/// A greedy mesh: positions in the level's global sample coordinates, heights,
/// and triangles (positively oriented in sample space: column east, row south).
#[derive(Debug, Default)]
pub struct GreedyMesh {
    pub points: Vec<[f64; 2]>,
    pub heights: Vec<f64>,
    pub triangles: Vec<[u32; 3]>,
    /// The threshold it was made with.
    pub tau: f64,
}

/// Meshes the rectangle `[x0, y0, x1, y1]` (global sample coordinates, inside
/// `grid`) whose outline is `outline` (the side points, positively oriented, from
/// the north-west corner: north side west to east, east side, south side east to
/// west, west side), with every sample strictly inside within `tau` of the mesh.
pub fn mesh(grid: &HeightGrid, rect: [f64; 4], outline: &[SidePoint], tau: f64) -> GreedyMesh {
    let mut g = Greedy::new(grid, rect, outline);
    g.run(tau);
    let n = (g.tris.len() / 3) as u32;
    g.changed = (0..n).collect();
    g.is_changed = vec![true; n as usize];
    // Between samples: where an edge strays more than `tau` (beyond a quarter of the
    // cell's twist) from the samples' bilinear surface, a corner of the cell where
    // it strays most becomes a vertex, until none does (or the cell's corners are
    // all vertices, or beyond the rectangle's inside). Each pass adds a sample or
    // stops.
    while g.refine_between(tau) {
        g.run(tau);
    }
    g.finish(tau)
}

struct Greedy<'a> {
    grid: &'a HeightGrid,
    /// The grid's first sample: local = global − origin.
    origin: [f64; 2],
    /// Candidate samples (global, inclusive): strictly inside the rectangle.
    cand: [i64; 4],
    pts: Vec<[f64; 2]>,
    z: Vec<f64>,
    tris: Vec<u32>,
    half: Vec<u32>,
    /// Per triangle: its worst candidate (grid index) and error.
    best: Vec<(f64, u32)>,
    generation: Vec<u32>,
    heap: BinaryHeap<(u64, u32, u32)>,
    /// Samples already vertices (grid index).
    used: Vec<bool>,
    /// Triangles changed by the current insertion, to rescan.
    pending: Vec<u32>,
    stamp: Vec<u32>,
    round: u32,
    /// Triangles changed since the last pass between samples (`refine_between`
    /// walks only their edges), marked per triangle.
    changed: Vec<u32>,
    is_changed: Vec<bool>,
}

fn orient(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    let p = |v: [f64; 2]| robust::Coord { x: v[0], y: v[1] };
    robust::orient2d(p(a), p(b), p(c))
}

fn in_circle(a: [f64; 2], b: [f64; 2], c: [f64; 2], d: [f64; 2]) -> bool {
    let p = |v: [f64; 2]| robust::Coord { x: v[0], y: v[1] };
    robust::incircle(p(a), p(b), p(c), p(d)) > 0.0
}

fn next(e: u32) -> u32 {
    if e % 3 == 2 { e - 2 } else { e + 1 }
}

fn prev(e: u32) -> u32 {
    if e.is_multiple_of(3) { e + 2 } else { e - 1 }
}

impl<'a> Greedy<'a> {
    fn new(grid: &'a HeightGrid, rect: [f64; 4], outline: &[SidePoint]) -> Self {
        let [gx, gy, gw, gh] = grid.frame();
        let origin = [f64::from(gx), f64::from(gy)];
        let cand = [
            rect[0].floor() as i64 + 1,
            rect[1].floor() as i64 + 1,
            rect[2].ceil() as i64 - 1,
            rect[3].ceil() as i64 - 1,
        ];
        let mut g = Self {
            grid,
            origin,
            cand,
            pts: Vec::new(),
            z: Vec::new(),
            tris: Vec::new(),
            half: Vec::new(),
            best: Vec::new(),
            generation: Vec::new(),
            heap: BinaryHeap::new(),
            used: vec![false; gw as usize * gh as usize],
            pending: Vec::new(),
            stamp: Vec::new(),
            round: 0,
            changed: Vec::new(),
            is_changed: Vec::new(),
        };
        for p in outline {
            g.pts.push([p.x - origin[0], p.y - origin[1]]);
            g.z.push(p.h);
        }
        g.start(outline, rect);
        g
    }

    /// The outline: two triangles between the corners, then every other side point
    /// split into the hull edge it lies on.
    fn start(&mut self, outline: &[SidePoint], rect: [f64; 4]) {
        let is_corner = |p: &SidePoint| {
            (p.x == rect[0] || p.x == rect[2]) && (p.y == rect[1] || p.y == rect[3])
        };
        let corners: Vec<u32> = (0..outline.len() as u32)
            .filter(|&i| is_corner(&outline[i as usize]))
            .collect();
        let [nw, ne, se, sw] = [corners[0], corners[1], corners[2], corners[3]];
        let t0 = self.add_triangle(nw, ne, se);
        let t1 = self.add_triangle(nw, se, sw);
        // The diagonal: edge se→nw of t0 (position 2) and nw→se of t1 (position 0).
        self.link(3 * t0 + 2, 3 * t1);
        self.round += 1;
        let n = outline.len() as u32;
        for i in 0..n {
            if is_corner(&outline[i as usize]) {
                continue;
            }
            // The hull edge holding point i: from the previous point inserted to the
            // next corner along the outline.
            let from = i - 1;
            let to = (i + 1..n)
                .chain(0..i)
                .find(|&k| is_corner(&outline[k as usize]))
                .unwrap_or(0);
            let e = (0..self.tris.len() as u32)
                .find(|&e| {
                    self.half[e as usize] == NONE
                        && self.tris[e as usize] == from
                        && self.tris[next(e) as usize] == to
                })
                .expect("the point's hull edge");
            self.insert(e / 3, i);
        }
        self.pending.clear();
    }

    fn add_triangle(&mut self, a: u32, b: u32, c: u32) -> u32 {
        let t = (self.tris.len() / 3) as u32;
        self.tris.extend([a, b, c]);
        self.half.extend([NONE; 3]);
        self.best.push((0.0, NONE));
        self.generation.push(0);
        self.stamp.push(0);
        self.is_changed.push(false);
        t
    }

    fn set_triangle(&mut self, t: u32, [a, b, c]: [u32; 3]) {
        let e = 3 * t as usize;
        self.tris[e..e + 3].copy_from_slice(&[a, b, c]);
    }

    fn link(&mut self, a: u32, b: u32) {
        if a != NONE {
            self.half[a as usize] = b;
        }
        if b != NONE {
            self.half[b as usize] = a;
        }
    }

    fn touch(&mut self, t: u32) {
        if self.stamp[t as usize] != self.round {
            self.stamp[t as usize] = self.round;
            self.pending.push(t);
        }
        if !self.is_changed[t as usize] {
            self.is_changed[t as usize] = true;
            self.changed.push(t);
        }
    }

    fn pos(&self, v: u32) -> [f64; 2] {
        self.pts[v as usize]
    }

    /// Inserts vertex `p`, which lies in triangle `t` or on one of its edges.
    fn insert(&mut self, t: u32, p: u32) {
        let e0 = 3 * t;
        let pp = self.pos(p);
        let on = (0..3).map(|k| e0 + k).find(|&e| {
            orient(
                self.pos(self.tris[e as usize]),
                self.pos(self.tris[next(e) as usize]),
                pp,
            ) == 0.0
        });
        match on {
            None => self.insert_inside(t, p),
            Some(e) => self.insert_on_edge(e, p),
        }
    }

    fn insert_inside(&mut self, t: u32, p: u32) {
        let e = 3 * t as usize;
        let [a, b, c] = [self.tris[e], self.tris[e + 1], self.tris[e + 2]];
        let [hab, hbc, hca] = [self.half[e], self.half[e + 1], self.half[e + 2]];
        let t0 = t;
        self.set_triangle(t0, [a, b, p]);
        let t1 = self.add_triangle(b, c, p);
        let t2 = self.add_triangle(c, a, p);
        self.link(3 * t0, hab);
        self.link(3 * t1, hbc);
        self.link(3 * t2, hca);
        self.link(3 * t0 + 1, 3 * t1 + 2);
        self.link(3 * t1 + 1, 3 * t2 + 2);
        self.link(3 * t2 + 1, 3 * t0 + 2);
        for k in [t0, t1, t2] {
            self.touch(k);
        }
        self.legalize(3 * t0);
        self.legalize(3 * t1);
        self.legalize(3 * t2);
    }

    /// `p` on edge `e` (a→b of triangle (a, b, c)), and on its twin (b→a of
    /// (b, a, d)) unless it is a hull edge.
    fn insert_on_edge(&mut self, e: u32, p: u32) {
        let f = self.half[e as usize];
        let (a, b, c) = (
            self.tris[e as usize],
            self.tris[next(e) as usize],
            self.tris[prev(e) as usize],
        );
        let (hbc, hca) = (self.half[next(e) as usize], self.half[prev(e) as usize]);
        let t1 = e / 3;
        self.set_triangle(t1, [a, p, c]);
        let t2 = self.add_triangle(p, b, c);
        self.link(3 * t1 + 2, hca);
        self.link(3 * t2 + 1, hbc);
        self.link(3 * t1 + 1, 3 * t2 + 2);
        self.half[3 * t1 as usize] = NONE;
        self.half[3 * t2 as usize] = NONE;
        self.touch(t1);
        self.touch(t2);
        if f != NONE {
            let d = self.tris[prev(f) as usize];
            let (had, hdb) = (self.half[next(f) as usize], self.half[prev(f) as usize]);
            let u1 = f / 3;
            self.set_triangle(u1, [b, p, d]);
            let u2 = self.add_triangle(p, a, d);
            self.link(3 * u1 + 2, hdb);
            self.link(3 * u2 + 1, had);
            self.link(3 * u1 + 1, 3 * u2 + 2);
            self.link(3 * u1, 3 * t2);
            self.link(3 * u2, 3 * t1);
            self.touch(u1);
            self.touch(u2);
            self.legalize(3 * u1 + 2);
            self.legalize(3 * u2 + 1);
        }
        self.legalize(3 * t1 + 2);
        self.legalize(3 * t2 + 1);
    }

    /// Lawson's flips from edge `a`, whose triangle's vertex opposite it is the new
    /// point.
    fn legalize(&mut self, a: u32) {
        let mut stack = vec![a];
        while let Some(a) = stack.pop() {
            let b = self.half[a as usize];
            if b == NONE {
                continue;
            }
            let (al, ar) = (next(a), prev(a));
            let (br, bl) = (next(b), prev(b));
            let [p0, pr, pl, p1] = [ar, a, al, bl].map(|e| self.tris[e as usize]);
            if !in_circle(self.pos(p0), self.pos(pr), self.pos(pl), self.pos(p1)) {
                continue;
            }
            self.tris[a as usize] = p1;
            self.tris[b as usize] = p0;
            let (hbl, har) = (self.half[bl as usize], self.half[ar as usize]);
            self.link(a, hbl);
            self.link(b, har);
            self.link(ar, bl);
            self.touch(a / 3);
            self.touch(b / 3);
            stack.push(br);
            stack.push(a);
        }
    }

    /// Finds triangle `t`'s worst candidate and queues it if it exceeds `tau`.
    fn scan(&mut self, t: u32, tau: f64) {
        let e = 3 * t as usize;
        let [a, b, c] = [self.tris[e], self.tris[e + 1], self.tris[e + 2]];
        let (pa, pb, pc) = (self.pos(a), self.pos(b), self.pos(c));
        let (za, zb, zc) = (self.z[a as usize], self.z[b as usize], self.z[c as usize]);
        let det = (pb[0] - pa[0]) * (pc[1] - pa[1]) - (pc[0] - pa[0]) * (pb[1] - pa[1]);
        let gx = ((zb - za) * (pc[1] - pa[1]) - (zc - za) * (pb[1] - pa[1])) / det;
        let gy = ((zc - za) * (pb[0] - pa[0]) - (zb - za) * (pc[0] - pa[0])) / det;
        let [ox, oy] = self.origin;
        let [cx0, cy0, cx1, cy1] = self.cand;
        let ymin = pa[1].min(pb[1]).min(pc[1]) + oy;
        let ymax = pa[1].max(pb[1]).max(pc[1]) + oy;
        let y0 = (ymin - 1e-6).ceil().max(cy0 as f64) as i64;
        let y1 = (ymax + 1e-6).floor().min(cy1 as f64) as i64;
        let mut worst = (0.0_f64, NONE);
        let edges = [(pa, pb), (pb, pc), (pc, pa)];
        for gy_ in y0..=y1 {
            let y = gy_ as f64 - oy;
            let (mut xl, mut xr) = (f64::INFINITY, f64::NEG_INFINITY);
            for (p, q) in edges {
                let (lo, hi) = (p[1].min(q[1]), p[1].max(q[1]));
                if y < lo - 1e-6 || y > hi + 1e-6 {
                    continue;
                }
                if p[1] == q[1] {
                    xl = xl.min(p[0].min(q[0]));
                    xr = xr.max(p[0].max(q[0]));
                } else {
                    let x = p[0] + (y - p[1]) * (q[0] - p[0]) / (q[1] - p[1]);
                    xl = xl.min(x);
                    xr = xr.max(x);
                }
            }
            if xl > xr {
                continue;
            }
            let mut xs = ((xl + ox - 1e-6).ceil() as i64).max(cx0);
            let mut xe = ((xr + ox + 1e-6).floor() as i64).min(cx1);
            // Near the interval's ends, the exact test decides.
            let outside = |gx_: i64| {
                let p = [gx_ as f64 - ox, y];
                orient(pa, pb, p) < 0.0 || orient(pb, pc, p) < 0.0 || orient(pc, pa, p) < 0.0
            };
            if xs <= xe && outside(xs) {
                xs += 1;
            }
            if xs <= xe && outside(xe) {
                xe -= 1;
            }
            if xs > xe {
                continue;
            }
            let first = self.grid.index(xs as u32, gy_ as u32);
            let n = (xe - xs + 1) as usize;
            let heights = &self.grid.samples()[first..first + n];
            let used = &self.used[first..first + n];
            let row_plane = za + gy * (y - pa[1]);
            for (k, (&h, &u)) in heights.iter().zip(used).enumerate() {
                if u {
                    continue;
                }
                let x = (xs + k as i64) as f64 - ox;
                let err = (row_plane + gx * (x - pa[0]) - h).abs();
                if err > worst.0 {
                    worst = (err, (first + k) as u32);
                }
            }
        }
        self.best[t as usize] = worst;
        self.generation[t as usize] += 1;
        if worst.0 > tau {
            self.heap
                .push((worst.0.to_bits(), t, self.generation[t as usize]));
        }
    }

    fn run(&mut self, tau: f64) {
        for t in 0..(self.tris.len() / 3) as u32 {
            self.scan(t, tau);
        }
        let [gx, gy, gw, _] = self.grid.frame();
        while let Some((_, t, generation)) = self.heap.pop() {
            if self.generation[t as usize] != generation {
                continue;
            }
            let (_, i) = self.best[t as usize];
            let (sx, sy) = (i % gw, i / gw);
            self.used[i as usize] = true;
            let v = self.pts.len() as u32;
            self.pts.push([f64::from(sx), f64::from(sy)]);
            self.z.push(self.grid.at(gx + sx, gy + sy));
            self.round += 1;
            self.insert(t, v);
            let pending = std::mem::take(&mut self.pending);
            for &k in &pending {
                self.scan(k, tau);
            }
            self.pending = pending;
            self.pending.clear();
        }
    }

    fn global(&self, v: u32) -> [f64; 2] {
        let p = self.pos(v);
        [p[0] + self.origin[0], p[1] + self.origin[1]]
    }

    fn finish(self, tau: f64) -> GreedyMesh {
        let [ox, oy] = self.origin;
        GreedyMesh {
            points: self.pts.iter().map(|p| [p[0] + ox, p[1] + oy]).collect(),
            heights: self.z,
            triangles: self
                .tris
                .chunks_exact(3)
                .map(|t| [t[0], t[1], t[2]])
                .collect(),
            tau,
        }
    }
}

#[cfg(test)]
mod tests;
