//! The body's reference ellipsoid and geodetic → Earth-centred, Earth-fixed (ECEF)
//! coordinates: the one place both the client's globe and the server's Cesium
//! headers take positions from, so the two agree on where a height is.
//!
//! An ellipsoid of revolution centred on the origin: semi-axes along ECEF x, y
//! (the equatorial radius `a`) and z (the polar radius `b`), in metres. Angles are
//! radians. The surface point of a geodetic position is where its normal `n`
//! meets the ellipsoid: `(a²nx, a²ny, b²nz)` scaled onto the surface, which is the
//! prime-vertical form `N(φ)·(cosφ cosλ, cosφ sinλ, (b²/a²) sinφ)`; the height is
//! then added along `n` (the form CesiumJS's `Cartographic → Cartesian3` uses, so
//! a quantized-mesh header means to the client what the server meant).
//!
//! ```
//! use glam::DVec3;
//! use tessera_shared::ellipsoid::Ellipsoid;
//!
//! let wgs84 = Ellipsoid::WGS84;
//! let on_equator = wgs84.to_ecef(0.0, 0.0, 100.0);
//! assert!((on_equator - DVec3::new(6_378_237.0, 0.0, 0.0)).length() < 1e-6);
//! let pole = wgs84.to_ecef(0.0, 90f64.to_radians(), 0.0);
//! assert!((pole.z - wgs84.polar_radius()).abs() < 1e-6);
//! ```

use glam::DVec3;

/// An ellipsoid of revolution (or a sphere): see the module documentation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ellipsoid {
    /// Semi-axes along x, y and z (x = y, the equatorial radius), metres.
    radii: DVec3,
}

impl Ellipsoid {
    /// WGS 84: a = 6378137 m, b = a(1 − f) with 1/f = 298.257223563.
    pub const WGS84: Self = Self {
        radii: DVec3::new(6_378_137.0, 6_378_137.0, 6_356_752.314_245_179),
    };

    /// The ellipsoid with equatorial radius `a` and polar radius `b`; `None` unless
    /// both are finite and positive.
    pub fn new(a: f64, b: f64) -> Option<Self> {
        let ok = |r: f64| r.is_finite() && r > 0.0;
        (ok(a) && ok(b)).then_some(Self {
            radii: DVec3::new(a, a, b),
        })
    }

    /// A sphere of radius `r` (the Moon, Mars…); `None` unless `r` is finite and
    /// positive.
    pub fn sphere(r: f64) -> Option<Self> {
        Self::new(r, r)
    }

    /// The semi-axes along x, y and z, metres.
    pub fn radii(&self) -> DVec3 {
        self.radii
    }

    /// The equatorial semi-axis `a`, metres.
    pub fn equatorial_radius(&self) -> f64 {
        self.radii.x
    }

    /// The polar semi-axis `b`, metres.
    pub fn polar_radius(&self) -> f64 {
        self.radii.z
    }

    /// The largest semi-axis (the equatorial radius for an oblate body).
    pub fn maximum_radius(&self) -> f64 {
        self.radii.x.max(self.radii.z)
    }

    /// The smallest semi-axis (the polar radius for an oblate body).
    pub fn minimum_radius(&self) -> f64 {
        self.radii.x.min(self.radii.z)
    }

    /// The first eccentricity squared, `e² = 1 − b²/a²` (negative for a prolate
    /// body, which the formulas here still serve).
    pub fn eccentricity_squared(&self) -> f64 {
        let (a, b) = (self.radii.x, self.radii.z);
        1.0 - (b * b) / (a * a)
    }

    /// The prime-vertical radius of curvature at geodetic latitude `lat` (radians):
    /// `N(φ) = a / √(1 − e² sin²φ)`.
    pub fn prime_vertical_radius(&self, lat: f64) -> f64 {
        let s = lat.sin();
        self.radii.x / (1.0 - self.eccentricity_squared() * s * s).sqrt()
    }

