//! Fly-through paths: small JSON files of waypoints, speed and altitude above ground,
//! used by `tessera fly`, the load generator, tests and benchmarks.
//!
//! ```json
//! { "waypoints": [[0.1, 0.5], [0.9, 0.5]], "speed_mps": 300, "altitude_agl_m": 200,
//!   "pitch_deg": -15, "looped": false }
//! ```
//! Waypoints are fractions of the DEM's width and height (so one path fits any
//! dataset); the camera flies the polyline at `speed_mps`, looking along it.
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

    /// The pose after `t` seconds on a DEM `size_m` metres wide and high.
    pub fn pose(&self, t: f64, size_m: DVec2) -> Pose {
        let pts = self.points(size_m);
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

/// The camera of a pose over ground at height `ground_m`, on a DEM `extent_m` metres
/// across: looking along the path with a 60° vertical field of view times
/// `fov_scale` (the prefetch view is wider), `width × height` pixels, and a far plane
/// beyond the whole DEM.
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
        near: 1.0,
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
    let frames = (fly_path.length_m(size) / fly_path.speed_mps * fps).ceil() + 1.0;
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
            let want = (length / path.speed_mps * fps).ceil() as usize + 1;
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
                    ground + path.altitude_agl_m,
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
                path.speed_mps / fps
            } else {
                1e-6
            };
            assert!(miss <= within, "{name}: last frame {miss} m from the end");
        }
        assert!(path_cameras(&pyramid, &world, "pass", 0.0, 640, 480).is_err());
        assert!(path_cameras(&pyramid, &world, "no-such-path", 60.0, 640, 480).is_err());
    }
}
