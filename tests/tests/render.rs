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
use tessera_client::render::{RenderOptions, Renderer, quality};
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

/// Oblique cameras low over the terrain, looking down steeply enough that terrain
/// fills the whole view (any sky pixel is then a crack).
fn cameras(m: &Moon, count: usize) -> Vec<Camera> {
    let mut rng = Rng(7);
    let extent = f64::from(m.world.geometry.width()) * m.world.spacing;
    let meta = m.pyramid.metadata();
    (0..count)
        .map(|_| Camera {
            position: DVec3::new(
                (0.3 + 0.4 * rng.uniform()) * extent,
                meta.max_height + 500.0 + 8000.0 * rng.uniform(),
                (0.3 + 0.4 * rng.uniform()) * extent,
            ),
            yaw: rng.uniform() * std::f64::consts::TAU,
            pitch: -0.75 - 0.5 * rng.uniform(),
            fovy: 60f64.to_radians(),
            width: W,
            height: H,
            near: 1.0,
            far: 2.0 * extent,
        })
        .collect()
}

/// Every (inner LOD, edge LOD) combination on every side, on tiles of every level.
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
                let size = if rng.uniform() < 0.5 { 64 } else { g.tile_size() };
                let per_side = g.tile_size() / size;
                let origin = [
                    (rng.uniform() * f64::from(per_side)) as u32 * size,
                    (rng.uniform() * f64::from(per_side)) as u32 * size,
                ];
                // The other three edges at random LODs ≤ n.
                let mut edges = [0; 4].map(|_| 1 << (rng.uniform() * f64::from(k + 1)) as u32);
                edges[side] = e;
                patches.push(Patch {
                    tile,
                    origin,
                    size,
                    inner: n,
                    edges,
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
    let mut vertices = 0;
    for (p, got) in patches.iter().zip(&captured) {
        let expected = tessellate::vertices(&m.world.geometry, p, &m.heights[&p.tile]);
        assert_eq!(got, &expected, "{backend:?}: patch {p:?}");
        vertices += got.len();
    }
    assert!(vertices > 20_000, "{vertices}");
}

#[test]
fn shader_vertices_equal_the_reference_tessellator_vulkan() {
    check_capture(Backend::Vulkan);
}

#[test]
fn shader_vertices_equal_the_reference_tessellator_gl() {
    check_capture(Backend::Gl);
}

/// Renders each camera's selection; returns the frames' sky-pixel counts.
fn render_frames(r: &mut Renderer, m: &Moon, cams: &[Camera], unsnapped: bool) -> Vec<usize> {
    let mut sel = Selector::new(m.world, SelectParams::default());
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
fn frames_have_no_cracks_across_lods_tiles_and_levels() {
    let Some(m) = moon() else { return };
    let mut r = renderer(m, Backend::Vulkan);
    let cams = cameras(m, 10);
    // The cameras straddle what the test is about: snapped edges, several levels.
    let mut sel = Selector::new(m.world, SelectParams::default());
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
    assert!(levels.len() >= 3, "levels drawn: {levels:?}");
    let sky = render_frames(&mut r, m, &cams, false);
    assert_eq!(sky, vec![0; cams.len()], "sky (crack) pixels per frame");
    // The same frames without edge snapping do crack: the test can see cracks.
    let broken = render_frames(&mut r, m, &cams, true);
    assert!(
        broken.iter().sum::<usize>() > 0,
        "no cracks without snapping: {broken:?}"
    );
}
