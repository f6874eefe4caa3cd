//! The globe (DECISIONS.md "The globe") on the real moon 4096² mosaic, built with its
//! georeferencing (`--crs +proj=longlat +R=1737400`, `--bounds`): the `descent`
//! flight rendered headless on the Moon's sphere. The first frame shows the whole
//! dataset as a region with curved edges, sky all round it (flat, the same edges
//! are straight); the last is at ground level with terrain filling the lower half;
//! both have no crack pixels against the full-resolution reference; and a tile on
//! the far side of the Moon is culled by the horizon while the near side is kept.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

use glam::DVec3;
use std::collections::HashMap;
use tessera_client::camera::Camera;
use tessera_client::globe::GlobeMode;
use tessera_client::globe::frame::EyeFrame;
use tessera_client::paths::path_cameras;
use tessera_client::render::gpu::Backend;
use tessera_client::render::{RenderOptions, Renderer, quality, reference};
use tessera_client::select::{SelectParams, Selector, World};
use tessera_client::stream::pool::TilePool;
use tessera_server::builder::{BuildOptions, build};
use tessera_shared::api::DatasetInfo;
use tessera_shared::{ErrorTable, FileSource, Pyramid, TileId, VerticalDatum, testdata};

const W: u32 = 640;
const H: u32 = 480;

struct GeoMoon {
    pyramid: Pyramid<FileSource>,
    info: DatasetInfo,
    tables: HashMap<TileId, ErrorTable>,
    pool: TilePool,
    _dir: tempfile::TempDir,
}

/// The moon 4096² (51–67°E, 9–25°N, 1/256°) on the 1737.4 km sphere.
fn moon() -> Option<GeoMoon> {
    let path = testdata::dem_or_skip("moon_crisium_gld100_4096.png")?;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("moon.tess");
    let opts = BuildOptions {
        tile_size: 256,
        offset: -10000.0,
        vertical_datum: Some(VerticalDatum::Ellipsoid),
        crs: Some("+proj=longlat +R=1737400 +no_defs".into()),
        bounds: Some(
            tessera_server::ingest::assign::Bounds::new(51.0, 8.992_187_5, 67.0, 24.992_187_5)
                .unwrap(),
        ),
        ..BuildOptions::default()
    };
    build(path.to_str().unwrap(), &out, &opts).unwrap();
    let pyramid = Pyramid::open_file(&out).unwrap();
    let info = DatasetInfo::new("moon", pyramid.metadata(), pyramid.header().version, 0);
    let g = *pyramid.geometry();
    let mut tables = HashMap::new();
    let mut pool = TilePool::new(1024);
    for level in g.levels() {
        for tile in g.present_tiles(level) {
            let rec = pyramid.read_tile(tile).unwrap().unwrap();
            tables.insert(tile, rec.errors.clone());
            pool.insert(tile, rec.errors, rec.heights, rec.mask);
        }
    }
    Some(GeoMoon {
        pyramid,
        info,
        tables,
        pool,
        _dir: dir,
    })
}

fn world(m: &GeoMoon, mode: GlobeMode) -> World {
    World::from_dataset(&m.info, None)
        .unwrap()
        .with_globe(mode, &m.info)
        .unwrap()
}

fn renderer(m: &GeoMoon, world: World) -> Renderer {
    let meta = m.pyramid.metadata();
    let mut r = Renderer::new(
        world,
        (meta.min_height, meta.max_height),
        RenderOptions {
            width: W,
            height: H,
            slots: m.tables.len() as u32 + 1,
            backend: Backend::Vulkan,
            ..RenderOptions::default()
        },
    )
    .unwrap();
    let mut tiles: Vec<_> = m.tables.keys().copied().collect();
    tiles.sort_unstable();
    for t in tiles {
        assert!(r.upload(&m.pool, t), "no slot for {t}");
    }
    r
}

/// Our frame at τ = 1 px and the full-resolution reference of the same camera.
fn ours_and_reference(r: &mut Renderer, m: &GeoMoon, cam: &Camera) -> (Vec<u8>, Vec<u8>) {
    let world = r.world;
    let mut sel = Selector::new(
        world,
        SelectParams {
            tau: 1.0,
            ..SelectParams::default()
        },
    );
    let s = sel.select(cam, &m.tables);
    assert!(!s.patches.is_empty(), "nothing selected");
    r.draw(cam, &s.patches).unwrap();
    let ours = r.read_rgba().unwrap();
    let meta = m.pyramid.metadata();
    let frustum = world.frustum(cam);
    let tiles =
        reference::finest_tiles_in_view(&world, &frustum, (meta.min_height, meta.max_height));
    let patches = reference::full_resolution_patches(&world, &tiles, &m.tables, &frustum);
    r.draw(cam, &patches).unwrap();
    (ours, r.read_rgba().unwrap())
}

