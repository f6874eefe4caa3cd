//! The wgpu renderer on a real DEM, headless (lavapipe where there is no GPU):
//! the shader's vertices against the reference tessellator, crack-free frames,
//! at most 7 terrain draws, and Vulkan against GL.
//!
//! Scenes stay small (≤ 0.5 M triangles, 640×360): lavapipe costs ~0.1 s per
//! million triangles.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

use glam::DVec3;
use std::sync::OnceLock;
use tessera_client::camera::Camera;
use tessera_client::render::gpu::Backend;
use tessera_client::render::{RenderOptions, Renderer, quality, reference};
use tessera_client::select::morph::{self, Morph};
use tessera_client::select::{Patch, SelectParams, Selector};
use tessera_client::tessellate;
use tessera_e2e::{Moon, Rng};

fn moon() -> Option<&'static Moon> {
    static F: OnceLock<Option<Moon>> = OnceLock::new();
    F.get_or_init(|| Moon::build(128)).as_ref()
}

const W: u32 = 640;
const H: u32 = 360;

/// A renderer with every tile of the moon uploaded.
fn renderer(m: &Moon, backend: Backend) -> Renderer {
    let meta = m.pyramid.metadata();
    let mut r = Renderer::new(
        m.world,
        (meta.min_height, meta.max_height),
        RenderOptions {
            width: W,
            height: H,
            slots: m.tables.len() as u32 + 1,
            backend,
            ..RenderOptions::default()
        },
    )
    .unwrap();
    let pool = m.pool();
    let mut tiles: Vec<_> = m.tables.keys().copied().collect();
    tiles.sort_unstable();
    for t in tiles {
        assert!(r.upload(&pool, t), "no slot for {t}");
    }
    r
}

/// Random cameras over the middle of the moon: `(low, span)` ranges for the
/// position (fraction of the extent), the altitude above the highest ground (m) and
/// the pitch below the horizon (radians).
fn random_cameras(
    m: &Moon,
    seed: u64,
    count: usize,
    spread: (f64, f64),
    altitude: (f64, f64),
    pitch: (f64, f64),
) -> Vec<Camera> {
    let mut rng = Rng(seed);
    let extent = f64::from(m.world.geometry.width()) * m.world.spacing.x;
    let meta = m.pyramid.metadata();
    (0..count)
        .map(|_| Camera {
            position: DVec3::new(
                (spread.0 + spread.1 * rng.uniform()) * extent,
                meta.max_height + altitude.0 + altitude.1 * rng.uniform(),
                (spread.0 + spread.1 * rng.uniform()) * extent,
            ),
            yaw: rng.uniform() * std::f64::consts::TAU,
            pitch: -pitch.0 - pitch.1 * rng.uniform(),
            fovy: 60f64.to_radians(),
            width: W,
            height: H,
            near: 1.0,
            far: 2.0 * extent,
        })
        .collect()
}

/// Oblique cameras low over the terrain, looking down steeply enough that terrain
/// fills the whole view (any sky pixel is then a crack).
fn cameras(m: &Moon, count: usize) -> Vec<Camera> {
    random_cameras(m, 7, count, (0.3, 0.4), (500.0, 8000.0), (0.75, 0.5))
}

/// Every (inner LOD, edge LOD) combination on every side, on tiles of every level,
/// at morph factors from none through in-between to full (geomorphing).
fn all_edge_combinations(m: &Moon) -> Vec<Patch> {
    let g = m.world.geometry;
    let mut tiles: Vec<_> = m.tables.keys().copied().collect();
    tiles.sort_unstable();
    let mut rng = Rng(11);
    let mut patches = Vec::new();
    for k in 0..7u32 {
        let n = 1 << k;
        for side in 0..4 {
            for e in (0..=k).map(|j| 1u32 << j) {
                let tile = tiles[(rng.uniform() * tiles.len() as f64) as usize];
                // Patches of 64 or 128 cells at any aligned origin inside the tile.
                let size = if rng.uniform() < 0.5 {
                    64
                } else {
                    g.tile_size()
                };
                let per_side = g.tile_size() / size;
                let origin = [
                    (rng.uniform() * f64::from(per_side)) as u32 * size,
                    (rng.uniform() * f64::from(per_side)) as u32 * size,
                ];
                // The other three edges at random LODs ≤ n.
                let mut edges = [0; 4].map(|_| 1 << (rng.uniform() * f64::from(k + 1)) as u32);
                edges[side] = e;
                let mut factor = || match (rng.uniform() * 4.0) as u32 {
                    0 => 0,
                    1 => morph::FULL,
                    _ => (rng.uniform() * f64::from(morph::FULL)) as u16,
                };
                let morph = Morph::new(factor(), [0; 4].map(|_| factor())).unwrap();
                patches.push(Patch {
                    tile,
                    origin,
                    size,
                    inner: n,
                    edges,
                    morph,
                    fade: tessera_client::select::fade::Fade::NONE,
                });
            }
        }
    }
    patches
}

