//! Horizon culling: a tile wholly behind the limb of the body is not drawn or
//! fetched. The occluder is a sphere inside the body under every point of the
//! dataset ([`super::Globe::occluder_radius`]), so the test is conservative.

use glam::DVec3;

/// Whether the sphere (`centre`, `radius`) (ECEF) is wholly hidden from `eye` by
/// the sphere of radius `occluder` about the body's centre.
///
/// A point is hidden when it lies beyond the plane of the horizon circle (the
/// tangent points seen from the eye) and inside the cone of rays from the eye that
/// meet the occluder: every such ray first meets the occluder's near cap, which is
/// on the eye's side of that plane.
pub fn hidden(eye: DVec3, occluder: f64, centre: DVec3, radius: f64) -> bool {
    let d = eye.length();
    if d <= occluder || occluder <= 0.0 {
        return false;
    }
    let axis = eye / d;
    // Some of the sphere is on the eye's side of the horizon plane.
    if centre.dot(axis) + radius >= occluder * occluder / d {
        return false;
    }
    let v = centre - eye;
    let dv = v.length();
    if dv <= radius {
        return false;
    }
    let angle = (v.dot(-axis) / dv).clamp(-1.0, 1.0).acos();
    let cone = (occluder / d).asin();
    angle + (radius / dv).asin() <= cone
}

#[cfg(test)]
mod tests {
    use super::*;

    const MOON: f64 = 1_737_400.0;

    #[test]
    fn the_far_side_is_hidden_and_the_near_side_is_not() {
        // The eye 1000 km above the Moon's (1, 0, 0) point.
        let eye = DVec3::new(MOON + 1.0e6, 0.0, 0.0);
        let occ = MOON - 9000.0;
        // A 20 km tile on the far side, at the antipode and 100° around.
        let far = DVec3::new(-MOON, 0.0, 0.0);
        assert!(hidden(eye, occ, far, 20_000.0));
        let around = DVec3::new(100f64.to_radians().cos(), 100f64.to_radians().sin(), 0.0) * MOON;
        assert!(hidden(eye, occ, around, 20_000.0));
        // Near side: below the eye and 40° around (the horizon is at ~52°).
        assert!(!hidden(eye, occ, DVec3::new(MOON, 0.0, 0.0), 20_000.0));
        let side = DVec3::new(40f64.to_radians().cos(), 0.0, 40f64.to_radians().sin()) * MOON;
        assert!(!hidden(eye, occ, side, 20_000.0));
        // A tile just beyond the horizon but with mountains reaching over it (a big
        // bounding sphere) is kept.
        let beyond = DVec3::new(60f64.to_radians().cos(), 0.0, 60f64.to_radians().sin()) * MOON;
        assert!(hidden(eye, occ, beyond, 10_000.0));
        assert!(!hidden(eye, occ, beyond, 400_000.0));
    }
}
