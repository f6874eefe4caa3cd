//! A tile's vertices (deduplicated by position) and triangles as they are
//! collected, and the fill of the tile outside the data.

use super::Terrain;
use super::clip::{Pt, Support, clip_box};
use crate::cesium::quantized_mesh::{MeshVertex, TerrainMesh};
use rustc_hash::FxHashMap;
use std::collections::HashMap;

/// Collects a tile's vertices (deduplicated by position) and triangles.
pub(super) struct Builder {
    rect: [f64; 4],
    index: FxHashMap<(u64, u64), u32>,
    points: Vec<Pt>,
    triangles: Vec<[u32; 3]>,
}

impl Builder {
    pub(super) fn new(rect: [f64; 4]) -> Self {
        Self {
            rect,
            index: FxHashMap::default(),
            points: Vec::new(),
            triangles: Vec::new(),
        }
    }

    fn vertex(&mut self, p: Pt) -> u32 {
        let next = self.points.len() as u32;
        *self.index.entry(p.key()).or_insert_with(|| {
            self.points.push(p);
            next
        })
    }

    /// Clips one RTIN triangle (level coordinates) to the data, carries it to
    /// longitude/latitude, clips it to the tile and keeps the pieces.
    pub(super) fn add_triangle(
        &mut self,
        terrain: &Terrain,
        t: [Pt; 3],
        stride: f64,
        data_box: [f64; 4],
    ) {
        // Most triangles lie inside both boxes: no clipping (the same vertices result).
        let in_data = |p: &Pt| {
            p.x >= data_box[0] && p.y >= data_box[1] && p.x <= data_box[2] && p.y <= data_box[3]
        };
        if t.iter().all(in_data) {
            let ll = t.map(|p| {
                terrain
                    .mapping
                    .lon_lat(p.x * stride, p.y * stride)
                    .map(|[x, y]| Pt { x, y, h: p.h })
            });
            if let [Some(a), Some(b), Some(c)] = ll {
                let [w, s, e, n] = self.rect;
                let inside = |p: &Pt| p.x >= w && p.x <= e && p.y >= s && p.y <= n;
                if inside(&a) && inside(&b) && inside(&c) {
                    let ids = [a, b, c].map(|p| self.vertex(p));
                    self.triangle(ids[0], ids[1], ids[2]);
                    return;
                }
            }
        }
        let poly: Vec<(Pt, Support)> = (0..3)
            .map(|i| (t[i], Support::Segment(t[i], t[(i + 1) % 3])))
            .collect();
        let stage1 = clip_box(poly, data_box, &t);
        if stage1.is_empty() {
            return;
        }
        let to_ll = |p: Pt| {
            terrain
                .mapping
                .lon_lat(p.x * stride, p.y * stride)
                .map(|[x, y]| Pt { x, y, h: p.h })
        };
        let Some(tri_ll) = t.iter().map(|&p| to_ll(p)).collect::<Option<Vec<_>>>() else {
            return;
        };
        let tri_ll = [tri_ll[0], tri_ll[1], tri_ll[2]];
        let mut stage2 = Vec::with_capacity(stage1.len());
        for i in 0..stage1.len() {
            let (p, sup) = stage1[i];
            let Some(pl) = to_ll(p) else { return };
            let sup = match sup {
                Support::Segment(a, b) => match (to_ll(a), to_ll(b)) {
                    (Some(a), Some(b)) => Support::Segment(a, b),
                    _ => return,
                },
                // A piece of the data's boundary between two stage-1 points.
                Support::Line(_) => {
                    let q = stage1[(i + 1) % stage1.len()].0;
                    match to_ll(q) {
                        Some(q) => Support::Segment(pl, q),
                        None => return,
                    }
                }
            };
            stage2.push((pl, sup));
        }
        let poly = clip_box(stage2, self.rect, &tri_ll);
        if poly.len() < 3 {
            return;
        }
        let ids: Vec<u32> = poly.iter().map(|(p, _)| self.vertex(*p)).collect();
        for k in 1..ids.len() - 1 {
            self.triangle(ids[0], ids[k], ids[k + 1]);
        }
    }

    /// A triangle already inside the tile and the data (longitude/latitude), its
    /// points on the tile's edges exactly on them.
    pub(super) fn add_exact(&mut self, t: [Pt; 3]) {
        let ids = t.map(|p| self.vertex(p));
        self.triangle(ids[0], ids[1], ids[2]);
    }