fn check_capture(backend: Backend) {
    let Some(m) = moon() else { return };
    let r = renderer(m, backend);
    let patches = all_edge_combinations(m);
    let captured = r.capture_vertices(&patches).unwrap();
    let (mut vertices, mut moved) = (0, 0);
    for (p, got) in patches.iter().zip(&captured) {
        let expected = tessellate::vertices(&m.world.geometry, p, &m.heights[&p.tile]);
        assert_eq!(got, &expected, "{backend:?}: patch {p:?}");
        vertices += got.len();
        moved += got
            .iter()
            .filter(|v| v.h != u32::from(v.q) * morph::HEIGHT_UNITS)
            .count();
    }
    assert!(vertices > 20_000, "{vertices}");
    assert!(moved > 2_000, "only {moved} morphed vertices");
}

#[test]
fn shader_vertices_equal_the_reference_tessellator_vulkan() {
    check_capture(Backend::Vulkan);
}

#[test]
fn shader_vertices_equal_the_reference_tessellator_gl() {
    check_capture(Backend::Gl);
}

/// Renders each camera's selection (with `params`); returns the frames' sky-pixel
/// counts.
fn render_frames(
    r: &mut Renderer,
    m: &Moon,
    params: SelectParams,
    cams: &[Camera],
    unsnapped: bool,
) -> Vec<usize> {
    let mut sel = Selector::new(m.world, params);
    cams.iter()
        .map(|c| {
            let mut s = sel.select(c, &m.tables);
            if unsnapped {
                for p in &mut s.patches {
                    p.edges = [p.inner; 4];
                }
            }
            assert!(
                s.stats.triangles <= 500_000,
                "{} triangles",
                s.stats.triangles
            );
            let d = r.draw(c, &s.patches).unwrap();
            assert_eq!(d.skipped, 0);
            assert!(d.draw_calls <= 7, "{} draw calls", d.draw_calls);
            quality::sky_pixels(&r.read_rgba().unwrap())
        })
        .collect()
}

#[test]
fn frames_have_no_cracks_across_lods_tiles_and_levels_vulkan() {
    check_cracks(Backend::Vulkan);
}

#[test]
fn frames_have_no_cracks_across_lods_tiles_and_levels_gl() {
    check_cracks(Backend::Gl);
}

#[test]
fn an_impossible_viewport_is_an_error_not_a_panic() {
    let Some(m) = moon() else { return };
    let opts = RenderOptions {
        width: 1 << 20,
        height: 16,
        backend: Backend::Vulkan,
        ..RenderOptions::default()
    };
    let e = Renderer::new(m.world, (0.0, 1.0), opts).unwrap_err();
    assert!(format!("{e:#}").contains("exceeds this GPU's"), "{e:#}");
}

fn check_cracks(backend: Backend) {
    let Some(m) = moon() else { return };
    let mut r = renderer(m, backend);
    let cams = cameras(m, 10);
    // The cameras straddle what the test is about: snapped edges, several levels.
    // With the distance band (opt-in), selection slides patches part way without
    // a clock, so the frames hold morphed patches and sides too.
    let params = SelectParams {
        morph_by_distance: true,
        ..SelectParams::default()
    };
    let mut sel = Selector::new(m.world, params);
    let (mut snapped, mut levels) = (0, std::collections::BTreeSet::new());
    for c in &cams {
        let s = sel.select(c, &m.tables);
        snapped += s
            .patches
            .iter()
            .flat_map(|p| p.edges.iter().map(move |&e| e < p.inner))
            .filter(|&x| x)
            .count();
        levels.extend(s.tiles.iter().map(|t| t.level().get()));
    }
    assert!(snapped > 20, "only {snapped} snapped edges");
    // And morphing has slid patches and shared sides part way.
    let (mut inner, mut sides) = (0, 0);
    for c in &cams {
        for p in sel.select(c, &m.tables).patches {
            inner += usize::from(p.morph.inner > 0 && p.morph.inner < morph::FULL);
            sides += p.morph.edges.iter().filter(|&&f| f > 0).count();
        }
    }
    assert!(
        inner > 20 && sides > 20,
        "morphed: {inner} patches, {sides} sides"
    );
    assert!(levels.len() >= 3, "levels drawn: {levels:?}");
    let sky = render_frames(&mut r, m, params, &cams, false);
    assert_eq!(sky, vec![0; cams.len()], "sky (crack) pixels per frame");
    // The same frames without edge snapping do crack: the test can see cracks.
    let broken = render_frames(&mut r, m, params, &cams, true);
    assert!(
        broken.iter().sum::<usize>() > 0,
        "no cracks without snapping: {broken:?}"
    );
}

