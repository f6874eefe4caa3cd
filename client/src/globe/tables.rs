//! Eye-relative position tables: how `relative()` in `terrain.wgsl` makes globe
//! positions in f32 that are exact near the eye and far from it alike.
//!
//! With `C_i, S_i` the cosine and sine of column `i`'s longitude, `c_j, s_j` of row
//! `j`'s latitude, `N_j` its prime vertical radius, and the eye at height `h_e`,
//! longitude `λ_e`, `K = (N_e + h_e) cos φ_e`, `Z_e` its ECEF z:
//!
//! ```text
//! X − X_e = A_j·C_i + K·(C_i − C_e) + (h − h_e)·c_j·C_i,   A_j = (N_j + h_e)·c_j − K
//! Y − Y_e = A_j·S_i + K·(S_i − S_e) + (h − h_e)·c_j·S_i
//! Z − Z_e = B_j + (h − h_e)·s_j,                           B_j = (N_j(1−e²) + h_e)·s_j − Z_e
//! ```
//!
//! `A_j`, `B_j`, `C_i − C_e`, `S_i − S_e` are formed in f64 on the CPU each frame and
//! stored as f32; every term is then at most about the distance from the eye, so
//! f32's relative error (6·10⁻⁸) makes an absolute error proportional to that
//! distance: micrometres a metre from the eye, a metre 10 000 km away. No emulated
//! double arithmetic is needed, and a vertex's position depends only on its global
//! column, row and height (the same floats on both sides of a shared edge,
//! docs/ARCHITECTURE.md#crack-free-edges). The result is rotated into the eye's local
//! frame ([`super::frame`]).

use super::Globe;
use super::frame::EyeFrame;
use glam::{DVec3, Mat3, Vec3};

/// Per-frame tables: `rows[j] = (A_j, B_j, c_j, s_j)`, `cols[i] = (C_i − C_e,
/// S_i − S_e, C_i, S_i)`, and the scalars `K` and `h_e`.
#[derive(Clone, Debug, PartialEq)]
pub struct EyeTables {
    pub rows: Vec<[f32; 4]>,
    pub cols: Vec<[f32; 4]>,
    pub k: f32,
    pub eye_height: f32,
    /// ECEF → local (east, up, south), rows.
    pub to_local: Mat3,
}

impl EyeTables {
    /// Tables for finest columns `0..cols` and rows `0..rows`, seen from `eye`.
    pub fn new(globe: &Globe, eye: &EyeFrame, cols: u32, rows: u32) -> Self {
        let e = &globe.ellipsoid;
        let he = eye.height;
        let k = (e.prime_vertical_radius(eye.lat) + he) * eye.lat.cos();
        let ze = eye.ecef.z;
        let (se, ce) = eye.lon.sin_cos();
        let rows = (0..rows)
            .map(|j| {
                let (_, lat) = globe.grid.lon_lat(0.0, f64::from(j));
                let (s, c) = lat.sin_cos();
                let n = e.prime_vertical_radius(lat);
                [
                    ((n + he) * c - k) as f32,
                    ((n * (1.0 - e.eccentricity_squared()) + he) * s - ze) as f32,
                    c as f32,
                    s as f32,
                ]
            })
            .collect();
        let cols = (0..cols)
            .map(|i| {
                let (lon, _) = globe.grid.lon_lat(f64::from(i), 0.0);
                let (s, c) = lon.sin_cos();
                [(c - ce) as f32, (s - se) as f32, c as f32, s as f32]
            })
            .collect();
        Self {
            rows,
            cols,
            k: k as f32,
            eye_height: he as f32,
            to_local: eye.to_local.as_mat3(),
        }
    }

    /// The position `relative()` makes of column `x`, row `y`, height `h` (f32, as
    /// the shader computes it, up to the GPU's contraction of multiply-adds).
    pub fn relative(&self, x: u32, y: u32, h: f32) -> Vec3 {
        let r = self.rows[y as usize];
        let c = self.cols[x as usize];
        let dh = h - self.eye_height;
        let ecef = Vec3::new(
            r[0] * c[2] + self.k * c[0] + dh * r[2] * c[2],
            r[0] * c[3] + self.k * c[1] + dh * r[2] * c[3],
            r[1] + dh * r[3],
        );
        self.to_local * ecef
    }
}

