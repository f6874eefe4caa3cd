//! Brute-force checks of Cesium terrain tiles against a DEM's finest samples,
//! shared by tests/tests/cesium_terrain.rs, tests/tests/cesium_globe.rs and the
//! terrain benchmark (`examples/terrain_mesh.rs`).
//!
//! The truth is every stored finest sample of a pyramid whose grid is longitude and
//! latitude (placed from the georeferencing alone), in metres above the ellipsoid
//! (plus the geoid's undulation when one is given). A tile's surface is its
//! decoded triangles, linear in longitude and latitude as quantized-mesh defines it.

use tessera_server::cesium::quantized_mesh::TerrainMesh;
use tessera_server::geoid::Geoid;
use tessera_shared::{ByteSource, Pyramid};

/// The EGM96 grid (Debian's `proj-data`), or `None` (skipped) where it is missing
/// outside CI.
pub fn egm96_or_skip() -> Option<std::sync::Arc<Geoid>> {
    let Some(path) = tessera_server::geoid::find(None) else {
        assert!(
            std::env::var_os("CI").is_none(),
            "no EGM96 grid (install proj-data)"
        );
        eprintln!("SKIPPED: no EGM96 geoid grid (apt-get install proj-data)");
        return None;
    };
    Some(std::sync::Arc::new(
        Geoid::open(&path).expect("the EGM96 grid reads"),
    ))
}

/// The points of a mesh on one of its edges (`u` = 0 or 32767 for west or east, or
/// `v` for south or north): `(position along the edge, height bits)`, in order.
pub fn edge_points(mesh: &TerrainMesh, u: Option<u16>, v: Option<u16>) -> Vec<(u16, u64)> {
    let mut pts: Vec<(u16, u64)> = mesh
        .vertices
        .iter()
        .filter(|p| u.is_none_or(|u| p.u == u) && v.is_none_or(|v| p.v == v))
        .map(|p| (if u.is_some() { p.v } else { p.u }, p.height.to_bits()))
        .collect();
    pts.sort_unstable();
    pts
}

/// The finest samples of a geographic pyramid, on the ellipsoid.
#[derive(Debug)]
pub struct SampleGrid {
    pub lon0: f64,
    pub dlon: f64,
    pub lat0: f64,
    pub dlat: f64,
    pub width: u32,
    pub height: u32,
    /// Row-major, north row first.
    pub heights: Vec<f64>,
}

impl SampleGrid {
    /// Every stored finest sample of `pyramid`, `geoid` added when given.
    pub fn of<S: ByteSource>(pyramid: &Pyramid<S>, geoid: Option<&Geoid>) -> Self {
        let m = pyramid.metadata();
        let g = *pyramid.geometry();
        let gt = m
            .georef
            .as_ref()
            .expect("a georeferenced pyramid")
            .geotransform;
        let mut grid = Self {
            lon0: gt[0] + 0.5 * gt[1],
            dlon: gt[1],
            lat0: gt[3] + 0.5 * gt[5],
            dlat: gt[5],
            width: m.width,
            height: m.height,
            heights: vec![f64::NAN; (m.width * m.height) as usize],
        };
        let t = g.tile_size();
        for tile in g.present_tiles(g.finest()) {
            let rec = pyramid.read_tile(tile).unwrap().unwrap();
            for r in 0..=t {
                for c in 0..=t {
                    let (x, y) = (tile.x() * t + c, tile.y() * t + r);
                    if x < m.width && y < m.height {
                        let mut h = m
                            .quantization
                            .height(rec.heights[(r * (t + 1) + c) as usize]);
                        if let Some(geoid) = geoid {
                            let [lon, lat] = grid.lon_lat(f64::from(x), f64::from(y));
                            h += geoid.undulation(lon, lat);
                        }
                        grid.heights[(y * m.width + x) as usize] = h;
                    }
                }
            }
        }
        grid
    }

    pub fn lon_lat(&self, col: f64, row: f64) -> [f64; 2] {
        [self.lon0 + col * self.dlon, self.lat0 + row * self.dlat]
    }

    fn col(&self, lon: f64) -> f64 {
        (lon - self.lon0) / self.dlon
    }

    fn row(&self, lat: f64) -> f64 {
        (lat - self.lat0) / self.dlat
    }

