//! A fly-through path (the format is in the `paths` module documentation): its
//! waypoints and pace, the built-in paths, loading and checking a path file, and
//! the pose at a time.

use glam::DVec2;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A path that could not be loaded: not a built-in one nor a readable file, not
/// the JSON of a path, or a path that does not hold together ([`BadPath`]).
#[derive(Debug, thiserror::Error)]
pub enum PathError {
    #[error("{spec}: not a built-in path (canyon, pass, orbit, descent) nor a readable file")]
    NotAPath {
        spec: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{spec}: bad path JSON")]
    Json {
        spec: String,
        #[source]
        source: serde_json::Error,
    },
    #[error("{spec}")]
    Invalid {
        spec: String,
        #[source]
        source: BadPath,
    },
}

/// What is wrong with a path's fields.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum BadPath {
    #[error("a path needs at least two waypoints")]
    TooFewWaypoints,
    #[error("waypoints must be finite numbers")]
    NonFiniteWaypoints,
    #[error("{name} has {got} values for {n} waypoints")]
    Count {
        name: &'static str,
        got: usize,
        n: usize,
    },
    #[error("{name} must be finite numbers")]
    NonFinite { name: &'static str },
    #[error("give speed_mps or times_s, not both")]
    SpeedAndTimes,
    #[error("a path needs speed_mps or times_s")]
    NoPace,
    #[error("speed_mps must be a positive number")]
    Speed,
    #[error("times_s must start at 0 and increase")]
    Times,
    #[error("give altitude_agl_m or altitudes_agl_m, not both")]
    AltitudeTwice,
    #[error("a path needs altitude_agl_m or altitudes_agl_m")]
    NoAltitude,
    #[error("altitude_agl_m must be a finite number")]
    Altitude,
    #[error("pitch_deg must be a finite number")]
    Pitch,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlyPath {
    pub waypoints: Vec<[f64; 2]>,
    /// Ground speed along the polyline; absent when `times_s` times the waypoints.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub speed_mps: Option<f64>,
    /// Height above the ground under the eye; absent when `altitudes_agl_m` gives
    /// one per waypoint.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub altitude_agl_m: Option<f64>,
    #[serde(default = "default_pitch")]
    pub pitch_deg: f64,
    #[serde(default)]
    pub looped: bool,
    /// Seconds from the start at which the camera passes each waypoint.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub times_s: Option<Vec<f64>>,
    /// Altitude above the ground at each waypoint.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub altitudes_agl_m: Option<Vec<f64>>,
    /// Pitch at each waypoint (degrees above the horizon).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pitches_deg: Option<Vec<f64>>,
    /// Heading at each waypoint (degrees clockwise from north), instead of looking
    /// along the path; interpolated the short way round.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub headings_deg: Option<Vec<f64>>,
}

fn default_pitch() -> f64 {
    -15.0
}

/// The `descent` built-in's length in seconds.
pub const DESCENT_S: f64 = 6.0;
/// Where the `descent` built-in ends: this far above the ground under the eye.
pub const DESCENT_END_AGL_M: f64 = 100.0;
/// The `descent` built-in's pitch at its start (nearly straight down: a map view)
/// and at its end (looking ahead).
const DESCENT_PITCH_DEG: (f64, f64) = (-88.0, -10.0);
/// The `descent` built-in's start altitude, in DEM extents: high enough that the
/// whole DEM (and relief up to a tenth of its extent) is in a 60° view of aspect
/// 4:3 or wider (see the tests).
const DESCENT_START_EXTENTS: f64 = 1.1;

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
    /// A path flown at a constant speed, altitude and pitch.
    pub fn steady(
        waypoints: Vec<[f64; 2]>,
        speed_mps: f64,
        altitude_agl_m: f64,
        pitch_deg: f64,
        looped: bool,
    ) -> Self {
        Self {
            waypoints,
            speed_mps: Some(speed_mps),
            altitude_agl_m: Some(altitude_agl_m),
            pitch_deg,
            looped,
            times_s: None,
            altitudes_agl_m: None,
            pitches_deg: None,
            headings_deg: None,
        }
    }

    /// A built-in path sized to a DEM `extent_m` metres across.
    /// - `canyon`: low and fast, weaving across rough terrain;
    /// - `pass`: high-altitude fast traverse of the whole dataset;
    /// - `orbit`: a circle around the centre, looking inwards and down;
    /// - `descent`: from a map view of the whole dataset, high over its centre and
    ///   looking nearly straight down, continuously down to 100 m above the ground
    ///   looking ahead, in [`DESCENT_S`] seconds ([`FlyPath::descent`]).
    pub fn builtin(name: &str, extent_m: f64) -> Option<Self> {
        match name {
            "canyon" => Some(Self::steady(
                vec![
                    [0.15, 0.2],
                    [0.35, 0.45],
                    [0.5, 0.35],
                    [0.65, 0.6],
                    [0.85, 0.8],
                ],
                extent_m / 40.0,
                150.0,
                -12.0,
                false,
            )),
            "pass" => Some(Self::steady(
                vec![[0.02, 0.02], [0.98, 0.98]],
                extent_m / 12.0,
                extent_m / 40.0,
                -25.0,
                false,
            )),
            "orbit" => Some(Self::steady(
                (0..=32)
                    .map(|i| {
                        let a = f64::from(i) / 32.0 * std::f64::consts::TAU;
                        [0.5 + 0.3 * a.cos(), 0.5 + 0.3 * a.sin()]
                    })
                    .collect(),
                extent_m / 25.0,
                extent_m / 25.0,
                -30.0,
                true,
            )),
            "descent" => Some(Self::descent(extent_m)),
            _ => None,
        }
    }

    /// The `descent` built-in over a DEM `extent_m` metres across, heading south
    /// (away from the renderer's north-western sun, so the slopes ahead are lit).
    ///
    /// The camera keeps its gaze on the DEM's centre while it comes down: with
    /// `s` easing from 0 to 1 (smoothstep in time, so it starts and stops gently)
    /// the altitude falls geometrically, `A₀·(100 m / A₀)^s` (the view shrinks by
    /// the same factor every frame in the middle of the flight, as a zoom does),
    /// the pitch rises from −88° to −10° (faster near the end, where the horizon
    /// comes into view), and the eye stands back from the centre by
    /// `altitude / tan(−pitch)`, so that over flat ground the middle of the view
    /// stays on the centre. Sampled every 0.1 s; linear in between.
    pub fn descent(extent_m: f64) -> Self {
        let start = DESCENT_START_EXTENTS * extent_m.max(DESCENT_END_AGL_M);
        let keys = (DESCENT_S * 10.0).round() as usize;
        let (mut waypoints, mut times, mut altitudes, mut pitches) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for k in 0..=keys {
            let u = k as f64 / keys as f64;
            let s = u * u * (3.0 - 2.0 * u);
            let altitude = start * (DESCENT_END_AGL_M / start).powf(s);
            let (p0, p1) = DESCENT_PITCH_DEG;
            let pitch = p0 + (p1 - p0) * s.powf(1.2);
            let back = altitude / (-pitch).to_radians().tan();
            // South is +y on the map: standing back means north of the centre.
            waypoints.push([0.5, 0.5 - back / extent_m.max(1.0)]);
            times.push(u * DESCENT_S);
            altitudes.push(altitude);
            pitches.push(pitch);
        }
        Self {
            waypoints,
            speed_mps: None,
            altitude_agl_m: None,
            pitch_deg: DESCENT_PITCH_DEG.0,
            looped: false,
            times_s: Some(times),
            altitudes_agl_m: Some(altitudes),
            pitches_deg: Some(pitches),
            headings_deg: Some(vec![180.0; keys + 1]),
        }
    }

    /// A built-in name or a JSON file.
    pub fn load(spec: &str, extent_m: f64) -> Result<Self, PathError> {
        if let Some(p) = Self::builtin(spec, extent_m) {
            return Ok(p);
        }
        let text =
            std::fs::read_to_string(Path::new(spec)).map_err(|source| PathError::NotAPath {
                spec: spec.into(),
                source,
            })?;
        let p: Self = serde_json::from_str(&text).map_err(|source| PathError::Json {
            spec: spec.into(),
            source,
        })?;
        p.check().map_err(|source| PathError::Invalid {
            spec: spec.into(),
            source,
        })?;
        Ok(p)
    }

    pub(super) fn check(&self) -> Result<(), BadPath> {
        let n = self.waypoints.len();
        if n < 2 {
            return Err(BadPath::TooFewWaypoints);
        }
        if self.waypoints.iter().flatten().any(|v| !v.is_finite()) {
            return Err(BadPath::NonFiniteWaypoints);
        }
        let per_waypoint = [
            ("times_s", &self.times_s),
            ("altitudes_agl_m", &self.altitudes_agl_m),
            ("pitches_deg", &self.pitches_deg),
            ("headings_deg", &self.headings_deg),
        ];
        for (name, values) in per_waypoint {
            if let Some(v) = values {
                if v.len() != n {
                    return Err(BadPath::Count {
                        name,
                        got: v.len(),
                        n,
                    });
                }
                if v.iter().any(|x| !x.is_finite()) {
                    return Err(BadPath::NonFinite { name });
                }
            }
        }
        match (&self.times_s, self.speed_mps) {
            (Some(_), Some(_)) => return Err(BadPath::SpeedAndTimes),
            (None, None) => return Err(BadPath::NoPace),
            (None, Some(v)) if !(v.is_finite() && v > 0.0) => {
                return Err(BadPath::Speed);
            }
            (Some(t), None) if t[0] != 0.0 || t.windows(2).any(|w| w[1] <= w[0]) => {
                return Err(BadPath::Times);
            }
            _ => {}
        }
        match (&self.altitudes_agl_m, self.altitude_agl_m) {
            (Some(_), Some(_)) => return Err(BadPath::AltitudeTwice),
            (None, None) => return Err(BadPath::NoAltitude),
            (None, Some(a)) if !a.is_finite() => return Err(BadPath::Altitude),
            _ => {}
        }
        if !self.pitch_deg.is_finite() {
            return Err(BadPath::Pitch);
        }
        Ok(())
    }

    /// The waypoints in metres on a DEM `size_m` metres wide and high.
    fn points(&self, size_m: DVec2) -> Vec<DVec2> {
        self.waypoints
            .iter()
            .map(|w| DVec2::new(w[0], w[1]) * size_m)
            .collect()
    }

    /// Length in metres of the polyline (one lap of a looped path) on a DEM
    /// `size_m` metres wide and high.
    pub fn length_m(&self, size_m: DVec2) -> f64 {
        self.points(size_m)
            .windows(2)
            .map(|w| w[0].distance(w[1]))
            .sum()
    }

    /// Seconds from the start to the end of the path (one lap of a looped path) on
    /// a DEM `size_m` metres wide and high.
    pub fn duration_s(&self, size_m: DVec2) -> f64 {
        match (&self.times_s, self.speed_mps) {
            (Some(t), _) => t.last().copied().unwrap_or(0.0),
            (None, Some(v)) => self.length_m(size_m) / v,
            (None, None) => 0.0,
        }
    }

    /// The segment the camera is on after `t` seconds and how far along it
    /// (0 at its first waypoint, 1 at its second).
    fn segment_at(&self, t: f64, pts: &[DVec2]) -> (usize, f64) {
        let last = pts.len() - 2;
        if let Some(times) = &self.times_s {
            let end = times[times.len() - 1];
            let t = if self.looped {
                t.rem_euclid(end.max(1e-9))
            } else {
                t.clamp(0.0, end)
            };
            let seg = times.windows(2).position(|w| t <= w[1]).unwrap_or(last);
            let f = (t - times[seg]) / (times[seg + 1] - times[seg]);
            return (seg, f.clamp(0.0, 1.0));
        }
        let lens: Vec<f64> = pts.windows(2).map(|w| w[0].distance(w[1])).collect();
        let total: f64 = lens.iter().sum::<f64>().max(1e-9);
        let mut d = t * self.speed_mps.unwrap_or(0.0);
        d = if self.looped {
            d.rem_euclid(total)
        } else {
            d.clamp(0.0, total)
        };
        let mut seg = 0;
        while seg < last && d > lens[seg] {
            d -= lens[seg];
            seg += 1;
        }
        (seg, (d / lens[seg].max(1e-9)).clamp(0.0, 1.0))
    }

    /// The pose after `t` seconds on a DEM `size_m` metres wide and high.
    pub fn pose(&self, t: f64, size_m: DVec2) -> Pose {
        let pts = self.points(size_m);
        let (seg, f) = self.segment_at(t, &pts);
        let (a, b) = (pts[seg], pts[seg + 1]);
        let dir = (b - a).normalize_or(DVec2::X);
        let along = |v: &Option<Vec<f64>>, constant: f64| {
            v.as_ref()
                .map_or(constant, |v| v[seg] + (v[seg + 1] - v[seg]) * f)
        };
        // Yaw 0 looks north (−z, i.e. −y on the map); east is +x.
        let yaw = match &self.headings_deg {
            Some(h) => {
                let turn = (h[seg + 1] - h[seg] + 180.0).rem_euclid(360.0) - 180.0;
                ((h[seg] + turn * f + 180.0).rem_euclid(360.0) - 180.0).to_radians()
            }
            None => dir.x.atan2(-dir.y),
        };
        Pose {
            ground: a + (b - a) * f,
            altitude_agl: along(&self.altitudes_agl_m, self.altitude_agl_m.unwrap_or(0.0)),
            yaw,
            pitch: along(&self.pitches_deg, self.pitch_deg).to_radians(),
        }
    }
}

/// A nominal extent for [`FlyPath::start_focus`]: built-in paths scale with the
/// dataset, so any extent above the `descent`'s 100 m floor places them alike.
const NOMINAL_EXTENT_M: f64 = 1.0e6;

impl FlyPath {
    /// Where the path `spec` (as [`FlyPath::load`] reads it) is at `t` seconds, as
    /// fractions of the dataset ([`Focus`](tessera_shared::focus::Focus)), before
    /// the dataset's size is known: for a bootstrap's focus. Exact for built-in
    /// paths and paths timed per waypoint; a file path flown at a speed in metres
    /// per second is placed at its first waypoint (its pace needs the size). `None`
    /// when the spec does not load or the point is off the dataset.
    pub fn start_focus(spec: &str, t: f64) -> Option<tessera_shared::focus::Focus> {
        let path = Self::load(spec, NOMINAL_EXTENT_M).ok()?;
        let paced = Self::builtin(spec, NOMINAL_EXTENT_M).is_some() || path.times_s.is_some();
        let t = if paced { t } else { 0.0 };
        let g = path.pose(t, DVec2::splat(NOMINAL_EXTENT_M)).ground / NOMINAL_EXTENT_M;
        tessera_shared::focus::Focus::new(g.x, g.y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_move_at_their_speed_and_look_ahead() {
        let p = FlyPath::steady(vec![[0.0, 0.0], [1.0, 0.0]], 10.0, 50.0, -10.0, false);
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
        for name in ["canyon", "pass", "orbit", "descent"] {
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

    #[test]
    fn per_waypoint_times_altitudes_pitches_and_headings_are_interpolated() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("timed.json");
        std::fs::write(
            &file,
            r#"{"waypoints": [[0, 0], [1, 0], [1, 1]], "times_s": [0, 10, 30],
                "altitudes_agl_m": [1000, 200, 100], "pitches_deg": [-80, -20, -10],
                "headings_deg": [350, 10, 90]}"#,
        )
        .unwrap();
        let p = FlyPath::load(file.to_str().unwrap(), 1.0).unwrap();
        let size = DVec2::splat(100.0);
        assert_eq!(p.duration_s(size), 30.0);
        let a = p.pose(5.0, size);
        assert!((a.ground - DVec2::new(50.0, 0.0)).length() < 1e-9);
        assert!((a.altitude_agl - 600.0).abs() < 1e-9);
        assert!((a.pitch.to_degrees() + 50.0).abs() < 1e-9);
        // 350° to 10° turns through north, not back through south.
        assert!(a.yaw.to_degrees().abs() < 1e-9, "{}", a.yaw.to_degrees());
        let b = p.pose(20.0, size);
        assert!((b.ground - DVec2::new(100.0, 50.0)).length() < 1e-9);
        assert!((b.altitude_agl - 150.0).abs() < 1e-9);
        assert!((b.yaw.to_degrees() - 50.0).abs() < 1e-9);
        assert_eq!(p.pose(99.0, size), p.pose(30.0, size), "stops at the end");
        // Bad per-waypoint fields are rejected with the field named.
        for (json, want) in [
            (
                r#"{"waypoints": [[0, 0], [1, 0]], "times_s": [0], "altitude_agl_m": 5}"#,
                "times_s has 1 values for 2 waypoints",
            ),
            (
                r#"{"waypoints": [[0, 0], [1, 0]], "times_s": [0, 0], "altitude_agl_m": 5}"#,
                "times_s must start at 0 and increase",
            ),
            (
                r#"{"waypoints": [[0, 0], [1, 0]], "times_s": [0, 1], "speed_mps": 3, "altitude_agl_m": 5}"#,
                "not both",
            ),
            (
                r#"{"waypoints": [[0, 0], [1, 0]], "speed_mps": 3}"#,
                "needs altitude_agl_m or altitudes_agl_m",
            ),
            (
                r#"{"waypoints": [[0, 0], [1, 0]], "speed_mps": 3, "altitudes_agl_m": [1, 2], "pitches_deg": [1, 2, 3]}"#,
                "pitches_deg has 3 values",
            ),
        ] {
            std::fs::write(&file, json).unwrap();
            let e = FlyPath::load(file.to_str().unwrap(), 1.0).unwrap_err();
            let e = crate::errors::Chain(&e).to_string();
            assert!(e.contains(want), "{json}: {e}");
        }
    }
}
