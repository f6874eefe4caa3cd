//! True ground geometry and validity masks on real geographic DEMs (DECISIONS.md
//! "Coordinate systems, masks and reprojection"), end to end: `tessera-server build` →
//! serve → the client's dataset document, selection, streaming and wgpu renderer
//! (lavapipe here).
//!
//! - A geographic DEM's cells are not square: N46E008's are 63.97 m east–west and
//!   92.63 m north–south, and the client places samples with both spacings, so 1 km
//!   on the ground is the same number of pixels whichever way it runs.
//! - The acceptance frame: N46E008 straight down from 200 km is 0.6906× as wide as
//!   tall (76.8 km × 111.2 km), not square.
//! - Luxembourg (no-data outside the national border): no terrain pixel where the
//!   DEM has no terrain, at every level, in full and in flights; the same DEM
//!   reprojected to UTM has wholly no-data tiles, which the server leaves absent
//!   and the client neither waits for nor counts as holes.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared fixtures
mod streaming_support;

use glam::{DVec2, DVec3, DVec4};
use std::collections::{BTreeSet, HashMap};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Duration;
use tessera_client::app::fly::FlyOptions;
use tessera_client::app::headless::{Draws, RenderSetup};
use tessera_client::camera::Camera;
use tessera_client::paths;
use tessera_client::render::gpu::Backend;
use tessera_client::render::{DebugView, RenderOptions, Renderer, png_out, quality, reference};
use tessera_client::select::World;
use tessera_client::stream::pool::TilePool;
use tessera_client::stream::{StreamConfig, Streamer};
use tessera_server::builder::{BuildOptions, build};
use tessera_server::ingest::reproject::{ReprojectOptions, Resampling};
use tessera_shared::codec::{RecordLayout, TileRecord};
use tessera_shared::{FileSource, Pyramid, TileId, api, testdata};

/// A built pyramid, its records and the client's world for it.
struct Dataset {
    name: &'static str,
    file: PathBuf,
    pyramid: Pyramid<FileSource>,
    records: HashMap<TileId, TileRecord>,
    /// As `tessera fly` makes it from the dataset document: the measured spacings.
    world: World,
}

impl Dataset {
    fn build(dir: &Path, name: &'static str, input: &Path, opts: &BuildOptions) -> Self {
        let file = dir.join(format!("{name}.tess"));
        build(input.to_str().unwrap(), &file, opts).unwrap();
        let pyramid = Pyramid::open_file(&file).unwrap();
        let g = *pyramid.geometry();
        let mut records = HashMap::new();
        for level in g.levels() {
            for tile in g.present_tiles(level) {
                if let Some(rec) = pyramid.read_tile(tile).unwrap() {
                    records.insert(tile, rec);
                }
            }
        }
        let meta = pyramid.metadata();
        let world = World {
            geometry: g,
            quant: meta.quantization,
            spacing: World::spacing_from(None, meta.ground_spacing),
            globe: None,
        };
        Self {
            name,
            file,
            pyramid,
            records,
            world,
        }
    }

    /// Tiles the geometry places inside the DEM that have no record.
    fn absent(&self) -> usize {
        let g = self.world.geometry;
        g.levels()
            .flat_map(|l| g.present_tiles(l))
            .filter(|t| !self.records.contains_key(t))
            .count()
    }

    fn pool(&self) -> TilePool {
        let mut pool = TilePool::new(self.records.len() + 8);
        for (&t, r) in &self.records {
            pool.insert(t, r.errors.clone(), r.heights.clone(), r.mask.clone());
        }
        pool
    }
}

/// The three pyramids, served by one real server.
struct Fixture {
    _dir: tempfile::TempDir,
    _rt: tokio::runtime::Runtime,
    server: SocketAddr,
    /// N46E008 as `tessera-server build N46E008.tif` makes it (512-cell tiles).
    alps: Dataset,
    /// Luxembourg at its own 30″ grid, 64-cell tiles (two levels).
    lux: Dataset,
    /// Luxembourg resampled (nearest) to UTM 32N at 100 m, 64-cell tiles: five
    /// levels, and tiles beyond the rotated border that hold no terrain (absent).
    lux_utm: Dataset,
}

