//! One tile of a geographic grid at its finest level meshed lean: its sides by the rule neighbours share
//! ([`crate::cesium::side`]), its inside by greedy insertion
//! ([`crate::cesium::greedy`]), against the zoom's level and threshold
//! ([`super::plan`]). On a geographic grid a tile is a rectangle of the level's
//! sample space, so the mesh is made in that rectangle and needs no clipping; the
//! rest of the tile (beyond the data) is filled by [`super::tile_builder`].

use super::clip::Pt;
use super::mapping::Mapping;
use super::plan::ZoomPlan;
use super::tile_builder::Builder;
use super::{LevelData, Terrain};
use crate::cesium::greedy;
use crate::cesium::mesh::Truth;
use crate::cesium::side::{SidePoint, simplify};
use crate::cesium::tiling::CesiumTile;

/// Working memory per sample of the rectangle, at most: its height (8 bytes), whether
/// it is a vertex (1), and when every sample is one, two triangles of 3 indices, 3
/// twins, a candidate and a generation (2 × 44) and the heap's entries (2 × 16 per
/// rescan, a few rescans each).
const LEAN_BYTES_PER_SAMPLE: u64 = 192;

/// A tile's rectangle in the level's sample space, clipped to the data, and the
/// longitude or latitude of each side that is the tile's edge (the others are the
/// data's edge).
struct Frame {
    rect: [f64; 4],
    /// West, north, east, south: the exact edge value to put on the side's points.
    snap: [Option<f64>; 4],
}

impl Terrain {
    /// Whether zoom `plan` is meshed lean: a geographic grid meshed at its finest
    /// level, where the samples are the data and the greedy mesher's bound at the
    /// samples is the bound (`crate::cesium::greedy`).
    pub(super) fn is_lean(&self, plan: &ZoomPlan) -> bool {
        matches!(self.mapping, Mapping::Affine { .. }) && plan.truth == Truth::Samples
    }

    fn lean_frame(&self, rect: [f64; 4], plan: &ZoomPlan) -> Option<Frame> {
        let Mapping::Affine { dlon, dlat, .. } = self.mapping else {
            return None;
        };
        let (stride, _, data_box) = self.level_frame(plan.level);
        let [w, s, e, n] = rect;
        let [cw, rn] = self.mapping.to_samples(w, n)?;
        let [ce, rs] = self.mapping.to_samples(e, s)?;
        let (cw, ce, rn, rs) = (cw / stride, ce / stride, rn / stride, rs / stride);
        // Sample space runs east and south when dlon > 0 and dlat < 0.
        let ((x0, lx0), (x1, lx1)) = if dlon > 0.0 {
            ((cw, w), (ce, e))
        } else {
            ((ce, e), (cw, w))
        };
        let ((y0, ly0), (y1, ly1)) = if dlat < 0.0 {
            ((rn, n), (rs, s))
        } else {
            ((rs, s), (rn, n))
        };
        let side = |v: f64, edge: f64, clip: f64, low: bool| -> (f64, Option<f64>) {
            // An edge a rounding error off a sample line is on it: the tile on one
            // side would otherwise count that line's samples as its inside and the
            // other as beyond, and only one of them would put them on the edge. Both
            // compute the same `v`, so both snap alike.
            let v = if (v - v.round()).abs() < 1e-7 {
                v.round()
            } else {
                v
            };
            // A tile edge exactly on the data's edge stays the tile's edge, so its
            // points quantize to the border and get the border's skirt.
            let beyond = if low { v < clip } else { v > clip };
            if beyond {
                (clip, None)
            } else {
                (v, Some(edge))
            }
        };
        let (x0, sw) = side(x0, lx0, data_box[0], true);
        let (y0, sn) = side(y0, ly0, data_box[1], true);
        let (x1, se) = side(x1, lx1, data_box[2], false);
        let (y1, ss) = side(y1, ly1, data_box[3], false);
        (x0 < x1 && y0 < y1).then_some(Frame {
            rect: [x0, y0, x1, y1],
            snap: [sw, sn, se, ss],
        })
    }

    /// An upper estimate of the memory [`Terrain::mesh_greedy`] uses for `tile`.
    pub(super) fn lean_bytes(&self, tile: CesiumTile, plan: &ZoomPlan) -> Option<u64> {
        let f = self.lean_frame(self.frame_rect(tile), plan)?;
        let w = (f.rect[2].ceil() - f.rect[0].floor() + 2.0) as u64;
        let h = (f.rect[3].ceil() - f.rect[1].floor() + 2.0) as u64;
        let t = u64::from(self.geometry.tile_size());
        let tiles = (w.div_ceil(t) + 1) * (h.div_ceil(t) + 1);
        let tile_bytes = (t + 1) * (t + 1) * 2 + (t * t).div_ceil(8);
        Some(w * h * LEAN_BYTES_PER_SAMPLE + tiles * tile_bytes)
    }

    /// Meshes the data part of a tile of a geographic grid into `builder`.
    pub(super) fn mesh_greedy<D: LevelData>(
        &self,
        rect: [f64; 4],
        plan: &ZoomPlan,
        data: &D,
        builder: &mut Builder,
    ) -> Result<(), D::Error> {
        let Some(frame) = self.lean_frame(rect, plan) else {
            return Ok(());
        };
        let (stride, cells, _) = self.level_frame(plan.level);
        let [x0, y0, x1, y1] = frame.rect;
        // One sample beyond the rectangle where there is one: a side on a grid line
        // then reads the same cells from either tile.
        let window = [
            x0.floor() as u32,
            y0.floor() as u32,
            (x1.floor() as u32 + 1).min(cells),
            (y1.floor() as u32 + 1).min(cells),
        ];
        let grid = self.heights(plan.level, stride, window, data)?;
        data.check()?;
        let tau = plan.tau;
        let mut outline: Vec<SidePoint> = Vec::new();
        for (a, b) in [
            ([x0, y0], [x1, y0]),
            ([x1, y0], [x1, y1]),
            ([x1, y1], [x0, y1]),
            ([x0, y1], [x0, y0]),
        ] {
            let side = simplify(&grid, a, b, tau);
            outline.extend_from_slice(&side[..side.len() - 1]);
        }
        let mesh = greedy::mesh(&grid, frame.rect, &outline, tau);
        data.check()?;
        let [sw, sn, se, ss] = frame.snap;
        let points: Vec<Option<Pt>> = mesh
            .points
            .iter()
            .zip(&mesh.heights)
            .map(|(&[x, y], &h)| {
                let [lon, lat] = self.mapping.lon_lat(x * stride, y * stride)?;
                // A point on a side that is the tile's edge gets the edge's exact
                // value: both tiles along it quantize it to their border.
                let lon = match (x == x0, x == x1) {
                    (true, _) => sw.unwrap_or(lon),
                    (_, true) => se.unwrap_or(lon),
                    _ => lon,
                };
                let lat = match (y == y0, y == y1) {
                    (true, _) => sn.unwrap_or(lat),
                    (_, true) => ss.unwrap_or(lat),
                    _ => lat,
                };
                Some(Pt { x: lon, y: lat, h })
            })
            .collect();
        for t in &mesh.triangles {
            if let [Some(a), Some(b), Some(c)] = t.map(|i| points[i as usize]) {
                builder.add_exact([a, b, c]);
            }
        }
        Ok(())
    }
}
