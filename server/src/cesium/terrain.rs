//! One dataset as Cesium terrain (issue 15): which pyramid level and threshold each
//! zoom meshes with, and one tile's mesh — the level's RTIN ([`super::mesh`]) cut
//! to the tile, the rest of the tile filled down to sea level.
//!
//! **The bound.** CesiumJS refines assuming zoom `z` is within
//! `ε_z = ε_0 / 2^z` of the truth ([`super::tiling::level_zero_error`]). A tile's
//! heights at the finest samples are off by at most
//!
//! `V (≤ τ, the RTIN against level L)` + `e_L (the error tables: level L against
//! the finest)` + `q (height quantization, half a step of the largest possible
//! tile range)` + `p (vertex positions quantized to 1/32767 of the tile)`.
//!
//! `p` is at most `√2 · slope · span / 65534`; `ε_z` is 252 of those steps of height
//! on a 1:1 slope (Earth or Moon alike, since both scale with the radius), so 5 % of
//! `ε_z` covers slopes up to 83°. Hence `τ = 0.95 ε_z − e_L − q`. Level `L` is the
//! coarsest whose `e_L` plus its largest leaf twist (see [`super::mesh`]) is at most
//! `ε_z / 2`, from the error tables, so coarse zooms read coarse levels.
//!
//! **Shared edges.** Level, square size and `τ` depend on the zoom only; vertex
//! errors near a line depend on the samples around it; clip points are computed from
//! the full original edge with its endpoints in a fixed order; tile edges are
//! `−180 + x·span`. So neighbours compute bit-identical edge points.
//!
//! **Outside the data** (a tile the DEM covers only in part), the tile is filled
//! by a constrained Delaunay triangulation ([`spade`]) between the data's boundary
//! and the tile's corners, at sea level (the geoid, or the body's sphere): every
//! tile covers its rectangle, and the fill never touches a DEM sample.

use super::ellipsoid::Ellipsoid;
use super::mesh::{Truth, Window};
use super::quantized_mesh::{MeshVertex, TerrainMesh};
use super::tiling::{CesiumTile, MAX_ZOOM, geometric_error, level_zero_error};
use crate::crs::Crs;
use crate::geoid::Geoid;
use crate::web::resample::SourceTile;
use rustc_hash::FxHashMap;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use tessera_shared::{Level, Metadata, Quantization, TileGeometry, TileId, VerticalDatum};