fn fixture() -> Option<&'static Fixture> {
    static F: OnceLock<Option<Fixture>> = OnceLock::new();
    F.get_or_init(|| {
        let alps_in = testdata::dem_or_skip("N46E008.tif")?;
        let lux_in = testdata::dem_or_skip("luxembourg_elev.tif")?;
        let dir = tempfile::tempdir().unwrap();
        let alps = Dataset::build(dir.path(), "N46E008", &alps_in, &BuildOptions::default());
        let small = BuildOptions {
            tile_size: 64,
            ..BuildOptions::default()
        };
        let lux = Dataset::build(dir.path(), "luxembourg", &lux_in, &small);
        let utm = BuildOptions {
            reproject: Some(ReprojectOptions {
                to: "EPSG:32632".into(),
                resampling: Resampling::Nearest,
                spacing: Some([100.0, 100.0]),
            }),
            ..small
        };
        let lux_utm = Dataset::build(dir.path(), "luxembourg_utm", &lux_in, &utm);
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .unwrap();
        let settings = tessera_server::serve::config::Settings {
            listen: "127.0.0.1:0".parse().unwrap(),
            datasets: vec![alps.file.clone(), lux.file.clone(), lux_utm.file.clone()],
            ..tessera_server::serve::config::Settings::default()
        };
        let state = tessera_server::serve::state(&settings).unwrap();
        let listener = rt
            .block_on(tokio::net::TcpListener::bind(settings.listen))
            .unwrap();
        let server = listener.local_addr().unwrap();
        rt.spawn(async move {
            let _ = tessera_server::serve::serve_until(
                listener,
                state,
                &settings,
                std::future::pending(),
            )
            .await;
        });
        Some(Fixture {
            _dir: dir,
            _rt: rt,
            server,
            alps,
            lux,
            lux_utm,
        })
    })
    .as_ref()
}

/// Where a pixel of `camera`'s image shows world point `p` (x right, y down).
fn project(camera: &Camera, p: DVec3) -> DVec2 {
    let c = camera.view_projection() * DVec4::new(p.x, p.y, p.z, 1.0);
    let ndc = c.truncate().truncate() / c.w;
    DVec2::new(
        f64::midpoint(ndc.x, 1.0) * f64::from(camera.width),
        f64::midpoint(1.0, -ndc.y) * f64::from(camera.height),
    )
}

/// Straight down from `altitude` m above the DEM's highest point, over its centre,
/// north up.
fn straight_down(world: &World, max_height: f64, altitude: f64, size: u32) -> Camera {
    let c = world.size_m() / 2.0;
    Camera {
        position: DVec3::new(c.x, max_height + altitude, c.y),
        yaw: 0.0,
        pitch: -std::f64::consts::FRAC_PI_2,
        fovy: 60f64.to_radians(),
        width: size,
        height: size,
        near: 1.0,
        far: 2.0 * (max_height + altitude) + 1e5,
    }
}

/// Metres per degree of latitude and of longitude on the WGS 84 ellipsoid at
/// latitude `phi` (degrees): the meridional radius of curvature `M` and the
/// parallel's radius `N·cos φ`, times π/180.
fn wgs84_metres_per_degree(phi: f64) -> (f64, f64) {
    let a = 6_378_137.0;
    let f = 1.0 / 298.257_223_563;
    let e2 = f * (2.0 - f);
    let s = phi.to_radians().sin();
    let w = (1.0 - e2 * s * s).sqrt();
    let m = a * (1.0 - e2) / (w * w * w);
    let n = a / w;
    let rad = std::f64::consts::PI / 180.0;
    (m * rad, n * phi.to_radians().cos() * rad)
}

/// The client's world for a dataset as `tessera fly` builds it: from the dataset
/// document the real server sends (`ground_spacing`, no `--spacing`).
fn world_from_server(f: &Fixture, name: &str) -> World {
    let server = format!("http://{}", f.server);
    let streamer = Streamer::new(
        &server,
        name,
        RecordLayout::current(9),
        StreamConfig::default(),
    )
    .unwrap();
    let url = format!(
        "{server}{}",
        api::fill(api::routes::DATASET, &[("name", name)])
    );
    let info: api::DatasetInfo = streamer.block_on(async {
        let r = streamer.client().get(&url).send().await.unwrap();
        assert!(r.status().is_success(), "{url}: {}", r.status());
        serde_json::from_str(&r.text().await.unwrap()).unwrap()
    });
    World::from_dataset(&info, None).unwrap()
}