/// Renders `cam` at `tau` and the full-resolution reference; returns
/// `(ours, reference, our triangles, reference triangles)`.
fn ours_and_reference(
    r: &mut Renderer,
    m: &Moon,
    cam: &Camera,
    tau: f64,
) -> (Vec<u8>, Vec<u8>, u64, u64) {
    let mut sel = Selector::new(
        m.world,
        SelectParams {
            tau,
            ..SelectParams::default()
        },
    );
    let s = sel.select(cam, &m.tables);
    r.draw(cam, &s.patches).unwrap();
    let ours = r.read_rgba().unwrap();
    let meta = m.pyramid.metadata();
    let tiles = reference::finest_tiles_in_view(
        &m.world,
        &cam.frustum(),
        (meta.min_height, meta.max_height),
    );
    let patches = reference::full_resolution_patches(&m.world, &tiles, &m.tables, &cam.frustum());
    let ref_tris: u64 = patches.iter().map(Patch::triangles).sum();
    assert!(ref_tris <= 600_000, "reference has {ref_tris} triangles");
    r.draw(cam, &patches).unwrap();
    (ours, r.read_rgba().unwrap(), s.stats.triangles, ref_tris)
}

/// Cameras looking steeply down from a few kilometres, so that the reference
/// (every sample a vertex) stays small.
fn close_cameras(m: &Moon, count: usize) -> Vec<Camera> {
    random_cameras(m, 23, count, (0.2, 0.6), (9000.0, 6000.0), (1.0, 0.3))
}

/// Against the full-resolution reference at τ = 1 px. Every drawn vertex is a
/// DEM sample and the mesh is within τ of the finest surface on screen, so the
/// images differ only by sub-pixel geometry and by shading from coarser levels'
/// normal maps: we require PSNR ≥ 40 dB (RMS error under 2.6 of 255; we measure
/// 51–54 dB), no crack
/// pixels, and at most a quarter of the reference's triangles. A coarser τ must
/// be measurably worse, so the comparison can tell quality apart.
#[test]
fn close_to_the_full_resolution_reference_with_far_fewer_triangles() {
    let Some(m) = moon() else { return };
    let mut r = renderer(m, Backend::Vulkan);
    for (k, cam) in close_cameras(m, 4).iter().enumerate() {
        let (ours, reference, tris, ref_tris) = ours_and_reference(&mut r, m, cam, 1.0);
        let mse = quality::mse(&ours, &reference);
        let psnr = quality::psnr(mse);
        let cracks = quality::crack_pixels(&ours, &reference, W, H);
        println!("camera {k}: τ=1 PSNR {psnr:.2} dB, MSE {mse:.2}, {tris} vs {ref_tris} triangles");
        assert_eq!(cracks, 0, "camera {k}");
        assert!(psnr >= 40.0, "camera {k}: PSNR {psnr:.2} dB");
        assert!(
            tris * 4 <= ref_tris,
            "camera {k}: {tris} vs {ref_tris} triangles"
        );
        let (coarse, _, coarse_tris, _) = ours_and_reference(&mut r, m, cam, 16.0);
        let coarse_mse = quality::mse(&coarse, &reference);
        println!("camera {k}: τ=16 MSE {coarse_mse:.2}, {coarse_tris} triangles");
        assert!(
            coarse_mse > mse,
            "camera {k}: τ=16 MSE {coarse_mse} ≤ τ=1 MSE {mse}"
        );
    }
}