    /// A triangle, counter-clockwise in longitude/latitude; degenerate ones dropped.
    fn triangle(&mut self, a: u32, b: u32, c: u32) {
        let [pa, pb, pc] = [a, b, c].map(|i| self.points[i as usize]);
        let cross = (pb.x - pa.x) * (pc.y - pa.y) - (pc.x - pa.x) * (pb.y - pa.y);
        if cross > 0.0 {
            self.triangles.push([a, b, c]);
        } else if cross < 0.0 {
            self.triangles.push([a, c, b]);
        }
    }

    /// Fills what the data leaves of the tile, then quantizes positions. `data` is
    /// the data's rectangle in longitude and latitude where the grid is geographic
    /// (computed as the data's side points are): the rest is then a flat apron.
    pub(super) fn finish(mut self, terrain: &Terrain, data: Option<[f64; 4]>) -> TerrainMesh {
        match data {
            Some(d) if !self.triangles.is_empty() => self.apron(d),
            _ => self.fill(terrain),
        }
        let [w, s, e, n] = self.rect;
        let q = |v: f64, lo: f64, hi: f64| -> u16 {
            if v == lo {
                0
            } else if v == hi {
                32767
            } else {
                // Interior points never land on an edge: edges list only true edge points.
                ((v - lo) / (hi - lo) * 32767.0).round().clamp(1.0, 32766.0) as u16
            }
        };
        let vertices = self
            .points
            .iter()
            .map(|p| MeshVertex {
                u: q(p.x, w, e),
                v: q(p.y, s, n),
                height: p.h,
            })
            .collect();
        TerrainMesh {
            vertices,
            triangles: self.triangles,
        }
    }

    /// The rest of the rectangle, where the data is a rectangle `[w, s, e, n]` of
    /// it: each side of the data inside the tile is carried out flat to the tile's
    /// edge (every side point's height straight out), and each corner of the data
    /// inside the tile fills its corner of the tile at the corner's height. No
    /// slope that is not in the data, and the points on the tile's edges depend only
    /// on the data's side points there, which the tile beside computes alike.
    fn apron(&mut self, [dw, ds, de, dn]: [f64; 4]) {
        let [w, s, e, n] = self.rect;
        let (dw, ds, de, dn) = (dw.max(w), ds.max(s), de.min(e), dn.min(n));
        let side = |pts: &[Pt], on: &dyn Fn(&Pt) -> Option<f64>| -> Vec<(f64, Pt)> {
            let mut v: Vec<(f64, Pt)> = pts.iter().filter_map(|p| on(p).map(|t| (t, *p))).collect();
            v.sort_by(|a, b| a.0.total_cmp(&b.0));
            v.dedup_by(|a, b| a.0 == b.0);
            v
        };
        let within = |t: f64, lo: f64, hi: f64| t >= lo && t <= hi;
        // (side points along it, where the apron reaches, whether it is vertical)
        let mut strips = Vec::new();
        if dw > w {
            strips.push((
                side(&self.points, &|p| {
                    (p.x == dw && within(p.y, ds, dn)).then_some(p.y)
                }),
                w,
                true,
            ));
        }
        if de < e {
            strips.push((
                side(&self.points, &|p| {
                    (p.x == de && within(p.y, ds, dn)).then_some(p.y)
                }),
                e,
                true,
            ));
        }
        if ds > s {
            strips.push((
                side(&self.points, &|p| {
                    (p.y == ds && within(p.x, dw, de)).then_some(p.x)
                }),
                s,
                false,
            ));
        }
        if dn < n {
            strips.push((
                side(&self.points, &|p| {
                    (p.y == dn && within(p.x, dw, de)).then_some(p.x)
                }),
                n,
                false,
            ));
        }
        let out = |p: Pt, to: f64, vertical: bool| {
            if vertical {
                Pt { x: to, ..p }
            } else {
                Pt { y: to, ..p }
            }
        };
        for (pts, to, vertical) in &strips {
            for pair in pts.windows(2) {
                let (a, b) = (pair[0].1, pair[1].1);
                let ids =
                    [a, b, out(b, *to, *vertical), out(a, *to, *vertical)].map(|p| self.vertex(p));
                self.triangle(ids[0], ids[1], ids[2]);
                self.triangle(ids[0], ids[2], ids[3]);
            }
        }
        // Corners of the tile beyond two sides of the data: flat at the data's corner.
        for (cx, cy, tx, ty) in [
            (dw, dn, w, n),
            (de, dn, e, n),
            (de, ds, e, s),
            (dw, ds, w, s),
        ] {
            if cx == tx || cy == ty {
                continue;
            }
            let Some(c) = self.points.iter().find(|p| p.x == cx && p.y == cy).copied() else {
                continue;
            };
            let h = c.h;
            let quad = [
                c,
                Pt { x: tx, y: cy, h },
                Pt { x: tx, y: ty, h },
                Pt { x: cx, y: ty, h },
            ];
            let ids = quad.map(|p| self.vertex(p));
            self.triangle(ids[0], ids[1], ids[2]);
            self.triangle(ids[0], ids[2], ids[3]);
        }
    }