/// 1 km east–west and 1 km north–south on the ground cover the same pixels in a
/// straight-down view of N46E008, whose cells are 1/1200° square in degrees and
/// far from square in metres. The ground distances come from the WGS 84 formulas
/// at the DEM's centre (46.5° N), not from the client: 1 km east is 15.6 columns,
/// 1 km south 10.8 rows. The world is the one the client makes of the server's
/// dataset document. Drawn with square cells (the east–west spacing for both
/// axes, as before the metadata carried both spacings), north–south would be 31 %
/// short.
#[test]
fn a_kilometre_is_as_many_pixels_east_west_as_north_south() {
    let Some(f) = fixture() else { return };
    let world = world_from_server(f, "N46E008");
    let meta = f.alps.pyramid.metadata();
    let gs = meta.ground_spacing.expect("N46E008 has a ground spacing");
    assert_eq!(world.spacing, DVec2::new(gs.x, gs.y));
    // PixelIsPoint: the tiepoint (8°E, 47°N) is the first sample; the centre row
    // (600) is at 46.5°N.
    let (per_deg_ns, per_deg_ew) = wgs84_metres_per_degree(46.5);
    let step = 1.0 / 1200.0;
    let (cols_per_km, rows_per_km) = (1000.0 / (per_deg_ew * step), 1000.0 / (per_deg_ns * step));
    println!("1 km = {cols_per_km:.3} columns east–west, {rows_per_km:.3} rows north–south");
    let h = 1500.0;
    let camera = straight_down(&world, h, 20_000.0, 1000);
    let at = |col: f64, row: f64| {
        let m = world.metres(col, row);
        project(&camera, DVec3::new(m.x, h, m.y))
    };
    let centre = at(600.0, 600.0);
    let east = at(600.0 + cols_per_km, 600.0);
    let south = at(600.0, 600.0 + rows_per_km);
    let (ew, ns) = ((east - centre).length(), (south - centre).length());
    println!("1 km east–west: {ew:.3} px, north–south: {ns:.3} px");
    assert!(ew > 10.0, "{ew} px: the kilometre must be visible");
    // The server measures its spacing in a transverse Mercator centred on the DEM
    // (DECISIONS.md); the ellipsoid formulas agree with it to ~0.02 %.
    assert!(
        (ew / ns - 1.0).abs() < 2e-3,
        "1 km east–west is {ew:.3} px but north–south {ns:.3} px"
    );
}

/// A one-camera path straight down over the DEM's centre, north up: two waypoints
/// 0.01 % of the height apart (the first sets the eye, the pair the heading), at
/// `altitude` above the ground there.
fn straight_down_path(dir: &Path, altitude: f64) -> String {
    let p = dir.join(format!("down_{altitude}.json"));
    std::fs::write(
        &p,
        format!(
            r#"{{"waypoints": [[0.5, 0.5], [0.5, 0.4999]], "speed_mps": 1000, "altitude_agl_m": {altitude}, "pitch_deg": -90}}"#
        ),
    )
    .unwrap();
    p.to_string_lossy().into_owned()
}

/// `tessera fly --out DIR --quality --settle --quality-every 1 --frames 1`: the one
/// frame waits until the selection has everything it asks for, and is drawn with
/// the full-resolution reference beside it (`DIR/reference/`).
fn settled_flight(
    f: &Fixture,
    d: &Dataset,
    path: String,
    tau: f64,
    size: u32,
    out_dir: &Path,
) -> tessera_client::app::fly::FrameRecord {
    let opts = FlyOptions {
        source: tessera_client::stream::TileSource::server(format!("http://{}", f.server), d.name),
        path,
        frames: 1,
        fps: 30.0,
        tau,
        policy: tessera_client::select::Policy::ScreenError,
        morph_seconds: tessera_client::select::MORPH_SECONDS,
        morph_by_distance: false,
        morph_error_limit: tessera_client::select::MORPH_ERROR_LIMIT,
        width: size,
        height: size,
        spacing: None,
        prefetch: false,
        pool_tiles: 512,
        stream: StreamConfig::default(),
        t_offset: 0.0,
        runtime: None,
        progress: None,
        render: Some(RenderSetup {
            opts: RenderOptions {
                width: size,
                height: size,
                slots: 256,
                backend: Backend::Vulkan,
                ..RenderOptions::default()
            },
            out_dir: out_dir.to_path_buf(),
            draws: Draws::Quality,
            quality_every: 1,
            write_frames: true,
            upload_budget: Duration::from_millis(100),
            settle: true,
            reference_cache: None,
        }),
        globe: tessera_client::globe::GlobeMode::Off,
    };
    let (mut frames, summary) = streaming_support::run_flight(&opts);
    assert_eq!(frames.len(), 1);
    assert_eq!(summary.frames_drawn, 1, "{summary:?}");
    let rec = frames.remove(0);
    let render = rec.render.expect("a rendered flight records its rendering");
    assert!(render.converged, "the settled frame still wanted tiles");
    assert_eq!(rec.select.missing, 0, "holes in a settled frame");
    rec
}