/// The exact (f64) position of `(x, y, h)` in the eye's local frame.
pub fn exact_relative(globe: &Globe, eye: &EyeFrame, x: f64, y: f64, h: f64) -> DVec3 {
    eye.local(globe.ecef(x, y, h))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::globe::fixtures::moon;
    use crate::globe::grid::LonLatGrid;
    use glam::DVec2;

    fn alps() -> Globe {
        crate::globe::fixtures::alps(1200.0, DVec2::new(63.97, 92.63))
    }

    /// An independent geodetic → ECEF (Bowring's form with `b²/a²`, not `1 − e²`).
    fn independent(a: f64, b: f64, lon_deg: f64, lat_deg: f64, h: f64) -> DVec3 {
        let (lon, lat) = (lon_deg.to_radians(), lat_deg.to_radians());
        let n = a * a / ((a * lat.cos()).powi(2) + (b * lat.sin()).powi(2)).sqrt();
        DVec3::new(
            (n + h) * lat.cos() * lon.cos(),
            (n + h) * lat.cos() * lon.sin(),
            (n * b * b / (a * a) + h) * lat.sin(),
        )
    }

    #[test]
    fn the_mirror_matches_an_independent_geodetic_to_ecef() {
        let g = alps();
        let (a, b) = (g.ellipsoid.equatorial_radius(), g.ellipsoid.polar_radius());
        // Grid point (x, y) is at (8 + x/1200, 47 − y/1200) degrees.
        for (x, y, h) in [
            (0.0, 0.0, 0.0),
            (600.0, 600.0, 4000.0),
            (1200.0, 1200.0, -400.0),
        ] {
            let want = independent(a, b, 8.0 + x / 1200.0, 47.0 - y / 1200.0, h);
            assert!((g.ecef(x, y, h) - want).length() < 1e-3, "{x} {y} {h}");
        }
        // The equator and the pole on a grid that reaches them.
        let mut e = g;
        e.grid = LonLatGrid {
            lon0: 0.0,
            dlon: 1.0,
            lat0: 0.0,
            dlat: 1.0,
        };
        assert!((e.ecef(0.0, 0.0, 10.0) - DVec3::new(a + 10.0, 0.0, 0.0)).length() < 1e-3);
        assert!((e.ecef(0.0, 90.0, 10.0) - DVec3::new(0.0, 0.0, b + 10.0)).length() < 1e-3);
        assert!(
            (e.ecef(45.0, 30.0, 8848.0) - independent(a, b, 45.0, 30.0, 8848.0)).length() < 1e-3
        );
    }

    /// A camera 1 m above the ground and one 10 000 km away: neighbouring vertices
    /// near the camera are apart by the right amount to well under a centimetre in
    /// f32, and positions anywhere are within a part in 10⁶ of their distance.
    #[test]
    fn f32_positions_are_exact_near_the_eye_and_far_from_it() {
        for g in [moon(), alps()] {
            let (cx, cy) = (700u32, 900u32);
            let ground = 1234.5f64;
            let world = |x: f64, y: f64, h: f64| DVec3::new(x * g.spacing.x, h, y * g.spacing.y);
            for altitude in [1.0, 1.0e7] {
                let eye = EyeFrame::of_world(
                    &g,
                    world(f64::from(cx) + 0.3, f64::from(cy) + 0.6, ground + altitude),
                );
                let t = EyeTables::new(&g, &eye, 1201, 1201);
                let exact = |x: u32, y: u32, h: f32| {
                    exact_relative(&g, &eye, f64::from(x), f64::from(y), f64::from(h))
                };
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (5, -3), (-2, 4)] {
                    let (x, y) = (
                        cx.checked_add_signed(dx).unwrap(),
                        cy.checked_add_signed(dy).unwrap(),
                    );
                    let h = ground as f32 + 0.25;
                    let p = exact(x, y, h);
                    let abs = (t.relative(x, y, h).as_dvec3() - p).length();
                    assert!(
                        abs <= 2e-6 * p.length().max(1.0),
                        "altitude {altitude}: off by {abs} m at {} m",
                        p.length()
                    );
                    if altitude == 1.0 {
                        // Neighbours (one column, one row, a diagonal step) near the
                        // camera: their difference is right to well under 1 cm.
                        for (x2, y2) in [(x + 1, y), (x, y + 1), (x + 1, y + 1)] {
                            let got = t.relative(x2, y2, h) - t.relative(x, y, h);
                            let want = exact(x2, y2, h) - p;
                            let err = (got.as_dvec3() - want).length();
                            assert!(err < 1e-4, "neighbour step off by {err} m");
                        }
                    }
                }
            }
        }
    }
}