/// With `GLOBE_DUMP=DIR`, writes `img` as raw RGBA (`W×H`) to `DIR/name.rgba`, for
/// looking at the frames (the report's figures).
fn dump(name: &str, img: &[u8]) {
    if let Some(dir) = std::env::var_os("GLOBE_DUMP") {
        std::fs::write(std::path::Path::new(&dir).join(format!("{name}.rgba")), img).unwrap();
    }
}

/// Sky pixels of `image` whose `(2·margin + 1)²` neighbourhood is all terrain in
/// `reference` (`margin = 1` is [`quality::crack_pixels`]).
fn cracks_inside(image: &[u8], reference: &[u8], margin: u32) -> usize {
    (margin..H - margin)
        .flat_map(|y| (margin..W - margin).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            !terrain(image, x, y)
                && (y - margin..=y + margin)
                    .all(|yy| (x - margin..=x + margin).all(|xx| terrain(reference, xx, yy)))
        })
        .count()
}

fn terrain(img: &[u8], x: u32, y: u32) -> bool {
    !quality::is_sky(&img[((y * W + x) * 4) as usize..])
}

/// The columns at 1/4, 1/2 and 3/4 of the terrain's width in the image.
fn quarter_columns(img: &[u8]) -> [u32; 3] {
    let cols: Vec<u32> = (0..W)
        .filter(|&x| (0..H).any(|y| terrain(img, x, y)))
        .collect();
    let (lo, hi) = (cols[0], *cols.last().unwrap());
    let span = hi - lo;
    [lo + span / 4, lo + span / 2, lo + 3 * span / 4]
}

/// How far the terrain's top edge bows away from a straight line: the topmost
/// terrain row in `columns`, and the middle one's distance (pixels) from the
/// chord of the other two.
fn top_edge_bow(img: &[u8], [a, b, c]: [u32; 3]) -> f64 {
    let top = |x: u32| f64::from((0..H).find(|&y| terrain(img, x, y)).unwrap());
    (top(b) - f64::midpoint(top(a), top(c))).abs()
}

/// The same bow predicted in f64: the dataset's south edge (at the top of the
/// image, the descent heading south) at height 0, projected exactly.
fn predicted_bow(world: &World, cam: &Camera, [a, b, c]: [u32; 3]) -> f64 {
    let g = world.globe.unwrap();
    let eye = EyeFrame::of_world(&g, cam.position);
    let vp = cam.view_projection_at_eye();
    let south = f64::from(world.geometry.height() - 1);
    let edge: Vec<(f64, f64)> = (0..world.geometry.width())
        .map(|x| {
            let p = eye.local(g.ecef(f64::from(x), south, 0.0));
            let clip = vp * p.extend(1.0);
            let (nx, ny) = (clip.x / clip.w, clip.y / clip.w);
            (
                f64::midpoint(nx, 1.0) * f64::from(W),
                (1.0 - ny) / 2.0 * f64::from(H),
            )
        })
        .collect();
    let row = |col: u32| {
        let px = f64::from(col) + 0.5;
        edge.iter()
            .min_by(|p, q| (p.0 - px).abs().total_cmp(&(q.0 - px).abs()))
            .unwrap()
            .1
    };
    (row(b) - f64::midpoint(row(a), row(c))).abs()
}