/// Which pixels of a frame written by `tessera fly` show terrain: all but the
/// painted sky.
fn terrain_in_png(path: &Path) -> (Vec<bool>, u32, u32) {
    let (rgba, w, h) = png_out::read_png(path).unwrap();
    let terrain = rgba
        .chunks_exact(4)
        .enumerate()
        .map(|(i, px)| px[..3] != quality::painted_sky(i as u32 / w, h)[..3])
        .collect();
    (terrain, w, h)
}

/// `(width, height)` in pixels of the box around the terrain pixels.
fn footprint(terrain: &[bool], w: u32) -> (u32, u32) {
    let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
    for (i, _) in terrain.iter().enumerate().filter(|(_, t)| **t) {
        let (x, y) = (i as u32 % w, i as u32 / w);
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
    }
    assert!(x0 <= x1, "no terrain in the frame");
    (x1 - x0 + 1, y1 - y0 + 1)
}

/// The acceptance frame of true ground geometry: N46E008 straight down from 200 km above
/// its centre, drawn by the real flight (`tessera fly` with a one-camera path JSON,
/// settled), north up. Its footprint — terrain pixels against the sky, which is all that
/// surrounds it now that masks keep the padding beyond the DEM's east and south edges
/// from being drawn — is 76.8 km × 111.2 km on the ground, so 63.97/92.63 = 0.6906× as
/// wide as tall; within 1 %. (Before two spacings and validity masks it was square, with
/// streaks of padding beyond two edges.) The frame is written to
/// `target/acceptance/N46E008/frame_00000.png` to be looked at.
///
/// The 1 % holds the frame's own errors: a pixel at each edge of a ~530 px wide
/// box (0.4 %), and relief: points 3 km above the ground at the edges are seen
/// 1.5 % larger from 200 km, but on every edge alike to within ~0.4 %.
#[test]
fn n46e008_straight_down_is_0_69_times_as_wide_as_tall() {
    let Some(f) = fixture() else { return };
    let out = Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/acceptance/N46E008");
    let _ = std::fs::remove_dir_all(&out);
    std::fs::create_dir_all(&out).unwrap();
    let path = straight_down_path(&out, 200_000.0);
    settled_flight(f, &f.alps, path, 1.0, 1600, &out);
    let frame = out.join("frame_00000.png");
    println!(
        "acceptance frame: {}",
        frame.canonicalize().unwrap().display()
    );
    let (terrain, w, _) = terrain_in_png(&frame);
    let (fw, fh) = footprint(&terrain, w);
    let ratio = f64::from(fw) / f64::from(fh);
    let gs = f.alps.pyramid.metadata().ground_spacing.unwrap();
    let want = gs.x / gs.y;
    println!(
        "footprint {fw} × {fh} px: {ratio:.4} as wide as tall (spacings {:.2} × {:.2} m: {want:.4})",
        gs.x, gs.y
    );
    assert!(
        (ratio / want - 1.0).abs() <= 0.01,
        "footprint {fw} × {fh} px is {ratio:.4}× as wide as tall, not {want:.4}"
    );
    // The reference (full resolution) drawn in the same flight agrees.
    let (reference, _, _) = terrain_in_png(&out.join("reference/frame_00000.png"));
    let (rw, rh) = footprint(&reference, w);
    assert!(
        fw.abs_diff(rw) <= 2 && fh.abs_diff(rh) <= 2,
        "{rw} × {rh} px"
    );
}

