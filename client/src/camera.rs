//! A perspective camera over the terrain and its view frustum.
//!
//! World coordinates are metres, right-handed and y-up: `x` east, `y` up, `z` south,
//! so finest-grid sample `(X, Y)` with height `h` sits at `(X·sx, h, Y·sy)` for the
//! sample spacings `sx` east–west and `sy` north–south ([`crate::select::World`];
//! they differ for a geographic DEM, whose cells are not square on the ground).

use crate::globe::volume::GlobeView;
use glam::{DMat4, DVec3, DVec4};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub position: DVec3,
    /// Heading in radians: 0 looks north (−z), π/2 east (+x).
    pub yaw: f64,
    /// Radians above the horizon.
    pub pitch: f64,
    /// Vertical field of view in radians.
    pub fovy: f64,
    pub width: u32,
    pub height: u32,
    pub near: f64,
    pub far: f64,
}

impl Camera {
    /// Unit vector the camera looks along.
    pub fn forward(&self) -> DVec3 {
        DVec3::new(
            self.pitch.cos() * self.yaw.sin(),
            self.pitch.sin(),
            -self.pitch.cos() * self.yaw.cos(),
        )
    }

    pub fn view(&self) -> DMat4 {
        DMat4::look_to_rh(self.position, self.forward(), DVec3::Y)
    }

    pub fn projection(&self) -> DMat4 {
        let aspect = f64::from(self.width) / f64::from(self.height.max(1));
        DMat4::perspective_rh(self.fovy, aspect, self.near, self.far)
    }

    pub fn view_projection(&self) -> DMat4 {
        self.projection() * self.view()
    }

    /// `λ = viewport_height / (2·tan(fovy/2))`: pixels per unit of `error / distance`
    /// (Yang §4.2, Judnich's ρ).
    pub fn lambda(&self) -> f64 {
        f64::from(self.height) / (2.0 * (self.fovy / 2.0).tan())
    }

    pub fn frustum(&self) -> Frustum {
        Frustum::from_matrix(&self.view_projection())
    }

    /// Projection × view with the eye at the origin of its local frame: on the
    /// globe that frame is east–up–south at the eye (`globe::frame`), so yaw and
    /// pitch keep their meaning on the map.
    pub fn view_projection_at_eye(&self) -> DMat4 {
        self.projection() * DMat4::look_to_rh(DVec3::ZERO, self.forward(), DVec3::Y)
    }

    /// The frustum on the globe: planes in the eye's local frame, boxes tested as
    /// the bounding spheres of their curved shells, and behind-the-limb culling.
    pub fn frustum_on_globe(&self, view: GlobeView) -> Frustum {
        Frustum {
            globe: Some(view),
            ..Frustum::from_matrix(&self.view_projection_at_eye())
        }
    }
}

/// Six planes `n·p + d ≥ 0` inside (Gribb–Hartmann extraction, depth 0..1).
#[derive(Clone, Copy, Debug)]
pub struct Frustum {
    planes: [DVec4; 6],
    /// On the globe, boxes are flat-world boxes of curved shells ([`GlobeView`]).
    globe: Option<GlobeView>,
}

impl Frustum {
    pub fn from_matrix(m: &DMat4) -> Self {
        let r = |i: usize| m.row(i);
        let planes = [
            r(3) + r(0),
            r(3) - r(0),
            r(3) + r(1),
            r(3) - r(1),
            r(2),
            r(3) - r(2),
        ]
        .map(|p| p / p.truncate().length());
        Self {
            planes,
            globe: None,
        }
    }

    /// Whether an axis-aligned box may be visible (false only when it is wholly
    /// outside one plane).
    pub fn intersects_box(&self, min: DVec3, max: DVec3) -> bool {
        if let Some(view) = &self.globe {
            let (c, r, hidden) = view.local_sphere(min, max);
            return !hidden && self.planes.iter().all(|p| p.truncate().dot(c) + p.w >= -r);
        }
        self.planes.iter().all(|p| {
            let n = p.truncate();
            let v = DVec3::new(
                if n.x >= 0.0 { max.x } else { min.x },
                if n.y >= 0.0 { max.y } else { min.y },
                if n.z >= 0.0 { max.z } else { min.z },
            );
            n.dot(v) + p.w >= 0.0
        })
    }
}

/// Distance from a point to an axis-aligned box (0 inside).
pub fn distance_to_box(p: DVec3, min: DVec3, max: DVec3) -> f64 {
    (min - p).max(p - max).max(DVec3::ZERO).length()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera {
            position: DVec3::new(0.0, 100.0, 0.0),
            yaw: 0.0,
            pitch: 0.0,
            fovy: 60f64.to_radians(),
            width: 1920,
            height: 1080,
            near: 1.0,
            far: 10_000.0,
        }
    }

    #[test]
    fn frustum_keeps_what_is_ahead() {
        let f = cam().frustum();
        // Ahead (north, −z) and at eye height: visible.
        assert!(f.intersects_box(
            DVec3::new(-10.0, 90.0, -510.0),
            DVec3::new(10.0, 110.0, -490.0)
        ));
        // Behind the camera, far to the side, or beyond the far plane: culled.
        assert!(!f.intersects_box(
            DVec3::new(-10.0, 90.0, 490.0),
            DVec3::new(10.0, 110.0, 510.0)
        ));
        assert!(!f.intersects_box(
            DVec3::new(5000.0, 90.0, -600.0),
            DVec3::new(5100.0, 110.0, -500.0)
        ));
        assert!(!f.intersects_box(
            DVec3::new(-10.0, 90.0, -20_000.0),
            DVec3::new(10.0, 110.0, -19_000.0)
        ));
    }

    #[test]
    fn lambda_and_distance() {
        let c = cam();
        assert!((c.lambda() - 1080.0 / (2.0 * (30f64.to_radians()).tan())).abs() < 1e-9);
        let d = distance_to_box(
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(3.0, -1.0, 4.0),
            DVec3::new(5.0, 1.0, 6.0),
        );
        assert!((d - 5.0).abs() < 1e-12);
        assert_eq!(
            distance_to_box(DVec3::ONE, DVec3::ZERO, DVec3::splat(2.0)),
            0.0
        );
    }
}
