//! An ellipsoid of revolution and geodetic → Earth-centred, Earth-fixed (ECEF)
//! coordinates.

use glam::DVec3;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ellipsoid {
    /// Semi-major (equatorial) axis, metres.
    pub a: f64,
    /// Semi-minor (polar) axis, metres.
    pub b: f64,
    /// First eccentricity squared, `1 − b²/a²`.
    pub e2: f64,
}

impl Ellipsoid {
    /// `a ≥ b > 0`, finite; `None` otherwise.
    pub fn new(a: f64, b: f64) -> Option<Self> {
        (a.is_finite() && b > 0.0 && b <= a).then(|| Self {
            a,
            b,
            e2: 1.0 - (b * b) / (a * a),
        })
    }

    /// Prime vertical radius of curvature `N(φ) = a / √(1 − e² sin²φ)`.
    pub fn n(&self, lat: f64) -> f64 {
        let s = lat.sin();
        self.a / (1.0 - self.e2 * s * s).sqrt()
    }

    /// ECEF of longitude, latitude (radians, geodetic) and height above the ellipsoid:
    /// `((N+h) cosφ cosλ, (N+h) cosφ sinλ, (N(1−e²)+h) sinφ)`.
    pub fn ecef(&self, lon: f64, lat: f64, h: f64) -> DVec3 {
        let n = self.n(lat);
        let (sl, cl) = lon.sin_cos();
        let (sp, cp) = lat.sin_cos();
        DVec3::new(
            (n + h) * cp * cl,
            (n + h) * cp * sl,
            (n * (1.0 - self.e2) + h) * sp,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equator_and_pole() {
        let w = Ellipsoid::new(6_378_137.0, 6_356_752.314_245).unwrap();
        let p = w.ecef(0.0, 0.0, 100.0);
        assert!((p - DVec3::new(6_378_237.0, 0.0, 0.0)).length() < 1e-6);
        let p = w.ecef(90f64.to_radians(), 0.0, 0.0);
        assert!((p - DVec3::new(0.0, 6_378_137.0, 0.0)).length() < 1e-6);
        let p = w.ecef(0.3, 90f64.to_radians(), -50.0);
        assert!((p - DVec3::new(0.0, 0.0, 6_356_702.314_245)).length() < 1e-6);
        assert!(Ellipsoid::new(1.0, 2.0).is_none());
    }
}