    /// The same ellipsoid with `dh` metres added to every semi-axis; `None` when that
    /// leaves no body (a radius not positive).
    pub fn grown(&self, dh: f64) -> Option<Self> {
        Self::new(self.radii.x + dh, self.radii.z + dh)
    }

    /// The outward unit normal at geodetic longitude and latitude (radians): by
    /// definition of geodetic latitude it depends on neither radius.
    pub fn geodetic_surface_normal(&self, lon: f64, lat: f64) -> DVec3 {
        let (sin_lon, cos_lon) = lon.sin_cos();
        let (sin_lat, cos_lat) = lat.sin_cos();
        DVec3::new(cos_lat * cos_lon, cos_lat * sin_lon, sin_lat)
    }

    /// The ECEF position (metres) of geodetic longitude, latitude (radians) and
    /// height above the ellipsoid (metres).
    pub fn to_ecef(&self, lon: f64, lat: f64, height: f64) -> DVec3 {
        let n = self.geodetic_surface_normal(lon, lat);
        let k = self.radii * self.radii * n;
        let gamma = n.dot(k).sqrt();
        k / gamma + n * height
    }

    /// `p` in the ellipsoid-scaled frame, where this ellipsoid is the unit sphere.
    pub fn to_scaled_space(&self, p: DVec3) -> DVec3 {
        p / self.radii
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const WGS84_B: f64 = 6_356_752.314_245_179;

    #[test]
    fn equator_and_pole() {
        let w = Ellipsoid::WGS84;
        assert!((w.to_ecef(0.0, 0.0, 100.0) - DVec3::new(6_378_237.0, 0.0, 0.0)).length() < 1e-6);
        let p = w.to_ecef(90f64.to_radians(), 0.0, 0.0);
        assert!((p - DVec3::new(0.0, 6_378_137.0, 0.0)).length() < 1e-6);
        let p = w.to_ecef(0.3, 90f64.to_radians(), -50.0);
        assert!((p - DVec3::new(0.0, 0.0, WGS84_B - 50.0)).length() < 1e-6);
    }

    /// The normal-projection form equals the textbook prime-vertical form
    /// `((N+h) cosφ cosλ, (N+h) cosφ sinλ, (N(1−e²)+h) sinφ)` everywhere.
    #[test]
    fn agrees_with_the_prime_vertical_form() {
        for e in [Ellipsoid::WGS84, Ellipsoid::sphere(1_737_400.0).unwrap()] {
            for (lon, lat, h) in [
                (45.0, 30.0, 8848.0),
                (-170.0, -60.0, -400.0),
                (8.0, 46.5, 0.0),
            ] {
                let (lon, lat) = (f64::to_radians(lon), f64::to_radians(lat));
                let n = e.prime_vertical_radius(lat);
                let (sl, cl) = lon.sin_cos();
                let (sp, cp) = lat.sin_cos();
                let want = DVec3::new(
                    (n + h) * cp * cl,
                    (n + h) * cp * sl,
                    (n * (1.0 - e.eccentricity_squared()) + h) * sp,
                );
                assert!(
                    (e.to_ecef(lon, lat, h) - want).length() < 1e-6,
                    "{lon} {lat} {h}"
                );
            }
        }
    }

    #[test]
    fn constructors_refuse_what_is_not_a_body() {
        assert!(Ellipsoid::new(0.0, 1.0).is_none());
        assert!(Ellipsoid::new(f64::NAN, 1.0).is_none());
        assert!(Ellipsoid::sphere(-1.0).is_none());
        assert!(Ellipsoid::sphere(10.0).unwrap().grown(-10.0).is_none());
        let g = Ellipsoid::WGS84.grown(-100.0).unwrap();
        assert_eq!(g.equatorial_radius(), 6_378_037.0);
        assert!((Ellipsoid::WGS84.eccentricity_squared() - 0.006_694_379_990_14).abs() < 1e-12);
    }
}