/// The GL backend draws the same frames as Vulkan: both are llvmpipe here, but
/// through different shader translations (SPIR-V vs GLSL), so rasterization and
/// float rounding may differ by a little. Tolerance: mean absolute difference
/// ≤ 0.5 (of 255) and under 0.5 % of pixels differing by more than 16.
#[test]
fn gl_renders_what_vulkan_renders() {
    let Some(m) = moon() else { return };
    let mut vk = renderer(m, Backend::Vulkan);
    let mut gl = renderer(m, Backend::Gl);
    let mut sel = Selector::new(m.world, SelectParams::default());
    for (k, cam) in cameras(m, 3).iter().enumerate() {
        let s = sel.select(cam, &m.tables);
        let dv = vk.draw(cam, &s.patches).unwrap();
        let dg = gl.draw(cam, &s.patches).unwrap();
        assert_eq!(dv.draw_calls, dg.draw_calls);
        let (a, b) = (vk.read_rgba().unwrap(), gl.read_rgba().unwrap());
        let mad = quality::mean_abs_diff(&a, &b);
        let far = a
            .chunks_exact(4)
            .zip(b.chunks_exact(4))
            .filter(|(p, q)| (0..3).any(|c| p[c].abs_diff(q[c]) > 16))
            .count();
        println!("camera {k}: mean abs diff {mad:.3}, {far} pixels off by > 16");
        assert_eq!(quality::sky_pixels(&b), 0, "camera {k}: GL frame has holes");
        assert!(mad <= 0.5, "camera {k}: mean abs diff {mad}");
        assert!(
            far * 200 < (W * H) as usize,
            "camera {k}: {far} pixels differ by > 16"
        );
    }
}

/// Golden image: the synthetic terrain (generated here, so the test runs on any
/// clone) from a fixed camera, in the shaded view with the wireframe over it.
/// Tolerance: mean absolute difference ≤ 1.0 (of 255) and under 1 % of pixels
/// off by more than 24 — enough for another rasterizer's rounding, not for a
/// moved patch or a changed colour. On failure the actual and difference images
/// are written to `target/golden/`. `TESSERA_BLESS=1` rewrites the golden image.
#[test]
fn golden_image_of_the_synthetic_terrain() {
    use tessera_client::render::{DebugView, png_out};
    use tessera_server::builder::{BuildOptions, build};
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("synthetic.tess");
    build("synthetic:1025:7", &file, &BuildOptions::default()).unwrap();
    let p = tessera_shared::Pyramid::open_file(&file).unwrap();
    let g = *p.geometry();
    let meta = p.metadata().clone();
    let world = tessera_client::select::World {
        geometry: g,
        quant: meta.quantization,
        spacing: glam::DVec2::splat(30.0),
        globe: None,
    };
    let mut pool = tessera_client::stream::pool::TilePool::new(64);
    let mut tables = std::collections::HashMap::new();
    for level in g.levels() {
        for tile in g.present_tiles(level) {
            let rec = p.read_tile(tile).unwrap().unwrap();
            tables.insert(tile, rec.errors.clone());
            pool.insert(tile, rec.errors, rec.heights, rec.mask);
        }
    }
    let (w, h) = (480, 270);
    let mut r = Renderer::new(
        world,
        (meta.min_height, meta.max_height),
        RenderOptions {
            width: w,
            height: h,
            slots: 8,
            view: DebugView::Wireframe,
            backend: Backend::Vulkan,
            ..RenderOptions::default()
        },
    )
    .unwrap();
    for &t in tables.keys() {
        assert!(r.upload(&pool, t));
    }
    let extent = 1024.0 * world.spacing.x;
    let cam = Camera {
        position: DVec3::new(0.15 * extent, meta.max_height + 2500.0, 0.9 * extent),
        yaw: 40f64.to_radians(),
        pitch: -0.35,
        fovy: 60f64.to_radians(),
        width: w,
        height: h,
        near: 1.0,
        far: 4.0 * extent,
    };
    // τ = 8 px keeps the triangles large enough to see in the wireframe.
    let params = SelectParams {
        tau: 8.0,
        ..SelectParams::default()
    };
    let s = Selector::new(world, params).select(&cam, &tables);
    r.draw(&cam, &s.patches).unwrap();
    let mut actual = r.read_rgba().unwrap();
    quality::paint_sky(&mut actual, w, h);
    let golden =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("golden/synthetic_wireframe.png");
    if std::env::var_os("TESSERA_BLESS").is_some() {
        png_out::write_png(&golden, &actual, w, h).unwrap();
        return;
    }
    let (expected, gw, gh) = png_out::read_png(&golden).unwrap();
    assert_eq!((gw, gh), (w, h));
    let mad = quality::mean_abs_diff(&actual, &expected);
    let far = actual
        .chunks_exact(4)
        .zip(expected.chunks_exact(4))
        .filter(|(p, q)| (0..3).any(|c| p[c].abs_diff(q[c]) > 24))
        .count();
    if mad > 1.0 || far * 100 >= (w * h) as usize {
        let out = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/golden");
        std::fs::create_dir_all(&out).unwrap();
        png_out::write_png(&out.join("synthetic_wireframe.actual.png"), &actual, w, h).unwrap();
        let diff = quality::difference_image(&actual, &expected);
        png_out::write_png(&out.join("synthetic_wireframe.diff.png"), &diff, w, h).unwrap();
        panic!(
            "golden image differs: mean abs diff {mad:.3}, {far} pixels off by > 24; see {}",
            out.display()
        );
    }
}

