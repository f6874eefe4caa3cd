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

use crate::camera::Camera;
use crate::select::World;
use crate::stream::pool::TilePool;
use anyhow::{Context, bail};
use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};
use std::path::Path;
use tessera_shared::{ByteSource, Pyramid};

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
    pub fn load(spec: &str, extent_m: f64) -> anyhow::Result<Self> {
        if let Some(p) = Self::builtin(spec, extent_m) {
            return Ok(p);
        }
        let text = std::fs::read_to_string(Path::new(spec)).with_context(|| {
            format!(
                "{spec}: not a built-in path (canyon, pass, orbit, descent) nor a readable file"
            )
        })?;
        let p: Self =
            serde_json::from_str(&text).with_context(|| format!("{spec}: bad path JSON"))?;
        p.check().with_context(|| spec.to_string())?;
        Ok(p)
    }

    fn check(&self) -> anyhow::Result<()> {
        let n = self.waypoints.len();
        if n < 2 {
            bail!("a path needs at least two waypoints");
        }
        if self.waypoints.iter().flatten().any(|v| !v.is_finite()) {
            bail!("waypoints must be finite numbers");
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
                    bail!("{name} has {} values for {n} waypoints", v.len());
                }
                if v.iter().any(|x| !x.is_finite()) {
                    bail!("{name} must be finite numbers");
                }
            }
        }
        match (&self.times_s, self.speed_mps) {
            (Some(_), Some(_)) => bail!("give speed_mps or times_s, not both"),
            (None, None) => bail!("a path needs speed_mps or times_s"),
            (None, Some(v)) if !(v.is_finite() && v > 0.0) => {
                bail!("speed_mps must be a positive number")
            }
            (Some(t), None) if t[0] != 0.0 || t.windows(2).any(|w| w[1] <= w[0]) => {
                bail!("times_s must start at 0 and increase")
            }
            _ => {}
        }
        match (&self.altitudes_agl_m, self.altitude_agl_m) {
            (Some(_), Some(_)) => bail!("give altitude_agl_m or altitudes_agl_m, not both"),
            (None, None) => bail!("a path needs altitude_agl_m or altitudes_agl_m"),
            (None, Some(a)) if !a.is_finite() => bail!("altitude_agl_m must be a finite number"),
            _ => {}
        }
        if !self.pitch_deg.is_finite() {
            bail!("pitch_deg must be a finite number");
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

/// World position of a pose over ground at height `ground_m`.
pub fn eye(pose: &Pose, ground_m: f64) -> DVec3 {
    DVec3::new(pose.ground.x, ground_m + pose.altitude_agl, pose.ground.y)
}

/// The camera of a pose over ground at height `ground_m`, on a DEM `extent_m` metres
/// across: looking along the path with a 60° vertical field of view times
/// `fov_scale` (the prefetch view is wider), `width × height` pixels, and a far plane
/// beyond the whole DEM. The near plane is 1 m, or a thousandth of the altitude
/// when that is more: from hundreds of kilometres up a 1 m near plane leaves the
/// 32-bit depth buffer kilometres of resolution, while terrain within a thousandth
/// of the altitude of the eye is all but impossible.
pub fn pose_camera(
    pose: &Pose,
    ground_m: f64,
    extent_m: f64,
    fov_scale: f64,
    (width, height): (u32, u32),
) -> Camera {
    Camera {
        position: eye(pose, ground_m),
        yaw: pose.yaw,
        pitch: pose.pitch,
        fovy: 60f64.to_radians() * fov_scale,
        width,
        height,
        near: (pose.altitude_agl / 1000.0).max(1.0),
        far: 4.0 * extent_m + 1e5,
    }
}

/// The camera of every frame of a path flown at `fps` over a local pyramid, placed
/// as `tessera fly` places it: the path (`canyon`, `pass`, `orbit` or a path JSON
/// file, as [`FlyPath::load`] reads it) sized to the DEM, the eye at the path's
/// altitude above the ground under it, the camera looking along the path (60°
/// vertical field of view, `width × height` pixels). `tessera fly` reads the ground
/// from the finest tile it has streamed; here it is always read from the finest
/// tile under the eye ([`Pyramid::read_tile`] into a [`TilePool`], then
/// [`TilePool::ground_height`]).
///
/// One camera for each frame from the start of the path to its end (one lap of a
/// looped path): `⌈length / speed · fps⌉ + 1` cameras.
pub fn path_cameras<S: ByteSource>(
    pyramid: &Pyramid<S>,
    world: &World,
    path: &str,
    fps: f64,
    width: u32,
    height: u32,
) -> anyhow::Result<Vec<Camera>> {
    anyhow::ensure!(
        fps.is_finite() && fps > 0.0,
        "frames per second must be positive"
    );
    let g = &world.geometry;
    anyhow::ensure!(
        g == pyramid.geometry(),
        "the world's geometry is not the pyramid's"
    );
    let size = world.size_m();
    let fly_path = FlyPath::load(path, size.max_element())?;
    let frames = (fly_path.duration_s(size) * fps).ceil() + 1.0;
    anyhow::ensure!(
        frames <= 1e7,
        "{path}: {frames} frames at {fps} fps is too many"
    );
    let max_height = pyramid.metadata().max_height;
    let mut ground = TilePool::new(64);
    let mut cameras = Vec::with_capacity(frames as usize);
    for f in 0..frames as u32 {
        let pose = fly_path.pose(f64::from(f) / fps, size);
        // The finest tile under the eye, or its nearest ancestor with a record where
        // it is absent (wholly no-data: its filled heights are in the ancestor).
        let mut under = Some(world.finest_tile_at(pose.ground.x, pose.ground.y));
        while let Some(t) = under {
            if ground.contains(t) {
                break;
            }
            if let Some(rec) = pyramid.read_tile(t)? {
                ground.insert(t, rec.errors, rec.heights, rec.mask);
                break;
            }
            under = t.parent();
        }
        let h = ground
            .ground_height(world, pose.ground.x, pose.ground.y)
            .unwrap_or(max_height);
        cameras.push(pose_camera(
            &pose,
            h,
            size.max_element(),
            1.0,
            (width, height),
        ));
    }
    Ok(cameras)
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

    /// Quantized height of finest sample `(x, y)` of the test pyramid; coarser
    /// levels store it raised by 5000 so a camera standing on them shows.
    fn test_height(x: u64, y: u64, level_above_finest: u8) -> u16 {
        ((x * 37 + y * 101) % 4000) as u16 + 5000 * u16::from(level_above_finest.min(1))
    }

    /// A small pyramid in memory: `width × height` samples of [`test_height`] in
    /// 64-cell tiles, empty error tables.
    fn test_pyramid(width: u32, height: u32) -> Pyramid<Vec<u8>> {
        use tessera_shared::format::{
            self, FileHeader, HEADER_LEN, INDEX_ENTRY_LEN, IndexEntry, LEVEL_ENTRY_LEN, LevelEntry,
            VERSION,
        };
        use tessera_shared::{ErrorTable, Metadata, TileGeometry, codec};
        let g = TileGeometry::new(width, height, 64).unwrap();
        let side = g.tile_samples();
        // Records level by level (relative offsets for now) and each level's index.
        let mut records = Vec::new();
        let mut levels = Vec::new();
        for level in g.levels() {
            let start = records.len() as u64;
            let mut index = vec![IndexEntry::default(); level.tile_slots() as usize];
            for tile in g.present_tiles(level) {
                let (x0, y0) = g.origin(tile);
                let s = g.spacing(level);
                let heights: Vec<u16> = (0..side as u64)
                    .flat_map(|v| {
                        (0..side as u64).map(move |u| {
                            test_height(x0 + u * s, y0 + v * s, g.finest().get() - level.get())
                        })
                    })
                    .collect();
                let rec = codec::encode_record(
                    &ErrorTable::empty(g.tile_log2()),
                    &tessera_shared::CellMask::all_valid(g.tile_size()),
                    &heights,
                );
                index[tile.morton().get() as usize] = IndexEntry {
                    offset: records.len() as u64,
                    length: rec.len() as u32,
                    checksum: format::checksum(&rec),
                    ..IndexEntry::default()
                };
                records.extend_from_slice(&rec);
            }
            levels.push((start, records.len() as u64 - start, index));
        }
        let meta = Metadata {
            content_hash: String::new(),
            ..tessera_shared::fixtures::metadata(width, height, g.tile_size())
        };
        let meta_bytes = format::encode_metadata(&meta);
        let table_len = levels.len() * LEVEL_ENTRY_LEN;
        let index_len: usize = levels.iter().map(|l| l.2.len() * INDEX_ENTRY_LEN).sum();
        let records_offset = (HEADER_LEN + table_len + index_len + meta_bytes.len()) as u64;
        let mut region = Vec::new();
        let mut index_at = (HEADER_LEN + table_len) as u64;
        for (level, (start, len, index)) in g.levels().zip(&levels) {
            let entry = LevelEntry {
                level: level.get(),
                tiles_per_side: level.tiles_per_side(),
                index_offset: index_at,
                index_entries: level.tile_slots(),
                records_offset: records_offset + start,
                records_len: *len,
            };
            region.extend_from_slice(&entry.to_bytes());
            index_at += (index.len() * INDEX_ENTRY_LEN) as u64;
        }
        for (_, _, index) in &levels {
            for e in index {
                let mut e = *e;
                if e.is_present() {
                    e.offset += records_offset;
                }
                region.extend_from_slice(&e.to_bytes());
            }
        }
        let meta_offset = (HEADER_LEN + region.len()) as u64;
        region.extend_from_slice(&meta_bytes);
        let mut header = FileHeader {
            version: VERSION,
            flags: 0,
            meta_offset,
            meta_len: meta_bytes.len() as u64,
            level_table_offset: HEADER_LEN as u64,
            level_count: u32::from(g.level_count()),
            index_entry_len: INDEX_ENTRY_LEN as u32,
            records_offset,
            checksum: 0,
        };
        header.checksum = header.compute_checksum(&region);
        let mut file = header.to_bytes().to_vec();
        file.extend_from_slice(&region);
        file.extend_from_slice(&records);
        Pyramid::open(file).unwrap()
    }

    #[test]
    fn path_cameras_fly_the_whole_path_at_altitude_over_the_finest_ground() {
        // 300 × 200 samples: a finest level of 8 × 8 slots (5 × 4 tiles present)
        // under three coarser levels.
        let pyramid = test_pyramid(300, 200);
        let world = World {
            geometry: *pyramid.geometry(),
            quant: pyramid.metadata().quantization,
            spacing: DVec2::splat(7.5),
            globe: None,
        };
        let size = DVec2::new(300.0, 200.0) * 7.5;
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("corner.json");
        std::fs::write(
            &file,
            r#"{"waypoints": [[0, 0], [1, 0], [1, 1]], "speed_mps": 40, "altitude_agl_m": 20}"#,
        )
        .unwrap();
        let file = file.to_str().unwrap();
        for (name, fps) in [
            ("canyon", 60.0),
            ("pass", 60.0),
            ("orbit", 24.0),
            (file, 30.0),
        ] {
            let path = FlyPath::load(name, size.max_element()).unwrap();
            let length: f64 = path
                .waypoints
                .windows(2)
                .map(|w| ((DVec2::from(w[1]) - DVec2::from(w[0])) * size).length())
                .sum();
            let cameras = path_cameras(&pyramid, &world, name, fps, 640, 480).unwrap();
            let want = (length / path.speed_mps.unwrap() * fps).ceil() as usize + 1;
            assert_eq!(cameras.len(), want, "{name}: frames");
            for (f, c) in cameras.iter().enumerate() {
                let pose = path.pose(f as f64 / fps, size);
                assert_eq!(c.position.x, pose.ground.x, "{name} frame {f}");
                assert_eq!(c.position.z, pose.ground.y, "{name} frame {f}");
                let (fx, fy) = (
                    ((pose.ground.x / 7.5).round() as u64).min(299),
                    ((pose.ground.y / 7.5).round() as u64).min(199),
                );
                let ground = world.quant.height(test_height(fx, fy, 0));
                assert_eq!(
                    c.position.y,
                    ground + path.altitude_agl_m.unwrap(),
                    "{name} frame {f}: eye over ({fx}, {fy})"
                );
                assert_eq!((c.yaw, c.pitch), (pose.yaw, pose.pitch));
                assert_eq!((c.width, c.height), (640, 480));
            }
            // The last frame is at the last waypoint: exactly for a path that stops
            // there, within a frame's flight for a looped one (orbit's last waypoint
            // is its first).
            let end = DVec2::from(*path.waypoints.last().unwrap()) * size;
            let last = cameras.last().unwrap().position;
            let miss = (DVec2::new(last.x, last.z) - end).length();
            let within = if path.looped {
                path.speed_mps.unwrap() / fps
            } else {
                1e-6
            };
            assert!(miss <= within, "{name}: last frame {miss} m from the end");
        }
        assert!(path_cameras(&pyramid, &world, "pass", 0.0, 640, 480).is_err());
        assert!(path_cameras(&pyramid, &world, "no-such-path", 60.0, 640, 480).is_err());
    }
    /// Whether a world point is inside a camera's view frustum (clip space, depth
    /// 0..1).
    fn in_view(c: &Camera, p: DVec3) -> bool {
        let q = c.view_projection() * p.extend(1.0);
        q.w > 0.0 && q.x.abs() <= q.w && q.y.abs() <= q.w && q.z >= 0.0 && q.z <= q.w
    }

    #[test]
    fn descent_starts_with_the_whole_dataset_in_view() {
        for extent in [2000.0, 30_000.0, 245_000.0] {
            let path = FlyPath::builtin("descent", extent).unwrap();
            path.check().unwrap();
            let size = DVec2::splat(extent);
            let pose = path.pose(0.0, size);
            assert!(pose.pitch.to_degrees() < -80.0, "{extent}: looks down");
            let centre = DVec2::splat(extent / 2.0);
            assert!(
                (pose.ground - centre).length() < 0.05 * extent,
                "{extent}: over the centre, {:?}",
                pose.ground
            );
            // The ground anywhere in 0..relief, under the eye and at the corners.
            let relief = (0.1 * extent).min(5000.0);
            for (w, h) in [(1280, 720), (800, 600)] {
                for eye_ground in [0.0, relief] {
                    let c = pose_camera(&pose, eye_ground, extent, 1.0, (w, h));
                    for corner in 0..8 {
                        let p = DVec3::new(
                            if corner & 1 == 0 { 0.0 } else { extent },
                            if corner & 2 == 0 { 0.0 } else { relief },
                            if corner & 4 == 0 { 0.0 } else { extent },
                        );
                        assert!(
                            in_view(&c, p),
                            "{extent} m, {w}×{h}, ground {eye_ground}: corner {p} out of view"
                        );
                    }
                    // Not absurdly far: the DEM fills at least a third of the height.
                    let near = c.view_projection() * DVec3::new(centre.x, 0.0, 0.0).extend(1.0);
                    let far = c.view_projection() * DVec3::new(centre.x, 0.0, extent).extend(1.0);
                    assert!(
                        (near.y / near.w - far.y / far.w).abs() > 2.0 / 3.0,
                        "{extent}"
                    );
                }
            }
        }
    }

    #[test]
    fn descent_comes_down_continuously_to_100_m_looking_ahead() {
        let pyramid = test_pyramid(300, 200);
        let world = World {
            geometry: *pyramid.geometry(),
            quant: pyramid.metadata().quantization,
            spacing: DVec2::splat(7.5),
            globe: None,
        };
        let size = DVec2::new(300.0, 200.0) * 7.5;
        let path = FlyPath::builtin("descent", size.max_element()).unwrap();
        let cameras = path_cameras(&pyramid, &world, "descent", 30.0, 640, 480).unwrap();
        assert_eq!(cameras.len(), (DESCENT_S * 30.0) as usize + 1);
        let poses: Vec<Pose> = (0..cameras.len())
            .map(|f| path.pose(f as f64 / 30.0, size))
            .collect();
        // Above the ground under the eye: falling every frame, never jumping by more
        // than a sixth between frames.
        for w in poses.windows(2) {
            assert!(w[1].altitude_agl < w[0].altitude_agl);
            assert!(w[1].altitude_agl > w[0].altitude_agl * 5.0 / 6.0);
            assert!(w[1].pitch >= w[0].pitch, "pitch rises");
            assert_eq!(
                w[1].yaw.abs(),
                std::f64::consts::PI,
                "heading south throughout"
            );
        }
        let (last, pose) = (cameras.last().unwrap(), poses.last().unwrap());
        let (fx, fy) = (
            ((pose.ground.x / 7.5).round() as u64).min(299),
            ((pose.ground.y / 7.5).round() as u64).min(199),
        );
        let ground = world.quant.height(test_height(fx, fy, 0));
        assert!((last.position.y - ground - DESCENT_END_AGL_M).abs() < 1e-9);
        assert!((last.pitch.to_degrees() + 10.0).abs() < 1e-9, "looks ahead");
        assert!(cameras[0].position.y > ground + size.max_element());
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
            assert!(format!("{e:#}").contains(want), "{json}: {e:#}");
        }
    }
}
