//! The cameras of a path: the eye of a pose over the ground, its camera, and every
//! frame's camera over a local pyramid (benchmarks, tests).

use super::fly_path::{FlyPath, PathError, Pose};
use crate::camera::Camera;
use crate::select::World;
use crate::stream::pool::TilePool;
use glam::DVec3;
use tessera_shared::reader::ReadError;
use tessera_shared::{ByteSource, Pyramid};

/// Why a path's cameras could not be placed.
#[derive(Debug, thiserror::Error)]
pub enum CamerasError {
    #[error("frames per second must be positive")]
    Fps,
    #[error("the world's geometry is not the pyramid's")]
    Geometry,
    #[error("{path}: {frames} frames at {fps} fps is too many")]
    TooMany { path: String, frames: f64, fps: f64 },
    #[error(transparent)]
    Path(#[from] PathError),
    #[error(transparent)]
    Read(#[from] ReadError),
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
) -> Result<Vec<Camera>, CamerasError> {
    if !(fps.is_finite() && fps > 0.0) {
        return Err(CamerasError::Fps);
    }
    let g = &world.geometry;
    if g != pyramid.geometry() {
        return Err(CamerasError::Geometry);
    }
    let size = world.size_m();
    let fly_path = FlyPath::load(path, size.max_element())?;
    let frames = (fly_path.duration_s(size) * fps).ceil() + 1.0;
    if frames > 1e7 {
        return Err(CamerasError::TooMany {
            path: path.into(),
            frames,
            fps,
        });
    }
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
    use crate::paths::fly_path::{DESCENT_END_AGL_M, DESCENT_S};
    use glam::DVec2;

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
}
