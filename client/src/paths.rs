//! Fly-through paths: small JSON files of waypoints, speed and altitude above ground,
//! used by `tessera fly`, the load generator, tests and benchmarks.
//!
//! ```json
//! { "waypoints": [[0.1, 0.5], [0.9, 0.5]], "speed_mps": 300, "altitude_agl_m": 200,
//!   "pitch_deg": -15, "looped": false }
//! ```
//! Waypoints are fractions of the DEM's width and height (so one path fits any
//! dataset); the camera flies the polyline at `speed_mps`, looking along it.
//!
//! A path may also give, one value per waypoint, when the camera passes it
//! (`times_s`, seconds from the start, increasing; instead of `speed_mps`), its
//! altitude above the ground there (`altitudes_agl_m`, instead of
//! `altitude_agl_m`), its pitch (`pitches_deg`, instead of `pitch_deg`) and its
//! heading (`headings_deg`, degrees clockwise from north, instead of looking along
//! the path); between waypoints each is interpolated linearly (in time with
//! `times_s`, in distance otherwise). The `descent` built-in is such a path:
//!
//! ```json
//! { "waypoints": [[0.5, 0.48], [0.5, 0.49], [0.5, 0.5]], "times_s": [0, 3, 6],
//!   "altitudes_agl_m": [250000, 5000, 100], "pitches_deg": [-88, -60, -10],
//!   "headings_deg": [180, 180, 180] }
//! ```
//! [`path_cameras`] places every frame's camera over a local pyramid, for benchmarks.

mod cameras;
mod fly_path;

pub use cameras::{CamerasError, eye, path_cameras, pose_camera};
pub use fly_path::{BadPath, DESCENT_END_AGL_M, DESCENT_S, FlyPath, PathError, Pose};