/// The DEM's own validity seen by `camera`: every terrain cell of the finest
/// level (its mask) rasterised on the CPU as the two triangles between its
/// corners at their finest heights, terrain where a pixel centre is inside one.
fn reference_terrain(d: &Dataset, camera: &Camera) -> Vec<bool> {
    let g = d.world.geometry;
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut out = vec![false; w * h];
    let n = g.tile_samples();
    let mut fill = |a: DVec2, b: DVec2, c: DVec2| {
        let area = (b - a).perp_dot(c - a);
        if area.abs() < 1e-12 {
            return;
        }
        let lo = a.min(b).min(c).floor().max(DVec2::ZERO);
        let hi = a.max(b).max(c).ceil();
        for y in lo.y as usize..(hi.y as usize).min(h) {
            for x in lo.x as usize..(hi.x as usize).min(w) {
                let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                let (e0, e1, e2) = (
                    (b - a).perp_dot(p - a) / area,
                    (c - b).perp_dot(p - b) / area,
                    (a - c).perp_dot(p - c) / area,
                );
                if e0 >= 0.0 && e1 >= 0.0 && e2 >= 0.0 {
                    out[y * w + x] = true;
                }
            }
        }
    };
    for tile in g.present_tiles(g.finest()) {
        let Some(rec) = d.records.get(&tile) else {
            continue; // absent: no terrain
        };
        let (gx, gy) = g.origin(tile);
        let corner = |i: u32, j: u32| {
            let m = d
                .world
                .metres((gx + u64::from(i)) as f64, (gy + u64::from(j)) as f64);
            let q = rec.heights[j as usize * n + i as usize];
            project(camera, DVec3::new(m.x, d.world.quant.height(q), m.y))
        };
        for j in 0..g.tile_size() {
            for i in 0..g.tile_size() {
                if rec.mask.is_valid(i, j) {
                    let (a, b, c, e) = (
                        corner(i, j),
                        corner(i + 1, j),
                        corner(i + 1, j + 1),
                        corner(i, j + 1),
                    );
                    fill(a, b, c);
                    fill(a, c, e);
                }
            }
        }
    }
    out
}

/// Terrain pixels where the reference has none: `(exact, beyond one pixel)`, the
/// second counting only those with no reference terrain among their eight
/// neighbours either.
fn terrain_without_reference(image: &[bool], reference: &[bool], w: u32, h: u32) -> (usize, usize) {
    let (w, h) = (w as usize, h as usize);
    let (mut exact, mut beyond) = (0, 0);
    for y in 0..h {
        for x in 0..w {
            if !image[y * w + x] || reference[y * w + x] {
                continue;
            }
            exact += 1;
            let near = (y.saturating_sub(1)..(y + 2).min(h))
                .any(|yy| (x.saturating_sub(1)..(x + 2).min(w)).any(|xx| reference[yy * w + xx]));
            if !near {
                beyond += 1;
            }
        }
    }
    (exact, beyond)
}

/// Every level of a pyramid drawn whole at full resolution straight down, with
/// `view`: the pixels that show terrain (or, in the mask view, red non-terrain).
fn draw_levels(d: &Dataset, camera: &Camera, view: DebugView) -> Vec<(u8, Vec<bool>)> {
    let meta = d.pyramid.metadata();
    let mut r = Renderer::new(
        d.world,
        (meta.min_height, meta.max_height),
        RenderOptions {
            width: camera.width,
            height: camera.height,
            slots: d.records.len() as u32 + 1,
            view,
            backend: Backend::Vulkan,
            ..RenderOptions::default()
        },
    )
    .unwrap();
    let pool = d.pool();
    let mut tiles: Vec<TileId> = d.records.keys().copied().collect();
    tiles.sort_unstable();
    for &t in &tiles {
        assert!(r.upload(&pool, t), "no slot for {t}");
    }
    let tables: HashMap<_, _> = d
        .records
        .iter()
        .map(|(t, r)| (*t, r.errors.clone()))
        .collect();
    let frustum = camera.frustum();
    d.world
        .geometry
        .levels()
        .map(|level| {
            let of_level: Vec<TileId> = tiles
                .iter()
                .copied()
                .filter(|t| t.level() == level)
                .collect();
            let patches =
                reference::full_resolution_patches(&d.world, &of_level, &tables, &frustum);
            r.draw(camera, &patches).unwrap();
            let rgba = r.read_rgba().unwrap();
            let terrain = rgba.chunks_exact(4).map(|p| !quality::is_sky(p)).collect();
            (level.get(), terrain)
        })
        .collect()
}