/// What a tile needs from the pyramid: decoded tiles, and the largest
/// full-resolution error of a level's tiles (error tables).
pub trait LevelData {
    type Error;
    /// The decoded level tile (`(T+1)²` quantized heights, north row first); `None`
    /// when the pyramid has no such tile.
    fn tile(&self, tile: TileId) -> Result<Option<Arc<SourceTile>>, Self::Error>;
    /// The largest full-resolution error (metres) of any tile of `level`.
    fn level_error(&self, level: Level) -> Result<f64, Self::Error>;
    /// `Err` when the work should stop (its requester is gone: serve/compute.rs);
    /// called between rows of squares.
    fn check(&self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// Working memory of a mesh per window sample: the window's height and error
/// (`f64` each), and the triangles and vertices made from it (measured: see
/// [`Terrain::mesh_bytes`]).
const MESH_BYTES_PER_SAMPLE: u64 = 48;

/// Where the finest samples are on the body.
#[derive(Debug)]
enum Mapping {
    /// A geographic grid on the body: `lon = lon0 + col·dlon`, `lat = lat0 + row·dlat`.
    Affine {
        lon0: f64,
        dlon: f64,
        lat0: f64,
        dlat: f64,
    },
    /// Any other CRS: the GDAL geotransform, then the projection library.
    Projected {
        crs: Box<Crs>,
        body: Box<Crs>,
        gt: [f64; 6],
        inverse: [f64; 6],
    },
}

impl Mapping {
    /// Longitude and latitude of finest-grid point `(col, row)`.
    fn lon_lat(&self, col: f64, row: f64) -> Option<[f64; 2]> {
        match self {
            Self::Affine {
                lon0,
                dlon,
                lat0,
                dlat,
            } => Some([lon0 + col * dlon, lat0 + row * dlat]),
            Self::Projected { crs, body, gt, .. } => {
                let (c, r) = (col + 0.5, row + 0.5);
                let x = gt[0] + c * gt[1] + r * gt[2];
                let y = gt[3] + c * gt[4] + r * gt[5];
                crs.transform_to(body, x, y).ok()
            }
        }
    }

    /// Degrees between finest samples at `(col, row)`: the smaller of the two axes.
    fn spacing_at(&self, col: f64, row: f64) -> Option<f64> {
        let c = self.lon_lat(col, row)?;
        let e = self.lon_lat(col + 1.0, row)?;
        let s = self.lon_lat(col, row + 1.0)?;
        Some(
            (e[0] - c[0])
                .hypot(e[1] - c[1])
                .min((s[0] - c[0]).hypot(s[1] - c[1])),
        )
    }

    /// Finest-grid coordinates of a longitude and latitude.
    fn to_samples(&self, lon: f64, lat: f64) -> Option<[f64; 2]> {
        match self {
            Self::Affine {
                lon0,
                dlon,
                lat0,
                dlat,
            } => Some([(lon - lon0) / dlon, (lat - lat0) / dlat]),
            Self::Projected {
                crs, body, inverse, ..
            } => {
                let [x, y] = body.transform_to(crs, lon, lat).ok()?;
                let c = inverse[0] + x * inverse[1] + y * inverse[2];
                let r = inverse[3] + x * inverse[4] + y * inverse[5];
                Some([c - 0.5, r - 0.5])
            }
        }
    }
}

/// The inverse of a GDAL geotransform, or `None` when it is singular.
fn invert(gt: &[f64; 6]) -> Option<[f64; 6]> {
    let det = gt[1] * gt[5] - gt[2] * gt[4];
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let (a, b, c, d) = (gt[5] / det, -gt[2] / det, -gt[4] / det, gt[1] / det);
    Some([
        -(a * gt[0] + b * gt[3]),
        a,
        b,
        -(c * gt[0] + d * gt[3]),
        c,
        d,
    ])
}

/// How one zoom is meshed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ZoomPlan {
    pub level: Level,
    /// RTIN square size, in cells of the level.
    pub square: u32,
    /// RTIN threshold (metres).
    pub tau: f64,
    /// The error CesiumJS assumes at this zoom, which every tile keeps within.
    pub geometric_error: f64,
    truth: Truth,
}

impl ZoomPlan {
    /// The same plan at another threshold (for benchmarks at equal error).
    pub fn with_tau(self, tau: f64) -> Self {
        Self { tau, ..self }
    }
}

/// One dataset as terrain: what `layer.json` says and how tiles are meshed.
#[derive(Debug)]
pub struct Terrain {
    geometry: TileGeometry,
    quantization: Quantization,
    mapping: Mapping,
    pub ellipsoid: Ellipsoid,
    pub level_zero_error: f64,
    geoid: Option<Arc<Geoid>>,
    /// Said in `layer.json` when heights could not be put on the ellipsoid.
    pub datum_warning: Option<String>,
    /// `[west, south, east, north]` of the finest samples' centres (the data region's
    /// bounding box; exact for a geographic grid).
    pub bounds: [f64; 4],
    pub max_zoom: u8,
    /// Degrees between finest samples at the data's centre (the smaller axis).
    spacing_deg: f64,
    /// Half a height step of the widest tile range possible.
    quantization_margin: f64,
    /// Per level: `e_L` from the tables and the largest leaf twist, once known.
    level_bounds: Mutex<HashMap<u8, (f64, Option<f64>)>>,
}

/// Why a dataset cannot be terrain.
pub type TerrainError = String;

impl Terrain {
    /// The terrain of a dataset, with `geoid` for EGM96 heights (when given).
    pub fn new(m: &Metadata, geoid: Option<Arc<Geoid>>) -> Result<Self, TerrainError> {
        let geometry = TileGeometry::new(m.width, m.height, m.tile_size)
            .map_err(|e| format!("bad tile geometry: {e:?}"))?;
        let georef = m
            .georef
            .as_ref()
            .ok_or("it has no georeferencing (build it from a georeferenced input, or with --crs and --bounds)")?;
        let crs = Crs::of(georef).ok_or("its CRS is not one the projection library knows")?;
        let (a, b) = crs.body_radii().ok_or("its CRS names no ellipsoid")?;
        let ellipsoid = Ellipsoid::new(a, b).ok_or("its CRS has no usable ellipsoid")?;
        // Earth datasets go to WGS 84 longitude and latitude, what Cesium's globe is;
        // other bodies to their own ellipsoid's.
        let earth = (a - Ellipsoid::WGS84.radii()[0]).abs() < 1000.0;
        let ellipsoid = if earth { Ellipsoid::WGS84 } else { ellipsoid };
        let gt = georef.geotransform;
        let plain_lon_lat = crs.is_geographic() && (!earth || crs.epsg() == Some(4326));
        let mapping = if plain_lon_lat && gt[2] == 0.0 && gt[4] == 0.0 {
            Mapping::Affine {
                lon0: gt[0] + 0.5 * gt[1],
                dlon: gt[1],
                lat0: gt[3] + 0.5 * gt[5],
                dlat: gt[5],
            }
        } else {
            let inverse = invert(&gt).ok_or("its geotransform is singular")?;
            let body = if earth {
                Crs::from_epsg(4326)
            } else {
                Crs::from_proj_string(&format!("+proj=longlat +a={a} +b={b} +no_defs"))
            }
            .map_err(|e| format!("{e:#}"))?;
            Mapping::Projected {
                crs: Box::new(crs),
                body: Box::new(body),
                gt,
                inverse,
            }
        };
        let (wm, hm) = (f64::from(m.width - 1), f64::from(m.height - 1));
        let mut bounds = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for k in 0..=16 {
            let t = f64::from(k) / 16.0;
            for (c, r) in [(t * wm, 0.0), (t * wm, hm), (0.0, t * hm), (wm, t * hm)] {
                let [lon, lat] = mapping
                    .lon_lat(c, r)
                    .ok_or("its corners do not transform to longitude and latitude")?;
                bounds = [
                    bounds[0].min(lon),
                    bounds[1].min(lat),
                    bounds[2].max(lon),
                    bounds[3].max(lat),
                ];
            }
        }
        if !(bounds[0] >= -180.0 && bounds[2] <= 180.0 && bounds[1] >= -90.0 && bounds[3] <= 90.0) {
            return Err(format!(
                "it spans longitudes {:.6}..{:.6} and latitudes {:.6}..{:.6}, outside −180..180 × −90..90 (the antimeridian is not handled)",
                bounds[0], bounds[2], bounds[1], bounds[3]
            ));
        }
        let (geoid, datum_warning) = match (m.vertical_datum, geoid) {
            (VerticalDatum::Ellipsoid, _) => (None, None),
            (VerticalDatum::Egm96, Some(g)) => (Some(g), None),
            (VerticalDatum::Egm96, None) => (
                None,
                Some("heights are above the EGM96 geoid and no geoid grid was found (--geoid): served as-is, up to ~100 m off the ellipsoid".to_string()),
            ),
            (VerticalDatum::Egm2008, _) => (
                None,
                Some("heights are above the EGM2008 geoid, which this server does not apply: served as-is, up to ~100 m off the ellipsoid".to_string()),
            ),
            (VerticalDatum::Unknown, _) => (
                None,
                Some("the dataset's vertical datum is unknown: heights are served as-is, as if above the ellipsoid".to_string()),
            ),
        };
        // The widest tile range: the data's, the geoid's whole range (−107..+86 m) and
        // sea level for the fill.
        let geoid_range = if geoid.is_some() { 200.0 } else { 0.0 };
        let range = m.max_height.max(0.0) - m.min_height.min(0.0) + geoid_range;
        let level_zero_error = level_zero_error(ellipsoid.maximum_radius());
        // The deepest zoom: tiles of at most 4 finest samples, where the mesh is the
        // data; and no deeper than the quantization leaves half the error to the mesh.
        let spacing = mapping
            .spacing_at(wm / 2.0, hm / 2.0)
            .ok_or("its centre does not transform")?;
        let mut max_zoom = 0;
        while max_zoom < MAX_ZOOM
            && CesiumTile::span(max_zoom) > 4.0 * spacing
            && 0.45 * geometric_error(level_zero_error, max_zoom + 1) >= range / 65534.0
        {
            max_zoom += 1;
        }
        Ok(Self {
            geometry,
            quantization: m.quantization,
            mapping,
            ellipsoid,
            level_zero_error,
            geoid,
            datum_warning,
            bounds,
            max_zoom,
            spacing_deg: spacing,
            quantization_margin: range / 65534.0,
            level_bounds: Mutex::new(HashMap::new()),
        })
    }

