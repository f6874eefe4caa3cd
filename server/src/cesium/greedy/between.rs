//! The refinement between samples (see the module doc of [`super`]): where a mesh
//! edge strays from the samples' bilinear surface by more than the threshold plus a
//! quarter of the cell's twist (what any triangulation of the cell may differ by),
//! a corner of the cell where it strays most becomes a vertex.

use super::{Greedy, NONE, next, orient};

impl Greedy<'_> {
    /// One pass of [`super::mesh`]'s refinement between samples: whether a sample was added.
    pub(super) fn refine_between(&mut self, tau: f64) -> bool {
        let [gx, gy, _, _] = self.grid.frame();
        let [cx0, cy0, cx1, cy1] = self.cand;
        let mut wanted = Vec::new();
        // The edges of the triangles changed since the last pass (all, the first
        // time): the others were walked and have not moved.
        let changed = std::mem::take(&mut self.changed);
        for &t in &changed {
            self.is_changed[t as usize] = false;
        }
        let mut walked = rustc_hash::FxHashSet::default();
        for e in changed.iter().flat_map(|&t| 3 * t..3 * t + 3) {
            let f = self.half[e as usize];
            // Hull edges are the sides, within `tau` by their own rule.
            if f == NONE || !walked.insert(e.min(f)) {
                continue;
            }
            let (a, b) = (self.tris[e as usize], self.tris[next(e) as usize]);
            let (err, at) = self.grid.bilinear_excess(
                self.global(a),
                self.z[a as usize],
                self.global(b),
                self.z[b as usize],
            );
            if err <= tau {
                continue;
            }
            // The cell's corners that are candidates and not yet vertices, nearest
            // the stray point first.
            let (i, j) = (at[0].floor() as i64, at[1].floor() as i64);
            let mut corners: Vec<(f64, i64, i64)> =
                [(i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1)]
                    .into_iter()
                    .filter(|&(x, y)| x >= cx0 && x <= cx1 && y >= cy0 && y <= cy1)
                    .filter(|&(x, y)| !self.used[self.grid.index(x as u32, y as u32)])
                    .map(|(x, y)| ((x as f64 - at[0]).hypot(y as f64 - at[1]), x, y))
                    .collect();
            corners.sort_by(|p, q| p.0.total_cmp(&q.0));
            if let Some(&(_, x, y)) = corners.first() {
                wanted.push((e / 3, x, y));
            }
        }
        let mut any = false;
        for (t, x, y) in wanted {
            let i = self.grid.index(x as u32, y as u32);
            if self.used[i] {
                continue;
            }
            let p = [x as f64 - f64::from(gx), y as f64 - f64::from(gy)];
            let Some(t) = self.locate(t, p) else {
                continue;
            };
            self.used[i] = true;
            let v = self.pts.len() as u32;
            self.pts.push(p);
            self.z.push(self.grid.at(x as u32, y as u32));
            self.round += 1;
            self.insert(t, v);
            any = true;
            let pending = std::mem::take(&mut self.pending);
            for &k in &pending {
                self.scan(k, tau);
            }
            self.pending = pending;
            self.pending.clear();
        }
        any
    }

    /// The triangle holding `p` (inside or on an edge), walking from triangle `t`
    /// across the edge `p` lies beyond (a Delaunay triangulation's walk ends).
    fn locate(&self, mut t: u32, p: [f64; 2]) -> Option<u32> {
        for _ in 0..self.tris.len() {
            let e0 = 3 * t;
            let beyond = (e0..e0 + 3).find(|&e| {
                orient(
                    self.pos(self.tris[e as usize]),
                    self.pos(self.tris[next(e) as usize]),
                    p,
                ) < 0.0
            });
            match beyond {
                None => return Some(t),
                Some(e) => {
                    let f = self.half[e as usize];
                    if f == NONE {
                        return None;
                    }
                    t = f / 3;
                }
            }
        }
        None
    }
}
