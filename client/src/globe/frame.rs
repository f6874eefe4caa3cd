//! The local frame at a point of the body, in the flat world's axes (`x` east,
//! `y` up, `z` south, [`crate::camera`]), so that a camera's yaw and pitch mean the
//! same on the globe as on the map.

use super::Globe;
use glam::{DMat3, DVec3};

/// The eye on the globe: its ECEF position and the rotation from ECEF directions
/// to its local (east, up, south) frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EyeFrame {
    pub ecef: DVec3,
    /// Rows: east, up, south (ECEF unit vectors).
    pub to_local: DMat3,
    /// Longitude, latitude (radians) and height of the eye.
    pub lon: f64,
    pub lat: f64,
    pub height: f64,
}

/// Rotation from ECEF to (east, up, south) at geodetic `lon`, `lat` (radians).
pub fn to_local(lon: f64, lat: f64) -> DMat3 {
    let (sl, cl) = lon.sin_cos();
    let (sp, cp) = lat.sin_cos();
    let east = DVec3::new(-sl, cl, 0.0);
    let up = DVec3::new(cp * cl, cp * sl, sp);
    let south = DVec3::new(sp * cl, sp * sl, -cp);
    DMat3::from_cols(east, up, south).transpose()
}

impl EyeFrame {
    /// The frame of a map pose: world `(x, y, z)` = grid `(x/sx, z/sy)`, height `y`.
    pub fn of_world(globe: &Globe, p: DVec3) -> Self {
        let (lon, lat) = globe
            .grid
            .lon_lat(p.x / globe.spacing.x, p.z / globe.spacing.y);
        Self {
            ecef: globe.ellipsoid.to_ecef(lon, lat, p.y),
            to_local: to_local(lon, lat),
            lon,
            lat,
            height: p.y,
        }
    }

    /// An ECEF point in the eye's local frame, eye at the origin.
    pub fn local(&self, ecef: DVec3) -> DVec3 {
        self.to_local * (ecef - self.ecef)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_frame_is_orthonormal_and_up_is_the_ellipsoid_normal() {
        let (lon, lat) = (0.7f64, -0.4f64);
        let r = to_local(lon, lat);
        assert!((r * r.transpose() - DMat3::IDENTITY).abs_diff_eq(DMat3::ZERO, 1e-12));
        // Right-handed like the flat world: east × up = south... x × y = z.
        assert!((r.row(0).cross(r.row(1)) - r.row(2)).length() < 1e-12);
        let e = tessera_shared::ellipsoid::Ellipsoid::new(6_378_137.0, 6_356_752.314_245).unwrap();
        let up = e.to_ecef(lon, lat, 1.0) - e.to_ecef(lon, lat, 0.0);
        assert!((up - r.row(1)).length() < 1e-6);
        // North is a small step up in latitude: −south.
        let north = e.to_ecef(lon, lat + 1e-7, 0.0) - e.to_ecef(lon, lat, 0.0);
        assert!((north.normalize() + r.row(2)).length() < 1e-6);
    }
}
