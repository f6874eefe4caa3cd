//! A multi-resolution pyramid (DECISIONS.md "Multi-resolution pyramids") flown by the
//! client and drawn with wgpu (lavapipe where there is no GPU): the three-input
//! collection of the mixed-grid tests (a 30″ base, a 3″ window of N46E008 and
//! aletsch.tif at 200 m) built with default flags, so deep tiles exist only where fine
//! data lies. Cameras over the 3″ window's edges see finest tiles beside tiles held
//! back because nothing finer is stored under them: the frames have no crack pixels,
//! the client refines to the finest level only over the window, over the window it
//! draws every finest tile the full pyramid's selection draws (the stored tiles form
//! a restricted quadtree, so balancing never coarsens fine data beside coarse), and
//! the same cameras over a `--full-pyramid` build refine the base's ground further (so
//! the absent tiles are what held it back).

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[path = "../../server/tests/gdal/mod.rs"]
mod gdal;

use gdal::fusion::Collection;
use glam::DVec3;
use std::collections::BTreeSet;
use std::sync::OnceLock;
use tessera_client::camera::Camera;
use tessera_client::render::gpu::Backend;
use tessera_client::render::{RenderOptions, Renderer, quality};
use tessera_client::select::{SelectParams, Selection, Selector, World};
use tessera_e2e::{Rng, StoredTiles};
use tessera_server::builder::{BuildOptions, build_inputs};
use tessera_server::ingest::InputSpec;
use tessera_shared::{FileSource, Pyramid, TileId};

const W: u32 = 640;
const H: u32 = 360;

/// One build of the collection, every stored tile decoded.
struct Built {
    pyramid: Pyramid<FileSource>,
    tiles: StoredTiles,
    world: World,
}

struct Fused {
    multi: Built,
    full: Built,
    /// The 3″ window's samples `[x0, y0, x1, y1)` on the mosaic's grid.
    window: [u64; 4],
    _dir: tempfile::TempDir,
}

fn fused() -> Option<&'static Fused> {
    static F: OnceLock<Option<Fused>> = OnceLock::new();
    F.get_or_init(|| {
        let c = Collection::new()?;
        let dir = tempfile::tempdir().unwrap();
        let inputs = InputSpec {
            args: [&c.base, &c.fine, &c.aletsch]
                .map(|p| p.to_str().unwrap().to_string())
                .to_vec(),
            list: None,
        };
        // Tiles of 64 cells: six levels over the 1857 × 1200 mosaic, so the base's
        // level (2) lies three below the 3″ window's (5).
        let built = |name: &str, full_pyramid: bool| {
            let out = dir.path().join(name);
            let opts = BuildOptions {
                tile_size: 64,
                full_pyramid,
                ..BuildOptions::default()
            };
            build_inputs(&inputs, &out, &opts).unwrap();
            let pyramid = Pyramid::open_file(&out).unwrap();
            let tiles = StoredTiles::read(&pyramid);
            let meta = pyramid.metadata();
            let world = World {
                geometry: *pyramid.geometry(),
                quant: meta.quantization,
                spacing: World::spacing_from(None, meta.ground_spacing),
                globe: None,
            };
            Built {
                pyramid,
                tiles,
                world,
            }
        };
        let (multi, full) = (built("multi.tess", false), built("full.tess", true));
        let gt = multi
            .pyramid
            .metadata()
            .georef
            .as_ref()
            .unwrap()
            .geotransform;
        Some(Fused {
            multi,
            full,
            window: Collection::fine_window_on(&gt),
            _dir: dir,
        })
    })
    .as_ref()
}

/// Cameras low over the 3″ window just inside its north and east edges, looking out
/// across the edge and down steeply enough that terrain fills the view (any sky
/// pixel is then a crack).
fn cameras(f: &Fused, count: usize) -> Vec<Camera> {
    let mut rng = Rng(5);
    let s = f.multi.world.spacing;
    let [x0, y0, x1, y1] = f.window.map(|v| v as f64);
    let meta = f.multi.pyramid.metadata();
    (0..count)
        .map(|i| {
            let along = 0.1 + 0.8 * rng.uniform();
            let inside = 10.0 + 30.0 * rng.uniform();
            // Yaw 0 looks north, π/2 east.
            let (x, y, yaw) = if i % 2 == 0 {
                (x0 + along * (x1 - x0), y0 + inside, 0.0)
            } else {
                (
                    x1 - inside,
                    y0 + along * (y1 - y0),
                    std::f64::consts::FRAC_PI_2,
                )
            };
            Camera {
                position: DVec3::new(
                    x * s.x,
                    meta.max_height + 1000.0 + 1000.0 * rng.uniform(),
                    y * s.y,
                ),
                yaw: yaw + (rng.uniform() - 0.5) * 0.6,
                pitch: -0.9 - 0.35 * rng.uniform(),
                fovy: 60f64.to_radians(),
                width: W,
                height: H,
                near: 1.0,
                far: 300_000.0,
            }
        })
        .collect()
}

fn params() -> SelectParams {
    SelectParams {
        morph_by_distance: true,
        ..SelectParams::default()
    }
}

fn selections(b: &Built, cams: &[Camera]) -> Vec<Selection> {
    let mut sel = Selector::new(b.world, params());
    cams.iter()
        .map(|c| sel.select(c, &b.tiles.tables))
        .collect()
}

