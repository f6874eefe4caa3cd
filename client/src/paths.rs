//! Fly-through paths: small JSON files of waypoints, speed and altitude above ground,
//! used by `tessera fly`, the load generator, tests and benchmarks.
//!
//! ```json
//! { "waypoints": [[0.1, 0.5], [0.9, 0.5]], "speed_mps": 300, "altitude_agl_m": 200,
//!   "pitch_deg": -15, "looped": false }
//! ```
//! Waypoints are fractions of the DEM's width and height (so one path fits any
//! dataset); the camera flies the polyline at `speed_mps`, looking along it.

use anyhow::{Context, bail};
use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlyPath {
    pub waypoints: Vec<[f64; 2]>,
    pub speed_mps: f64,
    pub altitude_agl_m: f64,
    #[serde(default = "default_pitch")]
    pub pitch_deg: f64,
    #[serde(default)]
    pub looped: bool,
}

fn default_pitch() -> f64 {
    -15.0
}

/// Where the camera is and where it looks, before the ground height is added.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Metres east and south of the DEM's first sample.
    pub ground: DVec2,
    pub altitude_agl: f64,
    pub yaw: f64,
    pub pitch: f64,
}

impl FlyPath {
    /// A built-in path sized to a DEM `extent_m` metres across.
    /// - `canyon`: low and fast, weaving across rough terrain;
    /// - `pass`: high-altitude fast traverse of the whole dataset;
    /// - `orbit`: a circle around the centre, looking inwards and down.
    pub fn builtin(name: &str, extent_m: f64) -> Option<Self> {
        match name {
            "canyon" => Some(Self {
                waypoints: vec![
                    [0.15, 0.2],
                    [0.35, 0.45],
                    [0.5, 0.35],
                    [0.65, 0.6],
                    [0.85, 0.8],
                ],
                speed_mps: extent_m / 40.0,
                altitude_agl_m: 150.0,
                pitch_deg: -12.0,
                looped: false,
            }),
            "pass" => Some(Self {
                waypoints: vec![[0.02, 0.02], [0.98, 0.98]],
                speed_mps: extent_m / 12.0,
                altitude_agl_m: extent_m / 40.0,
                pitch_deg: -25.0,
                looped: false,
            }),
            "orbit" => Some(Self {
                waypoints: (0..=32)
                    .map(|i| {
                        let a = f64::from(i) / 32.0 * std::f64::consts::TAU;
                        [0.5 + 0.3 * a.cos(), 0.5 + 0.3 * a.sin()]
                    })
                    .collect(),
                speed_mps: extent_m / 25.0,
                altitude_agl_m: extent_m / 25.0,
                pitch_deg: -30.0,
                looped: true,
            }),
            _ => None,
        }
    }

    /// A built-in name or a JSON file.
    pub fn load(spec: &str, extent_m: f64) -> anyhow::Result<Self> {
        if let Some(p) = Self::builtin(spec, extent_m) {
            return Ok(p);
        }
        let text = std::fs::read_to_string(Path::new(spec)).with_context(|| {
            format!("{spec}: not a built-in path (canyon, pass, orbit) nor a readable file")
        })?;
        let p: Self =
            serde_json::from_str(&text).with_context(|| format!("{spec}: bad path JSON"))?;
        p.check().with_context(|| spec.to_string())?;
        Ok(p)
    }

    fn check(&self) -> anyhow::Result<()> {
        if self.waypoints.len() < 2 {
            bail!("a path needs at least two waypoints");
        }
        if self.waypoints.iter().flatten().any(|v| !v.is_finite()) {
            bail!("waypoints must be finite numbers");
        }
        let speed_ok = self.speed_mps.is_finite() && self.speed_mps > 0.0;
        if !speed_ok || !self.altitude_agl_m.is_finite() {
            bail!("speed_mps must be positive and altitude_agl_m finite");
        }
        Ok(())
    }

    /// The pose after `t` seconds on a DEM `size_m` metres wide and high.
    pub fn pose(&self, t: f64, size_m: DVec2) -> Pose {
        let pts: Vec<DVec2> = self
            .waypoints
            .iter()
            .map(|w| DVec2::new(w[0], w[1]) * size_m)
            .collect();
        let lens: Vec<f64> = pts.windows(2).map(|w| w[0].distance(w[1])).collect();
        let total: f64 = lens.iter().sum::<f64>().max(1e-9);
        let mut d = t * self.speed_mps;
        d = if self.looped {
            d.rem_euclid(total)
        } else {
            d.clamp(0.0, total)
        };
        let mut seg = 0;
        while seg + 1 < lens.len() && d > lens[seg] {
            d -= lens[seg];
            seg += 1;
        }
        let (a, b) = (pts[seg], pts[seg + 1]);
        let dir = (b - a).normalize_or(DVec2::X);
        let f = (d / lens[seg].max(1e-9)).clamp(0.0, 1.0);
        Pose {
            ground: a + (b - a) * f,
            altitude_agl: self.altitude_agl_m,
            // Yaw 0 looks north (−z, i.e. −y on the map); east is +x.
            yaw: dir.x.atan2(-dir.y),
            pitch: self.pitch_deg.to_radians(),
        }
    }
}

/// World position of a pose over ground at height `ground_m`.
pub fn eye(pose: &Pose, ground_m: f64) -> DVec3 {
    DVec3::new(pose.ground.x, ground_m + pose.altitude_agl, pose.ground.y)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_move_at_their_speed_and_look_ahead() {
        let p = FlyPath {
            waypoints: vec![[0.0, 0.0], [1.0, 0.0]],
            speed_mps: 10.0,
            altitude_agl_m: 50.0,
            pitch_deg: -10.0,
            looped: false,
        };
        let size = DVec2::splat(1000.0);
        let a = p.pose(3.0, size);
        assert!((a.ground.x - 30.0).abs() < 1e-9 && a.ground.y.abs() < 1e-9);
        assert!(
            (a.yaw - std::f64::consts::FRAC_PI_2).abs() < 1e-9,
            "flying east looks east"
        );
        assert!(
            (p.pose(1000.0, size).ground.x - 1000.0).abs() < 1e-9,
            "stops at the end"
        );
        for name in ["canyon", "pass", "orbit"] {
            let b = FlyPath::builtin(name, 8000.0).unwrap();
            b.check().unwrap();
            let q = b.pose(5.0, DVec2::splat(8000.0));
            assert!(
                q.ground.x >= 0.0
                    && q.ground.x <= 8000.0
                    && q.ground.y >= 0.0
                    && q.ground.y <= 8000.0
            );
        }
        assert!(FlyPath::load("no-such-path.json", 1.0).is_err());
    }
}
