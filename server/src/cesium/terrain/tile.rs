//! One tile's mesh: the squares it draws, the window of samples it reads, and their
//! triangles, clipped into the tile's `tile_builder::Builder`.

use super::clip::Pt;
use super::mapping::Mapping;
use super::plan::ZoomPlan;
use super::tile_builder::Builder;
use super::{LevelData, Terrain};
use crate::cesium::mesh::Window;
use crate::cesium::quantized_mesh::TerrainMesh;
use crate::cesium::surface::HeightGrid;
use crate::cesium::tiling::CesiumTile;
use tessera_shared::{Level, TileId};

/// Working memory of a mesh per window sample: the window's height and error
/// (`f64` each), and the triangles and vertices made from it (measured: see
/// [`Terrain::mesh_bytes`]).
const MESH_BYTES_PER_SAMPLE: u64 = 48;

impl Terrain {
    /// The mesh of `tile` (always covering its rectangle).
    pub fn mesh<D: LevelData>(&self, tile: CesiumTile, data: &D) -> Result<TerrainMesh, D::Error> {
        let plan = self.plan(tile.z, data)?;
        self.mesh_with(tile, &plan, data)
    }

    /// The mesh of `tile` with a given plan (benchmarks compare thresholds with it;
    /// tiles meshed with different plans do not share their edges).
    pub fn mesh_with<D: LevelData>(
        &self,
        tile: CesiumTile,
        plan: &ZoomPlan,
        data: &D,
    ) -> Result<TerrainMesh, D::Error> {
        let plan = *plan;
        let rect = self.frame_rect(tile);
        let (stride, cells, data_box) = self.level_frame(plan.level);
        let mut builder = Builder::new(rect);
        if self.is_lean(&plan) {
            self.mesh_greedy(rect, &plan, data, &mut builder)?;
            return Ok(builder.finish(self, self.data_lon_lat(stride, data_box)));
        }
        if let Some(squares) = self.squares(rect, &plan, stride, cells, data_box) {
            let window = self.window(&plan, cells, squares, stride, data)?;
            let [ix0, iy0, ix1, iy1] = squares.inner;
            let mut tris = Vec::new();
            for sy in iy0..iy1 {
                data.check()?;
                for sx in ix0..ix1 {
                    window.triangulate_square(sx, sy, plan.tau, &mut tris);
                }
            }
            for t in &tris {
                let pts = t.map(|v| Pt {
                    x: f64::from(v[0]),
                    y: f64::from(v[1]),
                    h: window.height(v),
                });
                builder.add_triangle(self, pts, stride, data_box);
            }
        }
        Ok(builder.finish(self, self.data_lon_lat(stride, data_box)))
    }

    /// A level's stride (finest samples per level sample), its cells per side, and
    /// the data region in level coordinates (the DEM's finest sample centres).
    pub(super) fn level_frame(&self, level: Level) -> (f64, u32, [f64; 4]) {
        let stride = self.geometry.spacing(level) as f64;
        let cells = (1u32 << level.get()) * self.geometry.tile_size();
        let data_box = [
            0.0,
            0.0,
            f64::from(self.geometry.width() - 1) / stride,
            f64::from(self.geometry.height() - 1) / stride,
        ];
        (stride, cells, data_box)
    }

    /// The data's rectangle `[w, s, e, n]` in longitude and latitude on a geographic
    /// grid, computed as the data's side points are (from level coordinates times
    /// the stride), so they compare equal.
    fn data_lon_lat(&self, stride: f64, data_box: [f64; 4]) -> Option<[f64; 4]> {
        let Mapping::Affine { .. } = self.mapping else {
            return None;
        };
        let [a, b] = self
            .mapping
            .lon_lat(data_box[0] * stride, data_box[1] * stride)?;
        let [c, d] = self
            .mapping
            .lon_lat(data_box[2] * stride, data_box[3] * stride)?;
        Some([a.min(c), b.min(d), a.max(c), b.max(d)])
    }

    /// An upper estimate of the memory [`Terrain::mesh_with`] uses for `tile`: its
    /// window of samples and the source tiles it holds (admission control reserves
    /// it before meshing: serve/compute/).
    pub fn mesh_bytes(&self, tile: CesiumTile, plan: &ZoomPlan) -> u64 {
        if self.is_lean(plan) {
            return self.lean_bytes(tile, plan).unwrap_or(0);
        }
        let (stride, cells, data_box) = self.level_frame(plan.level);
        let Some(sq) = self.squares(self.frame_rect(tile), plan, stride, cells, data_box) else {
            return 0;
        };
        let [x0, y0, x1, y1] = sq.outer;
        let s = u64::from(plan.square);
        let (w, h) = (u64::from(x1 - x0) * s + 1, u64::from(y1 - y0) * s + 1);
        let t = u64::from(self.geometry.tile_size());
        let tiles = (w.div_ceil(t) + 1) * (h.div_ceil(t) + 1);
        let tile_bytes = (t + 1) * (t + 1) * 2 + (t * t).div_ceil(8);
        w * h * MESH_BYTES_PER_SAMPLE + tiles * tile_bytes
    }