    /// The rest of the rectangle where the data is not a rectangle of it (a
    /// projected grid, or no data at all): a constrained Delaunay triangulation of
    /// the data mesh's boundary and the tile's corners, keeping the faces outside
    /// the data; a corner takes the height of the boundary point nearest it, or sea
    /// level when the tile holds no data.
    fn fill(&mut self, terrain: &Terrain) {
        use spade::{ConstrainedDelaunayTriangulation, Point2, Triangulation};
        let [w, s, e, n] = self.rect;
        // Boundary edges: used by one triangle only and not along the tile's edge.
        let mut uses: FxHashMap<(u32, u32), u32> = FxHashMap::default();
        for t in &self.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *uses.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        let along = |a: Pt, b: Pt| {
            (a.x == b.x && (a.x == w || a.x == e)) || (a.y == b.y && (a.y == s || a.y == n))
        };
        let mut boundary: Vec<(u32, u32)> = uses
            .into_iter()
            .filter(|&((a, b), k)| {
                k == 1 && !along(self.points[a as usize], self.points[b as usize])
            })
            .map(|(e, _)| e)
            .collect();
        if !self.triangles.is_empty() && boundary.is_empty() {
            return; // the data covers the tile
        }
        // A fixed order (not the map's): the same tile is the same bytes in every
        // process, for caches and replicas.
        boundary.sort_unstable();
        let mut cdt: ConstrainedDelaunayTriangulation<Point2<f64>> =
            ConstrainedDelaunayTriangulation::new();
        let mut handle_of: HashMap<u32, spade::handles::FixedVertexHandle> = HashMap::new();
        let mut id_of: HashMap<spade::handles::FixedVertexHandle, u32> = HashMap::new();
        let corners = [[w, s], [e, s], [e, n], [w, n]];
        let nearest = |x: f64, y: f64| {
            boundary
                .iter()
                .flat_map(|&(a, b)| [a, b])
                .map(|i| self.points[i as usize])
                .min_by(|p, q| {
                    let d = |r: &Pt| (r.x - x).hypot(r.y - y);
                    d(p).total_cmp(&d(q))
                })
                .map(|p| p.h)
        };
        let corner_heights: Vec<f64> = corners
            .iter()
            .map(|&[x, y]| nearest(x, y).unwrap_or_else(|| terrain.sea_level(x, y)))
            .collect();
        for ([x, y], h) in corners.into_iter().zip(corner_heights) {
            let p = Pt { x, y, h };
            let id = self.vertex(p);
            if let Ok(hd) = cdt.insert(Point2::new(x, y)) {
                handle_of.insert(id, hd);
                id_of.insert(hd, id);
            }
        }
        for &(a, b) in &boundary {
            for id in [a, b] {
                if let std::collections::hash_map::Entry::Vacant(slot) = handle_of.entry(id) {
                    let p = self.points[id as usize];
                    if let Ok(hd) = cdt.insert(Point2::new(p.x, p.y)) {
                        slot.insert(hd);
                        id_of.insert(hd, id);
                    }
                }
            }
        }
        // Data vertices where the data's boundary meets the tile's edge are endpoints
        // of boundary edges, so they are in; the corners close the hull.
        for &(a, b) in &boundary {
            if let (Some(&ha), Some(&hb)) = (handle_of.get(&a), handle_of.get(&b))
                && cdt.can_add_constraint(ha, hb)
            {
                cdt.add_constraint(ha, hb);
            }
        }
        let faces: Vec<[u32; 3]> = cdt
            .inner_faces()
            .filter_map(|f| {
                let vs = f.vertices();
                let ids: Option<Vec<u32>> =
                    vs.iter().map(|v| id_of.get(&v.fix()).copied()).collect();
                let ids = ids?;
                let c = vs.iter().fold([0.0, 0.0], |acc, v| {
                    let p = v.position();
                    [acc[0] + p.x / 3.0, acc[1] + p.y / 3.0]
                });
                (!terrain.inside_data(c[0], c[1])).then(|| [ids[0], ids[1], ids[2]])
            })
            .collect();
        for [a, b, c] in faces {
            self.triangle(a, b, c);
        }
    }
}