/// Mean absolute per-pixel change (|ΔR| + |ΔG| + |ΔB| over 3, 0–255).
fn mean_change(a: &[u8], b: &[u8]) -> f64 {
    let sum: u64 = a
        .chunks_exact(4)
        .zip(b.chunks_exact(4))
        .map(|(p, q)| (0..3).map(|c| u64::from(p[c].abs_diff(q[c]))).sum::<u64>())
        .sum();
    sum as f64 / (a.len() / 4) as f64 / 3.0
}

/// A tile refinement fades in (`select/fade.rs`): a level-3 tile drawn at inner
/// LOD 64, and its four children each at 32 (the same vertices, the pyramid
/// decimates), seen straight down. Geometry alike, the children differ from the
/// parent only by shading (their finer normal maps and heights): with a fade
/// factor of 1 from the parent they must look as the parent did, at ½ halfway
/// between, at 0 as themselves. A wrong place in the parent (offset, scale or
/// slot) would shade them as some other ground.
#[test]
fn a_refined_tile_fades_in_from_its_parents_shading() {
    use tessera_client::select::fade::Fade;
    use tessera_shared::{Level, TileId};
    let Some(m) = moon() else { return };
    let mut r = renderer(m, Backend::Vulkan);
    let g = m.world.geometry;
    let parent = TileId::new(Level::new(3).unwrap(), 3, 4).unwrap();
    let whole = |tile, inner, fade| Patch {
        tile,
        origin: [0, 0],
        size: g.tile_size(),
        inner,
        edges: [inner; 4],
        morph: Morph::NONE,
        fade,
    };
    let (x, y) = g.origin(parent);
    let side = f64::from(g.tile_size()) * g.spacing(parent.level()) as f64;
    let centre = |o: u64, s: f64| (o as f64 + side / 2.0) * s;
    let cam = Camera {
        position: DVec3::new(
            centre(x, m.world.spacing.x),
            m.pyramid.metadata().max_height + 0.4 * side * m.world.spacing.x,
            centre(y, m.world.spacing.y),
        ),
        yaw: 0.0,
        pitch: -1.5,
        fovy: 60f64.to_radians(),
        width: W,
        height: H,
        near: 1.0,
        far: 10.0 * side * m.world.spacing.x,
    };
    let mut draw = |patches: &[Patch]| {
        let d = r.draw(&cam, patches).unwrap();
        assert_eq!(d.skipped, 0);
        r.read_rgba().unwrap()
    };
    let before = draw(&[whole(parent, 64, Fade::NONE)]);
    let children = |fade| parent.children().unwrap().map(|c| whole(c, 32, fade));
    let own = draw(&children(Fade::NONE));
    let start = draw(&children(Fade::new(1, morph::FULL).unwrap()));
    let half = draw(&children(Fade::new(1, morph::FULL / 2).unwrap()));
    let pop = mean_change(&before, &own);
    let (at_start, half_to_before, half_to_own) = (
        mean_change(&before, &start),
        mean_change(&before, &half),
        mean_change(&own, &half),
    );
    println!(
        "children vs parent {pop:.3}; faded in at 1 {at_start:.4}; at ½ to the parent \
         {half_to_before:.3}, to the children {half_to_own:.3}"
    );
    // The refinement does change the shading (what the fade is for) …
    assert!(pop > 0.2, "children vs parent {pop}");
    // … the fade's start is the parent's (rounding only), and halfway is halfway.
    assert!(at_start < pop / 20.0, "{at_start} vs {pop}");
    for d in [half_to_before, half_to_own] {
        assert!(d > pop * 0.4 && d < pop * 0.6, "{d} vs {pop}");
    }
}