    /// The tiles of zoom `z` holding data: `[x0, y0, x1, y1]` inclusive.
    pub fn available(&self, z: u8) -> Option<[u32; 4]> {
        (z <= self.max_zoom)
            .then(|| CesiumTile::covering(z, self.bounds))
            .flatten()
    }

    /// Whether `tile` is one `layer.json` lists.
    pub fn is_available(&self, tile: CesiumTile) -> bool {
        self.available(tile.z).is_some_and(|[x0, y0, x1, y1]| {
            (x0..=x1).contains(&tile.x) && (y0..=y1).contains(&tile.y)
        })
    }

    /// Degrees between a level's samples (the smaller axis, at the centre).
    fn level_spacing_deg(&self, level: Level) -> f64 {
        // Locally linear: a level's spacing is its stride times the finest's.
        self.spacing_deg * self.geometry.spacing(level) as f64
    }

    /// The level, square size and threshold of zoom `z` (see the module doc).
    pub fn plan<D: LevelData>(&self, z: u8, data: &D) -> Result<ZoomPlan, D::Error> {
        let eps = geometric_error(self.level_zero_error, z);
        let finest = self.geometry.finest();
        let mut chosen = (finest, 0.0, Truth::Samples);
        for level in self.geometry.levels() {
            if level == finest {
                break;
            }
            let e = self.level_error(level, data)?;
            if e > eps / 2.0 {
                continue;
            }
            let twist = self.level_twist(level, data)?;
            if e + twist <= eps / 2.0 {
                chosen = (level, e, Truth::NorthWestDiagonal);
                break;
            }
        }
        let (level, e, truth) = chosen;
        let n = CesiumTile::span(z) / self.level_spacing_deg(level);
        let cells = (1u32 << level.get()) * self.geometry.tile_size();
        let quarter = (n / 4.0).clamp(2.0, f64::from(cells));
        let square = 1u32 << (quarter.log2().floor() as u32);
        Ok(ZoomPlan {
            level,
            square: square.clamp(2, cells),
            tau: 0.95 * eps - e - self.quantization_margin,
            geometric_error: eps,
            truth,
        })
    }