/// Straight down over a whole dataset, 800 px square.
fn over(d: &Dataset) -> Camera {
    let meta = d.pyramid.metadata();
    let size = d.world.size_m();
    // The DEM's larger side spans ~70 % of the view.
    let altitude = size.max_element() / 2.0 / (30f64.to_radians().tan() * 0.7);
    straight_down(&d.world, meta.max_height, altitude, 800)
}

/// Luxembourg's border mask: masked cells stay masked through every level and are
/// never drawn. Each level of each pyramid is drawn whole, at full resolution,
/// straight down, and compared with the finest level's mask rasterised on the CPU
/// with the same camera: no terrain pixel may lie where the reference has none.
///
/// Tolerance: one pixel of border. A coarse level's terrain is a union of finest
/// cells (AND-pooled masks), but its mesh interpolates heights between coarser
/// samples, so on screen its border lies a fraction of a pixel away from the finest
/// mesh's (heights off by up to ~140 m here, seen at most ~21° off the axis:
/// ≤ 55 m, against pixels of ~150 m), and a pixel centre can fall either side; GPU
/// and CPU also break ties on edges differently. So a terrain pixel counts as
/// wrong only when neither it nor any of its eight neighbours is terrain in the
/// reference; the exact count is printed (0–2 pixels per level when written).
///
/// The same levels drawn in the mask view (non-terrain cells shown in red instead
/// of discarded) must fail that count by far: the comparison sees no-data and the
/// padding beyond the DEM whenever they are drawn.
#[test]
fn luxembourg_no_terrain_is_drawn_where_the_dem_has_none_at_any_level() {
    let Some(f) = fixture() else { return };
    assert!(
        f.lux_utm.absent() > 0,
        "the UTM pyramid should have absent tiles"
    );
    for d in [&f.lux, &f.lux_utm] {
        let camera = over(d);
        let reference = reference_terrain(d, &camera);
        let ref_pixels = reference.iter().filter(|t| **t).count();
        assert!(
            ref_pixels > 100_000,
            "{}: {ref_pixels} reference pixels",
            d.name
        );
        let levels = draw_levels(d, &camera, DebugView::Shaded);
        assert_eq!(levels.len(), usize::from(d.world.geometry.level_count()));
        for (level, image) in &levels {
            let drawn = image.iter().filter(|t| **t).count();
            let (exact, beyond) = terrain_without_reference(image, &reference, 800, 800);
            println!(
                "{} level {level}: {drawn} terrain pixels ({ref_pixels} in the reference), {exact} outside it, {beyond} beyond one pixel",
                d.name
            );
            // Most of the country is drawn at every level.
            assert!(drawn * 10 > ref_pixels * 8, "{} level {level}", d.name);
            assert_eq!(
                beyond, 0,
                "{} level {level}: terrain where the DEM has none",
                d.name
            );
        }
        // Without discarding, the comparison fails at every level.
        for (level, image) in draw_levels(d, &camera, DebugView::Mask) {
            let (_, beyond) = terrain_without_reference(&image, &reference, 800, 800);
            println!(
                "{} level {level}, non-terrain drawn: {beyond} pixels beyond one pixel",
                d.name
            );
            assert!(beyond > 5_000, "{} level {level}: {beyond}", d.name);
        }
    }
}