/// Mean colour (R, G, B) of an RGBA8 image.
fn mean_colour(rgba: &[u8]) -> [f64; 3] {
    let n = (rgba.len() / 4).max(1) as f64;
    let mut sum = [0f64; 3];
    for p in rgba.chunks_exact(4) {
        for c in 0..3 {
            sum[c] += f64::from(p[c]);
        }
    }
    sum.map(|s| s / n)
}

/// Haze follows the air the view crosses, not the distance alone
/// (`terrain.wgsl` `haze_amount`): the same patch of ground, framed alike from
/// 0.2 and from 2 extents above it, looks the same, because the air above a few
/// scale heights is thin. Haze by distance alone would hide 18 % of the near view
/// and 86 % of the far one, moving the far view's mean colour by ~0.7 of its
/// distance to the haze colour (tens of levels of 255); the air-mass model
/// predicts under 2 % of it. Tolerance: the mean colours differ by ≤ 4 of 255 in
/// each channel, which leaves room for the coarser levels' shading far away. And
/// along the ground it still hazes: a low, level view is hazier at its far edge.
#[test]
fn haze_follows_the_air_crossed_not_the_distance() {
    let Some(m) = moon() else { return };
    let mut r = renderer(m, Backend::Vulkan);
    let meta = m.pyramid.metadata();
    let extent = f64::from(m.world.geometry.width()) * m.world.spacing.x;
    let ground = 0.5 * (meta.min_height + meta.max_height);
    let target = DVec3::new(0.5 * extent, ground, 0.5 * extent);
    let half_width = 0.05 * extent;
    let mut view_from = |distance: f64| {
        let mut cam = Camera {
            position: DVec3::ZERO,
            yaw: 0.3,
            pitch: -1.45,
            fovy: 2.0 * (half_width / distance).atan(),
            width: W,
            height: H,
            near: 0.01 * distance,
            far: 2.0 * distance,
        };
        cam.position = target - cam.forward() * distance;
        let s = Selector::new(m.world, SelectParams::default()).select(&cam, &m.tables);
        r.draw(&cam, &s.patches).unwrap();
        let rgba = r.read_rgba().unwrap();
        assert_eq!(quality::sky_pixels(&rgba), 0, "the ground fills the view");
        mean_colour(&rgba)
    };
    let near = view_from(0.2 * extent);
    let far = view_from(2.0 * extent);
    for c in 0..3 {
        assert!(
            (near[c] - far[c]).abs() <= 4.0,
            "channel {c}: {:.1} from 0.2 extents against {:.1} from 2 extents",
            near[c],
            far[c]
        );
    }

    // Low over the ground, looking level and a little down: the far rows (top) are
    // closer to the haze colour than the near rows (bottom).
    let cam = Camera {
        position: DVec3::new(0.1 * extent, meta.max_height + 200.0, 0.9 * extent),
        yaw: 45f64.to_radians(),
        pitch: -0.12,
        fovy: 60f64.to_radians(),
        width: W,
        height: H,
        near: 1.0,
        far: 4.0 * extent,
    };
    let s = Selector::new(m.world, SelectParams::default()).select(&cam, &m.tables);
    r.draw(&cam, &s.patches).unwrap();
    let rgba = r.read_rgba().unwrap();
    let row_bytes = (W * 4) as usize;
    let haze = tessera_client::render::HAZE_COLOUR.map(|c| f64::from(c) * 255.0);
    // Mean distance of a band of rows' terrain colour from the haze colour.
    let band = |rows: std::ops::Range<usize>| {
        let px: Vec<u8> = rgba[rows.start * row_bytes..rows.end * row_bytes]
            .chunks_exact(4)
            .filter(|p| !quality::is_sky(p))
            .flatten()
            .copied()
            .collect();
        assert!(px.len() > row_bytes, "terrain in rows {rows:?}");
        let c = mean_colour(&px);
        (0..3).map(|i| (c[i] - haze[i]).abs()).sum::<f64>() / 3.0
    };
    let h = H as usize;
    let (far_rows, near_rows) = (band(h / 4..h / 2), band(h - h / 8..h));
    assert!(
        far_rows + 10.0 < near_rows,
        "the far rows ({far_rows:.1} from the haze colour) should be hazier than the near ones ({near_rows:.1})"
    );
}