    /// The squares a tile draws and the window it reads (square units).
    fn squares(
        &self,
        rect: [f64; 4],
        plan: &ZoomPlan,
        stride: f64,
        cells: u32,
        data_box: [f64; 4],
    ) -> Option<Squares> {
        // The rectangle in level coordinates, from a 9 × 9 lattice (exact for a
        // geographic grid; a sample of margin for a curved projected one).
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for j in 0..=8 {
            for i in 0..=8 {
                let lon = rect[0] + (rect[2] - rect[0]) * f64::from(i) / 8.0;
                let lat = rect[1] + (rect[3] - rect[1]) * f64::from(j) / 8.0;
                let [c, r] = self.mapping.to_samples(lon, lat)?;
                let (c, r) = (c / stride, r / stride);
                b = [b[0].min(c), b[1].min(r), b[2].max(c), b[3].max(r)];
            }
        }
        let margin = if matches!(self.mapping, Mapping::Affine { .. }) {
            0.0
        } else {
            1.0 + 0.02 * (b[2] - b[0]).max(b[3] - b[1])
        };
        let b = [
            (b[0] - margin).max(data_box[0]),
            (b[1] - margin).max(data_box[1]),
            (b[2] + margin).min(data_box[2]),
            (b[3] + margin).min(data_box[3]),
        ];
        if !(b[0] < b[2] && b[1] < b[3]) {
            return None;
        }
        let s = f64::from(plan.square);
        let n = cells / plan.square;
        let lo = |v: f64| ((v / s).floor().max(0.0) as u32).min(n - 1);
        let hi = |v: f64| ((v / s).ceil() as u32).clamp(1, n);
        let inner = [lo(b[0]), lo(b[1]), hi(b[2]), hi(b[3])];
        let outer = [
            inner[0].saturating_sub(1),
            inner[1].saturating_sub(1),
            (inner[2] + 1).min(n),
            (inner[3] + 1).min(n),
        ];
        Some(Squares { inner, outer })
    }

    /// The window's heights (above the ellipsoid) and vertex errors.
    fn window<D: LevelData>(
        &self,
        plan: &ZoomPlan,
        cells: u32,
        squares: Squares,
        stride: f64,
        data: &D,
    ) -> Result<Window, D::Error> {
        let [ox0, oy0, ox1, oy1] = squares.outer;
        let s = plan.square;
        let grid = self.heights(
            plan.level,
            stride,
            [ox0 * s, oy0 * s, ox1 * s, oy1 * s],
            data,
        )?;
        let mut w = Window::new(s, cells, squares.outer, |x, y| grid.at(x, y))
            .expect("squares inside the grid");
        w.compute_errors(plan.truth);
        Ok(w)
    }

    /// The heights (above the ellipsoid) of a level's samples `[x0, x1] × [y0, y1]`
    /// (inclusive, global).
    pub(super) fn heights<D: LevelData>(
        &self,
        level: Level,
        stride: f64,
        [x0, y0, x1, y1]: [u32; 4],
        data: &D,
    ) -> Result<HeightGrid, D::Error> {
        let t = self.geometry.tile_size();
        // Absent tiles lie wholly beyond the DEM: read the nearest present sample
        // (the padding repeats the DEM's edge), so every tile sees the same heights.
        let last_x = (f64::from(self.geometry.width() - 1) / stride).ceil() as u32;
        let last_y = (f64::from(self.geometry.height() - 1) / stride).ceil() as u32;
        // The last tile column and row holding samples up to `last_x`, `last_y`
        // (a sample on a tile border belongs to the tile before it too).
        let max_tx = (last_x.max(1) - 1) / t;
        let max_ty = (last_y.max(1) - 1) / t;
        let (tx0, tx1) = ((x0 / t).min(max_tx), (x1 / t).min(max_tx));
        let (ty0, ty1) = ((y0 / t).min(max_ty), (y1 / t).min(max_ty));
        let ntx = tx1 - tx0 + 1;
        let mut tiles = Vec::with_capacity((ntx * (ty1 - ty0 + 1)) as usize);
        for ty in ty0..=ty1 {
            for tx in tx0..=tx1 {
                let id = TileId::new(level, tx, ty).expect("inside the level");
                tiles.push(data.tile(id)?);
            }
        }
        let ts = self.geometry.tile_samples();
        let quant = self.quantization;
        let geoid = self.geoid.as_deref();
        let mapping = &self.mapping;
        let lons: Vec<f64> = match (geoid, mapping) {
            (Some(_), Mapping::Affine { .. }) => (x0..=x1)
                .map(|x| {
                    mapping
                        .lon_lat(f64::from(x) * stride, 0.0)
                        .map_or(0.0, |p| p[0])
                })
                .collect(),
            _ => Vec::new(),
        };
        let mut row: Option<(u32, crate::geoid::GeoidRow<'_>)> = None;
        let height = |x: u32, y: u32| -> f64 {
            let (cx, cy) = (x.min(last_x), y.min(last_y));
            let (tx, ty) = ((cx / t).min(max_tx), (cy / t).min(max_ty));
            let q = tiles[((ty - ty0) * ntx + (tx - tx0)) as usize]
                .as_ref()
                .map_or(0, |src| {
                    let (c, r) = ((cx - tx * t) as usize, (cy - ty * t) as usize);
                    src.heights[r * ts + c]
                });
            let z = quant.height(q);
            let Some(g) = geoid else { return z };
            match mapping {
                Mapping::Affine { .. } => {
                    let r = match row {
                        Some((ry, r)) if ry == y => r,
                        _ => {
                            let lat = mapping
                                .lon_lat(0.0, f64::from(y) * stride)
                                .map_or(0.0, |p| p[1]);
                            let r = g.row(lat);
                            row = Some((y, r));
                            r
                        }
                    };
                    z + r.undulation(lons[(x - x0) as usize])
                }
                Mapping::Projected { .. } => mapping
                    .lon_lat(f64::from(x) * stride, f64::from(y) * stride)
                    .map_or(z, |[lon, lat]| z + g.undulation(lon, lat)),
            }
        };
        Ok(HeightGrid::new([x0, y0, x1, y1], height).expect("a non-empty window"))
    }
}

#[derive(Clone, Copy, Debug)]
struct Squares {
    inner: [u32; 4],
    outer: [u32; 4],
}