#[test]
fn the_descent_on_the_moon_globe_starts_with_a_curved_whole_and_lands_crack_free() {
    let Some(m) = moon() else { return };
    let body = m.info.body.expect("the georeferenced moon names its body");
    assert_eq!((body.semi_major, body.geographic), (1_737_400.0, true));
    let globe = world(&m, GlobeMode::Auto);
    assert!(
        globe.globe.is_some(),
        "auto draws a geographic dataset on the globe"
    );
    let cams = path_cameras(&m.pyramid, &globe, "descent", 10.0, W, H).unwrap();
    let (first, last) = (cams[0], *cams.last().unwrap());
    let mut r = renderer(&m, globe);

    let (ours, reference) = ours_and_reference(&mut r, &m, &first);
    dump("first", &ours);
    dump("first_reference", &reference);
    // The dataset's south and east edges end inside a coarse cell, whose mask
    // texel decides the whole cell: there the silhouette of a coarse level and of
    // the finest reference differ by a coarse cell (1–2 px here), flat or not. So
    // the crack measure is taken inside the reference's silhouette shrunk by 3 px
    // (a crack in the mesh is sky with terrain all round it, wherever it is).
    let cracks = cracks_inside(&ours, &reference, 3);
    println!(
        "first frame: {cracks} crack pixels inside, {} by quality::crack_pixels \
         (the dataset's edge)",
        quality::crack_pixels(&ours, &reference, W, H)
    );
    assert_eq!(cracks, 0, "first frame: crack pixels");
    // The whole dataset inside the frame: sky all along the border.
    for x in 0..W {
        assert!(
            !terrain(&ours, x, 0) && !terrain(&ours, x, H - 1),
            "terrain at the border, column {x}"
        );
    }
    for y in 0..H {
        assert!(
            !terrain(&ours, 0, y) && !terrain(&ours, W - 1, y),
            "terrain at the border, row {y}"
        );
    }
    let area = (0..H)
        .flat_map(|y| (0..W).map(move |x| (x, y)))
        .filter(|&(x, y)| terrain(&ours, x, y))
        .count();
    assert!(
        area > (W * H / 10) as usize,
        "the dataset covers only {area} pixels"
    );
    let columns = quarter_columns(&ours);
    let bow = top_edge_bow(&ours, columns);
    let predicted = predicted_bow(&globe, &first, columns);

    // The same camera flat: the same edge is a straight line.
    let flat_world = world(&m, GlobeMode::Off);
    let mut flat = renderer(&m, flat_world);
    let mut sel = Selector::new(flat_world, SelectParams::default());
    let s = sel.select(&first, &m.tables);
    flat.draw(&first, &s.patches).unwrap();
    let flat_img = flat.read_rgba().unwrap();
    let flat_bow = top_edge_bow(&flat_img, quarter_columns(&flat_img));
    println!(
        "first frame: {area} terrain pixels, edge bow {bow:.1} px on the globe \
         (predicted {predicted:.1}), {flat_bow:.1} px flat"
    );
    assert!(flat_bow <= 1.0, "flat edge bows by {flat_bow} px");
    assert!(
        predicted >= 2.0,
        "the test cannot tell a curve: {predicted} px"
    );
    assert!(
        (bow - predicted).abs() <= 1.5,
        "globe edge bows by {bow} px, not {predicted}"
    );

    let (ours, reference) = ours_and_reference(&mut r, &m, &last);
    dump("last", &ours);
    dump("last_reference", &reference);
    let cracks = quality::crack_pixels(&ours, &reference, W, H);
    assert_eq!(cracks, 0, "last frame: crack pixels");
    for y in H / 2..H {
        for x in 0..W {
            assert!(
                terrain(&ours, x, y),
                "last frame: sky at ({x}, {y}) in the lower half"
            );
        }
    }
    let psnr = quality::psnr(quality::mse(&ours, &reference));
    println!("last frame: PSNR {psnr:.1} dB against the reference");
}

/// Horizon culling with the real dataset's globe: seen from 1000 km above the
/// dataset's centre, a box on the far side of the Moon (the antipode of the
/// dataset, in the same flat-world coordinates the selection uses) is culled and
/// one in the dataset is kept, whatever the frustum's direction.
#[test]
fn horizon_culling_drops_the_far_side_and_keeps_the_near_side() {
    let Some(m) = moon() else { return };
    let w = world(&m, GlobeMode::On);
    let g = w.globe.unwrap();
    let size = w.size_m();
    // Looking straight down from 1000 km with a very wide view, so that the
    // frustum alone would keep both.
    let cam = Camera {
        position: DVec3::new(size.x / 2.0, 1.0e6, size.y / 2.0),
        yaw: 0.0,
        pitch: -89.9f64.to_radians(),
        fovy: 170f64.to_radians(),
        width: W,
        height: H,
        near: 1.0,
        far: 1.0e8,
    };
    let frustum = w.frustum(&cam);
    let near = (
        DVec3::new(0.0, -6000.0, 0.0),
        DVec3::new(size.x, 4000.0, size.y),
    );
    assert!(frustum.intersects_box(near.0, near.1));
    // 180° of longitude east of the dataset, the same latitudes negated: the
    // antipode, in grid samples (1/256° each) east and south.
    let east = 180.0 * 256.0 * g.spacing.x;
    let south = (2.0 * 17.0 * 256.0) * g.spacing.y;
    let far = (
        DVec3::new(east, -6000.0, south),
        DVec3::new(
            east + 256.0 * g.spacing.x,
            4000.0,
            south + 256.0 * g.spacing.y,
        ),
    );
    assert!(
        !frustum.intersects_box(far.0, far.1),
        "the far side is drawn"
    );
}