/// Whether `tile`'s samples meet the window `[x0, y0, x1, y1)` widened by `margin`
/// samples.
fn meets(b: &Built, tile: TileId, window: [u64; 4], margin: u64) -> bool {
    let g = b.world.geometry;
    let span = u64::from(g.tile_size()) << (g.finest().get() - tile.level().get());
    let (tx, ty) = (u64::from(tile.x()) * span, u64::from(tile.y()) * span);
    let [x0, y0, x1, y1] = window;
    tx <= x1 + margin && tx + span + margin >= x0 && ty <= y1 + margin && ty + span + margin >= y0
}

/// Sky pixels of each camera's frame, drawn from `selections`.
fn sky(b: &Built, cams: &[Camera], selections: &[Selection], unsnapped: bool) -> Vec<usize> {
    let meta = b.pyramid.metadata();
    let mut r = Renderer::new(
        b.world,
        (meta.min_height, meta.max_height),
        RenderOptions {
            width: W,
            height: H,
            slots: b.tiles.tables.len() as u32 + 1,
            backend: Backend::Vulkan,
            ..RenderOptions::default()
        },
    )
    .unwrap();
    let pool = b.tiles.pool();
    let mut tiles: Vec<_> = b.tiles.tables.keys().copied().collect();
    tiles.sort_unstable();
    for t in tiles {
        assert!(r.upload(&pool, t), "no slot for {t}");
    }
    cams.iter()
        .zip(selections)
        .map(|(c, s)| {
            let mut patches = s.patches.clone();
            if unsnapped {
                for p in &mut patches {
                    p.edges = [p.inner; 4];
                }
            }
            let d = r.draw(c, &patches).unwrap();
            assert_eq!(d.skipped, 0);
            quality::sky_pixels(&r.read_rgba().unwrap())
        })
        .collect()
}

#[test]
fn the_client_flies_across_resolution_boundaries_without_cracks() {
    let Some(f) = fused() else { return };
    let cams = cameras(f, 10);
    let multi = selections(&f.multi, &cams);
    let full = selections(&f.full, &cams);
    let finest = f.multi.world.geometry.finest();

    // The frames hold the boundary the test is about: finest tiles over the window
    // (in every frame) beside tiles drawn where the full pyramid has children and this
    // one does not (in most: a view can end before the ring of balancing tiles does).
    let mut both = 0;
    for (i, s) in multi.iter().enumerate() {
        let finest_drawn = s.tiles.iter().filter(|t| t.level() == finest).count();
        let held_back = s
            .tiles
            .iter()
            .filter(|t| {
                t.children().is_some_and(|c| {
                    c.iter().any(|c| f.full.tiles.tables.contains_key(c))
                        && !c.iter().any(|c| f.multi.tiles.tables.contains_key(c))
                })
            })
            .count();
        assert!(finest_drawn > 0, "frame {i}: no finest tile drawn");
        both += usize::from(held_back > 0);
        // Fine data beside coarse is drawn as the full pyramid draws it: the stored
        // tiles form a restricted quadtree, so balancing never coarsens the window.
        let full_fine: BTreeSet<TileId> = full[i]
            .tiles
            .iter()
            .copied()
            .filter(|t| t.level() == finest && meets(&f.full, *t, f.window, 0))
            .collect();
        let multi_fine: BTreeSet<TileId> = s.tiles.iter().copied().collect();
        let coarsened: Vec<_> = full_fine.difference(&multi_fine).collect();
        assert!(
            coarsened.is_empty(),
            "frame {i}: finest tiles over the window drawn coarser: {coarsened:?}"
        );
    }
    assert!(
        both >= 8,
        "{both} of 10 frames hold finest tiles beside tiles held back by absent children"
    );
    let levels: BTreeSet<u8> = multi
        .iter()
        .flat_map(|s| s.tiles.iter().map(|t| t.level().get()))
        .collect();
    assert!(levels.len() >= 3, "levels drawn: {levels:?}");

    // Refined to the finest level only where 3″ data lies: a finest tile's parent
    // meets the window (siblings are stored together).
    for s in &multi {
        for t in s.tiles.iter().filter(|t| t.level() == finest) {
            assert!(
                meets(&f.multi, t.parent().unwrap(), f.window, 0),
                "{t} drawn at the finest level away from the 3″ window"
            );
        }
    }
    // The same cameras over the full pyramid draw finest tiles far from the window:
    // what held the multi-resolution frames back is the absent tiles, not the view.
    let far_fine: usize = full
        .iter()
        .map(|s| {
            s.tiles
                .iter()
                .filter(|t| t.level() == finest && !meets(&f.full, **t, f.window, 128))
                .count()
        })
        .sum();
    assert!(
        far_fine > 0,
        "the full pyramid never refined away from the window"
    );

    let crack_pixels = sky(&f.multi, &cams, &multi, false);
    assert_eq!(
        crack_pixels,
        vec![0; cams.len()],
        "sky (crack) pixels per frame"
    );
    // The same frames without edge snapping do crack: the test can see cracks.
    let broken = sky(&f.multi, &cams, &multi, true);
    assert!(
        broken.iter().sum::<usize>() > 0,
        "no cracks without snapping: {broken:?}"
    );
}