/// The same check on what real flights draw: `tessera fly` straight down over
/// each Luxembourg pyramid, served by the real server and settled (the frame
/// waits until selection has everything it asks for), at τ from ¼ to 64 px so that
/// the flights draw several levels. Over the UTM pyramid the flight asks for tiles
/// that turn out to be absent (wholly no-data; the full-resolution reference drawn
/// beside each frame asks for every finest tile in view): the tile stream's trailer
/// lists them, the client remembers them, and the frame settles with no hole
/// counted instead of waiting for them until it fails. Same tolerance as above (one
/// pixel of border), for the same reasons: the flights' patches also simplify
/// within tiles (inner LODs below full resolution), which moves the border's
/// heights, and so where it is seen, the same way a coarse level does.
#[test]
fn luxembourg_flights_draw_no_terrain_where_the_dem_has_none() {
    let Some(f) = fixture() else { return };
    let dir = tempfile::tempdir().unwrap();
    for d in [&f.lux, &f.lux_utm] {
        let camera_shape = over(d);
        let agl = camera_shape.position.y - d.pyramid.metadata().max_height;
        let path = straight_down_path(dir.path(), agl.round());
        // The flight's camera, placed as `tessera fly` places it (ground from the
        // finest tile under the eye).
        let camera = paths::path_cameras(&d.pyramid, &d.world, &path, 30.0, 800, 800).unwrap()[0];
        let reference = reference_terrain(d, &camera);
        let mut coarsest = BTreeSet::new();
        for tau in [0.25, 1.0, 4.0, 16.0, 64.0] {
            let out = dir.path().join(format!("{}-{tau}", d.name));
            let rec = settled_flight(f, d, path.clone(), tau, 800, &out);
            coarsest.extend(rec.select.coarsest_level);
            let (image, w, h) = terrain_in_png(&out.join("frame_00000.png"));
            let (exact, beyond) = terrain_without_reference(&image, &reference, w, h);
            println!(
                "{} τ = {tau}: {} tiles from level {:?}, {exact} terrain pixels outside the reference, {beyond} beyond one pixel",
                d.name, rec.select.tiles, rec.select.coarsest_level
            );
            assert_eq!(
                beyond, 0,
                "{} τ = {tau}: terrain where the DEM has none",
                d.name
            );
            let drawn = image.iter().filter(|t| **t).count();
            let ref_pixels = reference.iter().filter(|t| **t).count();
            assert!(drawn * 10 > ref_pixels * 8, "{} τ = {tau}", d.name);
        }
        println!("{}: coarsest levels drawn {coarsest:?}", d.name);
        assert!(coarsest.len() >= 2, "{}: levels {coarsest:?}", d.name);
    }
}

/// With every record of a local pyramid resident (`bench-select`'s setting), a
/// parent whose children are partly absent (wholly no-data, beyond Luxembourg's
/// border in the UTM pyramid) is still refined into the children it has: seen from
/// close above, every such parent gives way to its present children, nothing is
/// wanted and the error stays bounded.
#[test]
fn selection_refines_into_present_children_beside_absent_ones() {
    let Some(f) = fixture() else { return };
    let d = &f.lux_utm;
    let g = d.world.geometry;
    let tables = tessera_client::select::all_tables(&d.pyramid).unwrap();
    let parents: Vec<TileId> = g
        .present_tiles(tessera_shared::Level::new(g.finest().get() - 1).unwrap())
        .filter(|p| {
            let c = p.children().unwrap();
            c.iter().any(|c| tables.contains_key(c))
                && c.iter()
                    .any(|c| g.is_present(*c) && !tables.contains_key(c))
        })
        .collect();
    assert!(!parents.is_empty(), "no parent with absent children");
    let meta = d.pyramid.metadata();
    for p in parents {
        let (origin, size) = d.world.tile_extent(p);
        let c = origin + size / 2.0;
        let camera = Camera {
            position: DVec3::new(c.x, meta.max_height + 3000.0, c.y),
            yaw: 0.0,
            pitch: -std::f64::consts::FRAC_PI_2,
            fovy: 60f64.to_radians(),
            width: 800,
            height: 800,
            near: 1.0,
            far: 1e6,
        };
        let mut sel = tessera_client::select::Selector::new(
            d.world,
            tessera_client::select::SelectParams::default(),
        );
        let s = sel.select(&camera, &tables);
        assert!(s.wanted.is_empty(), "{p}: wants {:?}", s.wanted);
        assert_eq!(s.stats.missing, 0, "{p}");
        assert!(
            s.stats.deficit.is_some_and(|x| x <= 1.0),
            "{p}: {:?}",
            s.stats
        );
        assert!(!s.tiles.contains(&p), "{p} was not refined");
        assert!(
            s.tiles.iter().any(|t| t.parent() == Some(p)),
            "{p}: none of its present children drawn"
        );
    }
}
