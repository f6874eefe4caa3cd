//! Bounding volumes of curved tiles: a flat-world box (grid extent × height range)
//! becomes, on the globe, the curved shell between two heights over a
//! longitude/latitude rectangle; it is bounded by a sphere holding that shell.

use super::Globe;
use super::frame::EyeFrame;
use super::horizon;
use glam::DVec3;

/// A sphere in ECEF metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    pub centre: DVec3,
    pub radius: f64,
}

/// Samples per side of the rectangle (corners, edge points, inside) at both heights.
const SAMPLES: u32 = 3;

/// A sphere holding the shell over the flat-world box `min..max` (`x`, `z` the grid
/// extent in metres, `y` the heights). The shell's points farthest from the centre
/// are on its boundary at the lowest or highest height; the boundary is sampled
/// (corners and edge midpoints) and the radius widened by 1 % plus a metre for the
/// curvature between samples and rounding.
pub fn sphere(globe: &Globe, min: DVec3, max: DVec3) -> Sphere {
    let mut points = [DVec3::ZERO; (SAMPLES * SAMPLES * 2) as usize];
    let mut k = 0;
    let last = f64::from(SAMPLES - 1);
    for j in 0..SAMPLES {
        for i in 0..SAMPLES {
            let (fi, fj) = (f64::from(i) / last, f64::from(j) / last);
            let x = min.x + (max.x - min.x) * fi;
            let z = min.z + (max.z - min.z) * fj;
            for h in [min.y, max.y] {
                points[k] = globe.ecef_of_world(DVec3::new(x, h, z));
                k += 1;
            }
        }
    }
    let (lo, hi) = points.iter().fold(
        (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN)),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    );
    let centre = (lo + hi) * 0.5;
    let r = points
        .iter()
        .map(|p| p.distance(centre))
        .fold(0.0, f64::max);
    Sphere {
        centre,
        radius: r * 1.01 + 1.0,
    }
}

/// What culling and the error metric need on the globe for one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GlobeView {
    pub globe: Globe,
    pub eye: EyeFrame,
}

impl GlobeView {
    /// A box's bounding sphere in the eye's local frame (eye at the origin) and
    /// whether it is wholly behind the limb.
    pub fn local_sphere(&self, min: DVec3, max: DVec3) -> (DVec3, f64, bool) {
        let s = sphere(&self.globe, min, max);
        let hidden = horizon::hidden(
            self.eye.ecef,
            self.globe.occluder_radius(),
            s.centre,
            s.radius,
        );
        (self.eye.local(s.centre), s.radius, hidden)
    }
}

/// Distance from the flat-world eye `eye` to the curved box `min..max`: to its
/// bounding sphere (0 inside).
pub fn distance(globe: &Globe, eye: DVec3, min: DVec3, max: DVec3) -> f64 {
    let s = sphere(globe, min, max);
    (globe.ecef_of_world(eye).distance(s.centre) - s.radius).max(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::globe::ellipsoid::Ellipsoid;
    use crate::globe::grid::LonLatGrid;
    use glam::DVec2;

    #[test]
    fn the_sphere_holds_the_whole_shell() {
        let g = Globe {
            ellipsoid: Ellipsoid::new(1_737_400.0, 1_737_400.0).unwrap(),
            grid: LonLatGrid {
                lon0: 43.0,
                dlon: 1.0 / 256.0,
                lat0: 33.0,
                dlat: -1.0 / 256.0,
            },
            spacing: DVec2::new(100.0, 118.45),
            min_height: -5547.0,
        };
        // A 32° tile (the whole moon 8192² dataset) from -6 km to +4 km.
        let (min, max) = (
            DVec3::new(0.0, -6000.0, 0.0),
            DVec3::new(8192.0 * 100.0, 4000.0, 8192.0 * 118.45),
        );
        let s = sphere(&g, min, max);
        for j in 0..=40 {
            for i in 0..=40 {
                for h in [-6000.0, 0.0, 4000.0] {
                    let p = g.ecef(
                        f64::from(i) * 8192.0 / 40.0,
                        f64::from(j) * 8192.0 / 40.0,
                        h,
                    );
                    assert!(p.distance(s.centre) <= s.radius, "({i}, {j}, {h}) outside");
                }
            }
        }
        // Not absurdly loose: the smallest such sphere is half the diagonal or more.
        let diag = g
            .ecef(0.0, 0.0, 4000.0)
            .distance(g.ecef(8192.0, 8192.0, 4000.0));
        assert!(s.radius < 0.56 * diag, "{} vs {diag}", s.radius);
    }
}