    fn level_error<D: LevelData>(&self, level: Level, data: &D) -> Result<f64, D::Error> {
        if let Some((e, _)) = self.lock().get(&level.get()) {
            return Ok(*e);
        }
        let e = data.level_error(level)?;
        self.lock().insert(level.get(), (e, None));
        Ok(e)
    }

    /// The largest half-twist of any cell of `level` (mesh.rs: the leaves' error).
    fn level_twist<D: LevelData>(&self, level: Level, data: &D) -> Result<f64, D::Error> {
        if let Some((_, Some(t))) = self.lock().get(&level.get()) {
            return Ok(*t);
        }
        let t_samples = self.geometry.tile_samples();
        let step = self.quantization.scale;
        let mut worst = 0_u32;
        for tile in self.geometry.present_tiles(level) {
            let Some(src) = data.tile(tile)? else {
                continue;
            };
            let h = &src.heights;
            for r in 0..t_samples - 1 {
                for c in 0..t_samples - 1 {
                    let q = |dc: usize, dr: usize| i64::from(h[(r + dr) * t_samples + c + dc]);
                    let twist = (q(0, 0) + q(1, 1) - q(1, 0) - q(0, 1)).unsigned_abs() as u32;
                    worst = worst.max(twist);
                }
            }
        }
        let t = 0.5 * f64::from(worst) * step;
        let e = self.level_error(level, data)?;
        self.lock().insert(level.get(), (e, Some(t)));
        Ok(t)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<u8, (f64, Option<f64>)>> {
        self.level_bounds
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Sea level at a point: the geoid's undulation above the ellipsoid, or 0.
    fn sea_level(&self, lon: f64, lat: f64) -> f64 {
        self.geoid.as_ref().map_or(0.0, |g| g.undulation(lon, lat))
    }

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
        let rect = tile.rect();
        let (stride, cells, data_box) = self.level_frame(plan.level);
        let mut builder = Builder::new(rect);
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
        Ok(builder.finish(self))
    }

    /// A level's stride (finest samples per level sample), its cells per side, and
    /// the data region in level coordinates (the DEM's finest sample centres).
    fn level_frame(&self, level: Level) -> (f64, u32, [f64; 4]) {
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

    /// An upper estimate of the memory [`Terrain::mesh_with`] uses for `tile`: its
    /// window of samples and the source tiles it holds (admission control reserves
    /// it before meshing: serve/compute.rs).
    pub fn mesh_bytes(&self, tile: CesiumTile, plan: &ZoomPlan) -> u64 {
        let (stride, cells, data_box) = self.level_frame(plan.level);
        let Some(sq) = self.squares(tile.rect(), plan, stride, cells, data_box) else {
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
        let t = self.geometry.tile_size();
        // Absent tiles lie wholly beyond the DEM: read the nearest present sample
        // (the padding repeats the DEM's edge), so every tile sees the same heights.
        let last_x = (f64::from(self.geometry.width() - 1) / stride).ceil() as u32;
        let last_y = (f64::from(self.geometry.height() - 1) / stride).ceil() as u32;
        // The last tile column and row holding samples up to `last_x`, `last_y`
        // (a sample on a tile border belongs to the tile before it too).
        let max_tx = (last_x.max(1) - 1) / t;
        let max_ty = (last_y.max(1) - 1) / t;
        let [ox0, oy0, ox1, oy1] = squares.outer;
        let s = plan.square;
        let (tx0, tx1) = ((ox0 * s / t).min(max_tx), (ox1 * s / t).min(max_tx));
        let (ty0, ty1) = ((oy0 * s / t).min(max_ty), (oy1 * s / t).min(max_ty));
        let ntx = tx1 - tx0 + 1;
        let mut tiles = Vec::with_capacity((ntx * (ty1 - ty0 + 1)) as usize);
        for ty in ty0..=ty1 {
            for tx in tx0..=tx1 {
                let id = TileId::new(plan.level, tx, ty).expect("inside the level");
                tiles.push(data.tile(id)?);
            }
        }
        let ts = self.geometry.tile_samples();
        let quant = self.quantization;
        let geoid = self.geoid.as_deref();
        let mapping = &self.mapping;
        let x_first = ox0 * s;
        let lons: Vec<f64> = match (geoid, mapping) {
            (Some(_), Mapping::Affine { .. }) => (x_first..=ox1 * s)
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
                    z + r.undulation(lons[(x - x_first) as usize])
                }
                Mapping::Projected { .. } => mapping
                    .lon_lat(f64::from(x) * stride, f64::from(y) * stride)
                    .map_or(z, |[lon, lat]| z + g.undulation(lon, lat)),
            }
        };
        let mut w = Window::new(s, cells, squares.outer, height).expect("squares inside the grid");
        w.compute_errors(plan.truth);
        Ok(w)
    }
}

#[derive(Clone, Copy, Debug)]
struct Squares {
    inner: [u32; 4],
    outer: [u32; 4],
}

/// A point being clipped: level coordinates (stage 1) or longitude/latitude
/// (stage 2), and its height.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Pt {
    x: f64,
    y: f64,
    h: f64,
}

impl Pt {
    fn key(self) -> (u64, u64) {
        (self.x.to_bits(), self.y.to_bits())
    }
}

/// What an edge of a clipped polygon lies on.
#[derive(Clone, Copy, Debug)]
enum Support {
    /// The segment between two points fixed before clipping (an original edge, or a
    /// piece of the data's boundary between two stage-1 points).
    Segment(Pt, Pt),
    /// A clip line of this stage.
    Line(usize),
}

/// An axis-aligned clip line: `x ≥ v`, `x ≤ v`, `y ≥ v` or `y ≤ v`.
#[derive(Clone, Copy, Debug)]
struct Line {
    vertical: bool,
    v: f64,
    keep_greater: bool,
}

impl Line {
    fn inside(self, p: Pt) -> bool {
        let c = if self.vertical { p.x } else { p.y };
        if self.keep_greater {
            c >= self.v
        } else {
            c <= self.v
        }
    }
}

/// The four lines of a box `[x0, y0, x1, y1]`.
fn box_lines(b: [f64; 4]) -> [Line; 4] {
    [
        Line {
            vertical: true,
            v: b[0],
            keep_greater: true,
        },
        Line {
            vertical: false,
            v: b[1],
            keep_greater: true,
        },
        Line {
            vertical: true,
            v: b[2],
            keep_greater: false,
        },
        Line {
            vertical: false,
            v: b[3],
            keep_greater: false,
        },
    ]
}

/// Where a segment crosses a line, computed from its endpoints in a fixed order so
/// that every triangle (and every tile) sharing the segment gets the same bits.
fn crossing(a: Pt, b: Pt, line: Line) -> Pt {
    let (p, q) = if (a.x, a.y) <= (b.x, b.y) {
        (a, b)
    } else {
        (b, a)
    };
    let (pc, qc) = if line.vertical {
        (p.x, q.x)
    } else {
        (p.y, q.y)
    };
    let t = (line.v - pc) / (qc - pc);
    let other = |pv: f64, qv: f64| pv + t * (qv - pv);
    let h = other(p.h, q.h);
    if line.vertical {
        Pt {
            x: line.v,
            y: other(p.y, q.y),
            h,
        }
    } else {
        Pt {
            x: other(p.x, q.x),
            y: line.v,
            h,
        }
    }
}

/// The height of triangle `t`'s plane at `(x, y)`.
fn plane(t: &[Pt; 3], x: f64, y: f64) -> f64 {
    let [a, b, c] = t;
    let det = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
    let l1 = ((x - a.x) * (c.y - a.y) - (c.x - a.x) * (y - a.y)) / det;
    let l2 = ((b.x - a.x) * (y - a.y) - (x - a.x) * (b.y - a.y)) / det;
    a.h + l1 * (b.h - a.h) + l2 * (c.h - a.h)
}

/// Sutherland–Hodgman against one line, keeping each edge's support.
fn clip(poly: &[(Pt, Support)], lines: &[Line; 4], k: usize, tri: &[Pt; 3]) -> Vec<(Pt, Support)> {
    let line = lines[k];
    let mut out = Vec::with_capacity(poly.len() + 2);
    for i in 0..poly.len() {
        let (a, sup) = poly[i];
        let b = poly[(i + 1) % poly.len()].0;
        let (ina, inb) = (line.inside(a), line.inside(b));
        if ina {
            out.push((a, sup));
        }
        if ina != inb {
            let p = match sup {
                Support::Segment(p, q) => crossing(p, q, line),
                Support::Line(j) => {
                    // Two lines of one box meet at its corner, inside the triangle.
                    let (vx, hy) = if lines[j].vertical {
                        (lines[j].v, line.v)
                    } else {
                        (line.v, lines[j].v)
                    };
                    Pt {
                        x: vx,
                        y: hy,
                        h: plane(tri, vx, hy),
                    }
                }
            };
            out.push((p, if ina { Support::Line(k) } else { sup }));
        }
    }
    // A point met twice in a row (a vertex on the line, then its crossing there):
    // keep one, with the later copy's support — the earlier copy's edge has no
    // length, the later one's is the real next edge.
    let mut kept: Vec<(Pt, Support)> = Vec::with_capacity(out.len());
    for (p, sup) in out {
        match kept.last_mut() {
            Some(last) if last.0.key() == p.key() => last.1 = sup,
            _ => kept.push((p, sup)),
        }
    }
    while kept.len() > 1 && kept[0].0.key() == kept[kept.len() - 1].0.key() {
        kept.pop();
    }
    kept
}

fn clip_box(poly: Vec<(Pt, Support)>, b: [f64; 4], tri: &[Pt; 3]) -> Vec<(Pt, Support)> {
    let lines = box_lines(b);
    let mut p = poly;
    for k in 0..4 {
        if p.len() < 3 {
            return Vec::new();
        }
        p = clip(&p, &lines, k, tri);
    }
    if p.len() < 3 { Vec::new() } else { p }
}

/// Collects a tile's vertices (deduplicated by position) and triangles.
struct Builder {
    rect: [f64; 4],
    index: FxHashMap<(u64, u64), u32>,
    points: Vec<Pt>,
    triangles: Vec<[u32; 3]>,
}

impl Builder {
    fn new(rect: [f64; 4]) -> Self {
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
    fn add_triangle(&mut self, terrain: &Terrain, t: [Pt; 3], stride: f64, data_box: [f64; 4]) {
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

    /// Fills what the data leaves of the tile, then quantizes positions.
    fn finish(mut self, terrain: &Terrain) -> TerrainMesh {
        self.fill(terrain);
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

    /// The rest of the rectangle: a constrained Delaunay triangulation of the data
    /// mesh's boundary and the tile's corners, keeping the faces outside the data.
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
        for [x, y] in corners {
            let p = Pt {
                x,
                y,
                h: terrain.sea_level(x, y),
            };
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

impl Terrain {
    /// Whether a longitude/latitude is inside the DEM's finest samples.
    fn inside_data(&self, lon: f64, lat: f64) -> bool {
        self.mapping.to_samples(lon, lat).is_some_and(|[c, r]| {
            c >= 0.0
                && r >= 0.0
                && c <= f64::from(self.geometry.width() - 1)
                && r <= f64::from(self.geometry.height() - 1)
        })
    }
}

/// A pyramid read directly (no server): for tests, benchmarks and tools. Decoded
/// tiles are kept, so a caller meshing many tiles decodes each source once.
#[derive(Debug)]
pub struct PyramidLevels<'a, S> {
    pyramid: &'a tessera_shared::Pyramid<S>,
    decoded: Mutex<HashMap<TileId, Option<Arc<SourceTile>>>>,
}

impl<'a, S: tessera_shared::ByteSource> PyramidLevels<'a, S> {
    pub fn new(pyramid: &'a tessera_shared::Pyramid<S>) -> Self {
        Self {
            pyramid,
            decoded: Mutex::new(HashMap::new()),
        }
    }
}

impl<S: tessera_shared::ByteSource> LevelData for PyramidLevels<'_, S> {
    type Error = String;

    fn tile(&self, tile: TileId) -> Result<Option<Arc<SourceTile>>, String> {
        let mut map = self
            .decoded
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(t) = map.get(&tile) {
            return Ok(t.clone());
        }
        let rec = self
            .pyramid
            .read_tile(tile)
            .map_err(|e| format!("{tile}: {e}"))?;
        let t = rec.map(|r| {
            Arc::new(SourceTile {
                heights: r.heights,
                mask: r.mask,
                quantization: self.pyramid.metadata().quantization,
            })
        });
        map.insert(tile, t.clone());
        Ok(t)
    }

    fn level_error(&self, level: Level) -> Result<f64, String> {
        let mut worst = 0.0_f64;
        for tile in self.pyramid.geometry().present_tiles(level) {
            if let Some(t) = self
                .pyramid
                .read_error_table(tile)
                .map_err(|e| format!("{tile}: {e}"))?
            {
                worst = worst.max(f64::from(t.full_resolution_error()));
            }
        }
        Ok(worst)
    }
}