    /// Bilinear between the four samples around a point (clamped to the grid).
    pub fn bilinear(&self, lon: f64, lat: f64) -> f64 {
        let c = self.col(lon).clamp(0.0, f64::from(self.width - 1));
        let r = self.row(lat).clamp(0.0, f64::from(self.height - 1));
        let (c0, r0) = (
            (c.floor() as u32).min(self.width - 2),
            (r.floor() as u32).min(self.height - 2),
        );
        let (fc, fr) = (c - f64::from(c0), r - f64::from(r0));
        let at = |dc: u32, dr: u32| self.heights[((r0 + dr) * self.width + c0 + dc) as usize];
        let top = at(0, 0) + fc * (at(1, 0) - at(0, 0));
        let bottom = at(0, 1) + fc * (at(1, 1) - at(0, 1));
        top + fr * (bottom - top)
    }

    /// The worst vertical distance between the surface `(positions, triangles)` —
    /// longitude, latitude, height per vertex — and the samples inside `rect`
    /// (closed), the samples checked, and how many of them no triangle covers.
    pub fn worst_error(
        &self,
        rect: [f64; 4],
        positions: &[[f64; 3]],
        triangles: &[[u32; 3]],
    ) -> Check {
        let c0 = self.col(rect[0]).ceil().max(0.0) as i64;
        let c1 = self.col(rect[2]).floor().min(f64::from(self.width - 1)) as i64;
        let (ra, rb) = (self.row(rect[3]), self.row(rect[1]));
        let r0 = ra.min(rb).ceil().max(0.0) as i64;
        let r1 = ra.max(rb).floor().min(f64::from(self.height - 1)) as i64;
        if c0 > c1 || r0 > r1 {
            return Check::default();
        }
        let nc = (c1 - c0 + 1) as usize;
        let mut err = vec![f64::NAN; nc * (r1 - r0 + 1) as usize];
        for t in triangles {
            let [a, b, c] = t.map(|i| positions[i as usize]);
            let det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
            if det == 0.0 {
                continue;
            }
            let lo = [a[0].min(b[0]).min(c[0]), a[1].min(b[1]).min(c[1])];
            let hi = [a[0].max(b[0]).max(c[0]), a[1].max(b[1]).max(c[1])];
            let (ca, cb) = (
                self.col(lo[0]).ceil() as i64,
                self.col(hi[0]).floor() as i64,
            );
            let (y0, y1) = (self.row(hi[1]), self.row(lo[1]));
            let (ya, yb) = (y0.min(y1).ceil() as i64, y0.max(y1).floor() as i64);
            for r in ya.max(r0)..=yb.min(r1) {
                for cc in ca.max(c0)..=cb.min(c1) {
                    let [x, y] = self.lon_lat(cc as f64, r as f64);
                    let l1 = ((x - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (y - a[1])) / det;
                    let l2 = ((b[0] - a[0]) * (y - a[1]) - (x - a[0]) * (b[1] - a[1])) / det;
                    let l0 = 1.0 - l1 - l2;
                    // A sample on a shared edge may fall a rounding error outside both.
                    let tol = -1e-9;
                    if l0 < tol || l1 < tol || l2 < tol {
                        continue;
                    }
                    let h = l0 * a[2] + l1 * b[2] + l2 * c[2];
                    let want = self.heights[(r as u32 * self.width + cc as u32) as usize];
                    let k = (r - r0) as usize * nc + (cc - c0) as usize;
                    let e = (h - want).abs();
                    err[k] = if err[k].is_nan() { e } else { err[k].max(e) };
                }
            }
        }
        Check {
            worst: err
                .iter()
                .copied()
                .filter(|e| !e.is_nan())
                .fold(0.0, f64::max),
            samples: err.len(),
            holes: err.iter().filter(|e| e.is_nan()).count(),
        }
    }

    /// A regular `n × n`-sample heightmap over `rect`, bilinear from the samples (as
    /// a heightmap terrain tile would be): positions and its `2(n−1)²` triangles.
    pub fn regular_grid(&self, rect: [f64; 4], n: u32) -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let f = |i: u32| f64::from(i) / f64::from(n - 1);
        let mut pos = Vec::with_capacity((n * n) as usize);
        for j in 0..n {
            for i in 0..n {
                let lon = rect[0] + (rect[2] - rect[0]) * f(i);
                let lat = rect[1] + (rect[3] - rect[1]) * f(j);
                pos.push([lon, lat, self.bilinear(lon, lat)]);
            }
        }
        let mut tris = Vec::with_capacity((2 * (n - 1) * (n - 1)) as usize);
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                let k = j * n + i;
                tris.push([k, k + 1, k + n + 1]);
                tris.push([k, k + n + 1, k + n]);
            }
        }
        (pos, tris)
    }
}

/// What [`SampleGrid::worst_error`] found.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Check {
    pub worst: f64,
    pub samples: usize,
    pub holes: usize,
}
