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
    sphere_of(&shell_points(globe, min, max))
}

fn sphere_of(points: &[DVec3]) -> Sphere {
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

/// The shell's boundary samples (corners, edge midpoints, centre), each at the
/// lowest then the highest height, in ECEF.
fn shell_points(
    globe: &Globe,
    min: DVec3,
    max: DVec3,
) -> [DVec3; (SAMPLES * SAMPLES * 2) as usize] {
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
    points
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

/// A lower bound on the distance from the flat-world eye `eye` to the curved box
/// `min..max` (ρ's `d` must never be overestimated), the larger of two:
/// - to its bounding sphere (0 inside; tight when the eye is off to the side);
/// - above the shell: `|E| − max |P|` over the shell's points `P`, by the triangle
///   inequality through the body's centre (`|E − P| ≥ |E| − |P|`); tight when the
///   eye is over the box, where the eye is usually inside the sphere (a camera
///   100 m above a block several kilometres wide), which alone would make ρ
///   infinite there.
///
/// `max |P|` is taken over the samples at the highest height and widened by
/// `(a − b)·Δφ²` plus a metre: at a fixed height `|P|` only varies with latitude,
/// monotonically in `|φ|`, so the samples' largest is the largest except where the
/// box straddles the equator, by at most `(a − b)·Δφ²` for a box `Δφ` tall.
pub fn distance(globe: &Globe, eye: &EyeFrame, min: DVec3, max: DVec3) -> f64 {
    let points = shell_points(globe, min, max);
    let s = sphere_of(&points);
    let e = eye.ecef;
    let to_sphere = (e.distance(s.centre) - s.radius).max(0.0);
    let beside = local_box_distance(globe, eye, &points, min.y);
    let top = points
        .iter()
        .skip(1)
        .step_by(2)
        .map(|p| p.length())
        .fold(0.0, f64::max);
    let (a, b) = (
        globe.ellipsoid.equatorial_radius(),
        globe.ellipsoid.polar_radius(),
    );
    let span = (max.z - min.z).abs() / b;
    let above = e.length() - top - ((a - b) * span * span + 1.0);
    to_sphere.max(above).max(beside)
}

/// A lower bound on the distance from the eye to the shell through the eye's local
/// frame: the distance to the box, in east/up/south axes, around the shell's samples,
/// widened by how far the shell can bulge between them. Tight when the eye is beside
/// a block (a canyon's wall that rises above the eye), where both other bounds are 0:
/// the eye is inside the wall block's bounding sphere and below its top.
///
/// The shell is the union of radial segments between its lowest and highest height,
/// so every point lies between two points at those heights over the same position.
/// A point of a surface of constant height lies within `c²/4ρ` of the box of the
/// sample cell around it (`c` the cell's diagonal chord, `ρ` the smallest radius of
/// curvature at that height: a chord of length `c` on a circle of radius `ρ` stands
/// `c²/8ρ` from its arc; doubled for the cell's two directions), plus a metre for
/// rounding.
fn local_box_distance(
    globe: &Globe,
    frame: &EyeFrame,
    points: &[DVec3; (SAMPLES * SAMPLES * 2) as usize],
    lowest: f64,
) -> f64 {
    let (lo, hi) = points.iter().fold(
        (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN)),
        |(lo, hi), p| {
            let l = frame.local(*p);
            (lo.min(l), hi.max(l))
        },
    );
    // Samples are stored (i, j) row-major, each at the lowest then the highest height.
    let at = |i: u32, j: u32, top: usize| points[((j * SAMPLES + i) * 2) as usize + top];
    let mut c = 0f64;
    for j in 0..SAMPLES - 1 {
        for i in 0..SAMPLES - 1 {
            for top in 0..2 {
                c = c
                    .max(at(i, j, top).distance(at(i + 1, j + 1, top)))
                    .max(at(i + 1, j, top).distance(at(i, j + 1, top)));
            }
        }
    }
    let (a, b) = (
        globe.ellipsoid.equatorial_radius(),
        globe.ellipsoid.polar_radius(),
    );
    let rho = (b * b / a + lowest.min(0.0)).max(1.0);
    let margin = c * c / (4.0 * rho) + 1.0;
    let nearest = DVec3::ZERO.clamp(lo - margin, hi + margin);
    nearest.length()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::globe::fixtures::{alps, moon, nearest_sampled};
    use glam::DVec2;

    /// The whole moon 8192² dataset (32°) from −6 km to +4 km, as a map box.
    fn moon_box(g: &Globe) -> (DVec3, DVec3) {
        (
            DVec3::new(0.0, -6000.0, 0.0),
            DVec3::new(8192.0 * g.spacing.x, 4000.0, 8192.0 * g.spacing.y),
        )
    }

    #[test]
    fn the_sphere_holds_the_whole_shell() {
        let g = moon();
        let (min, max) = moon_box(&g);
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

    #[test]
    fn the_distance_from_above_a_block_is_its_height_gap_and_never_more() {
        let g = alps(1200.0, DVec2::new(63.2, 92.6));
        // A 64-sample block (4 × 6 km) from 500 to 700 m, the eye 400 m over its
        // middle at 1100 m: inside the block's bounding sphere, 400 m above it.
        let (min, max) = (
            DVec3::new(0.0, 500.0, 0.0),
            DVec3::new(64.0 * 63.2, 700.0, 64.0 * 92.6),
        );
        let eye = DVec3::new(32.0 * 63.2, 1100.0, 32.0 * 92.6);
        let s = sphere(&g, min, max);
        assert!(
            g.ecef_of_world(eye).distance(s.centre) < s.radius,
            "the eye is inside the sphere"
        );
        let d = distance(&g, &EyeFrame::of_world(&g, eye), min, max);
        // The top surface under the eye, 400 m down, is the nearest.
        let nearest = nearest_sampled(&g, eye, min, max, 64, &[500.0, 600.0, 700.0]);
        assert!(d <= nearest, "{d} overestimates {nearest}");
        assert!(
            d > 0.8 * nearest,
            "{d} is far below {nearest}: ρ would be needlessly large"
        );
    }

    #[test]
    fn the_distance_beside_a_wall_that_rises_above_the_eye_is_not_zero() {
        let g = alps(3600.0, DVec2::new(21.1, 30.9));
        // A 32-sample block (675 × 989 m) from 900 to 2500 m; the eye at 1200 m,
        // 300 m west of it: inside its bounding sphere and below its top, so the
        // sphere and the height gap both say 0 (ρ would be infinite).
        let (min, max) = (
            DVec3::new(100.0 * 21.1, 900.0, 100.0 * 30.9),
            DVec3::new(132.0 * 21.1, 2500.0, 132.0 * 30.9),
        );
        let eye = DVec3::new(min.x - 300.0, 1200.0, 116.0 * 30.9);
        let s = sphere(&g, min, max);
        assert!(g.ecef_of_world(eye).distance(s.centre) < s.radius);
        let d = distance(&g, &EyeFrame::of_world(&g, eye), min, max);
        let heights: Vec<f64> = (0..=16).map(|k| 900.0 + 100.0 * f64::from(k)).collect();
        let nearest = nearest_sampled(&g, eye, min, max, 64, &heights);
        assert!(d <= nearest, "{d} overestimates {nearest}");
        assert!(d > 0.8 * nearest, "{d} is far below {nearest}");
    }

    #[test]
    fn the_local_bound_never_overestimates_on_a_whole_moon_tile() {
        let g = moon();
        // The whole dataset and eyes all around it, low and high: the bound stays
        // below the nearest of a dense sample of the shell.
        let (min, max) = moon_box(&g);
        for (ex, ez, eh) in [
            (-0.2, 0.5, 1000.0),
            (0.5, 0.5, 5000.0),
            (1.3, 1.1, 200_000.0),
            (0.1, -0.05, 4500.0),
        ] {
            let eye = DVec3::new(ex * max.x, eh, ez * max.z);
            let d = distance(&g, &EyeFrame::of_world(&g, eye), min, max);
            let nearest = nearest_sampled(&g, eye, min, max, 128, &[-6000.0, 4000.0]);
            assert!(d <= nearest, "eye {eye}: {d} overestimates {nearest}");
        }
    }
}
