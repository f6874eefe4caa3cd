//! Normal maps computed on the GPU (a compute pass over the uploaded heights, on
//! lavapipe where there is no GPU) against the CPU reference
//! (`render::normals::normal_map`) on real moon tiles: inside tiles, on borders
//! with and without resident neighbours, and a shared border whichever of its two
//! tiles arrived first.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

use std::collections::HashMap;
use std::sync::OnceLock;
use tessera_client::render::gpu::Backend;
use tessera_client::render::normals::{self, NormalSource};
use tessera_client::render::{RenderOptions, Renderer};
use tessera_client::stream::pool::TilePool;
use tessera_e2e::Moon;
use tessera_shared::{Level, TileId};

fn moon() -> Option<&'static Moon> {
    static F: OnceLock<Option<Moon>> = OnceLock::new();
    F.get_or_init(|| Moon::build(128)).as_ref()
}

fn renderer(m: &Moon, normals: NormalSource) -> Renderer {
    let meta = m.pyramid.metadata();
    Renderer::new(
        m.world,
        (meta.min_height, meta.max_height),
        RenderOptions {
            width: 64,
            height: 64,
            slots: 40,
            backend: Backend::Vulkan,
            normals,
            ..RenderOptions::default()
        },
    )
    .unwrap()
}

/// The level whose tiles form a 4 × 4 grid (every tile has neighbours on some
/// sides, the middle ones on all four).
fn grid_level(m: &Moon) -> Level {
    let mut counts: HashMap<Level, usize> = HashMap::new();
    for t in m.tables.keys() {
        *counts.entry(t.level()).or_default() += 1;
    }
    *counts
        .iter()
        .find(|&(_, &c)| c == 16)
        .expect("a level of 4 × 4 tiles")
        .0
}

fn tile(level: Level, x: u32, y: u32) -> TileId {
    TileId::new(level, x, y).unwrap()
}

/// The CPU reference for `t` with the neighbours in `resident` (same level).
fn reference(m: &Moon, t: TileId, resident: &[TileId]) -> Vec<[i8; 2]> {
    let side = |dx: i64, dy: i64| {
        let n = TileId::new(
            t.level(),
            u32::try_from(i64::from(t.x()) + dx).ok()?,
            u32::try_from(i64::from(t.y()) + dy).ok()?,
        )?;
        resident.contains(&n).then(|| m.heights[&n].as_slice())
    };
    let g = m.world.geometry;
    normals::normal_map(
        &m.heights[&t],
        g.tile_samples(),
        &[side(0, -1), side(1, 0), side(0, 1), side(-1, 0)],
        m.world.spacing * g.spacing(t.level()) as f64,
        m.world.quant.scale,
    )
}

/// Samples where `got` and `want` differ by more than 1 in a component, as
/// `(u, v, got, want)`, at most 5.
fn mismatches(
    n: usize,
    got: &[[i8; 2]],
    want: &[[i8; 2]],
) -> Vec<(usize, usize, [i8; 2], [i8; 2])> {
    assert_eq!(got.len(), want.len());
    got.iter()
        .zip(want)
        .enumerate()
        .filter(|(_, (a, b))| (0..2).any(|c| (i16::from(a[c]) - i16::from(b[c])).abs() > 1))
        .map(|(i, (a, b))| (i % n, i / n, *a, *b))
        .take(5)
        .collect()
}

/// A pool holding `tiles` only.
fn pool(m: &Moon, tiles: &[TileId]) -> TilePool {
    let mut pool = TilePool::new(tiles.len() + 1);
    for &t in tiles {
        pool.insert(
            t,
            m.tables[&t].clone(),
            m.heights[&t].clone(),
            m.masks[&t].clone(),
        );
    }
    pool
}

fn read(r: &mut Renderer, t: TileId) -> Vec<[i8; 2]> {
    let slot = r.slots.get(t).unwrap();
    r.read_normals(slot).unwrap()
}

#[test]
fn gpu_normal_maps_match_the_cpu_reference_with_and_without_neighbours() {
    let Some(m) = moon() else { return };
    let n = m.world.geometry.tile_samples();
    let level = grid_level(m);
    let all: Vec<TileId> = (0..4)
        .flat_map(|y| (0..4).map(move |x| tile(level, x, y)))
        .collect();
    let pool = pool(m, &all);
    let mut r = renderer(m, NormalSource::Gpu);
    assert!(r.normals_on_gpu(), "lavapipe has compute shaders");

    // A tile alone: one-sided differences on all four borders.
    let middle = tile(level, 1, 2);
    assert!(r.upload(&pool, middle));
    let alone = read(&mut r, middle);
    let bad = mismatches(n, &alone, &reference(m, middle, &[]));
    assert!(bad.is_empty(), "alone: (u, v, gpu, cpu) {bad:?}");
    // The reference with neighbours differs on the border (so the check above
    // would have seen neighbours wrongly taken in).
    let surrounded = reference(m, middle, &all);
    assert!(!mismatches(n, &alone, &surrounded).is_empty());

    // Every tile of the level, in one batch: each border either has a neighbour
    // (corner and edge tiles lack some) or is one-sided.
    for &t in &all {
        assert!(r.upload(&pool, t));
    }
    for &t in &all {
        let bad = mismatches(n, &read(&mut r, t), &reference(m, t, &all));
        assert!(bad.is_empty(), "{t}: (u, v, gpu, cpu) {bad:?}");
    }
    // The middle tile, computed alone first, had its border ring recomputed when
    // its neighbours arrived.
    let bad = mismatches(n, &read(&mut r, middle), &surrounded);
    assert!(bad.is_empty(), "middle after its neighbours: {bad:?}");

    // The CPU path writes the reference itself, exactly.
    let mut cpu = renderer(m, NormalSource::Cpu);
    assert!(!cpu.normals_on_gpu());
    assert!(cpu.upload(&pool, middle));
    assert_eq!(read(&mut cpu, middle), reference(m, middle, &all));
}

#[test]
fn a_shared_border_gets_the_same_normal_whichever_tile_arrived_first() {
    let Some(m) = moon() else { return };
    let n = m.world.geometry.tile_samples();
    let level = grid_level(m);
    let (west, east) = (tile(level, 1, 1), tile(level, 2, 1));
    let pool = pool(m, &[west, east]);
    let arrive = |first: TileId, second: TileId| {
        let mut r = renderer(m, NormalSource::Gpu);
        assert!(r.upload(&pool, first));
        // The first tile's normal map is done before the second arrives.
        let before = read(&mut r, first);
        assert!(r.upload(&pool, second));
        (before, read(&mut r, west), read(&mut r, east))
    };
    let (west_alone, w1, e1) = arrive(west, east);
    let (east_alone, w2, e2) = arrive(east, west);
    assert_eq!(
        w1, w2,
        "the west tile's map depends on the order of arrival"
    );
    assert_eq!(
        e1, e2,
        "the east tile's map depends on the order of arrival"
    );
    for v in 0..n {
        assert_eq!(w1[v * n + n - 1], e1[v * n], "shared border, row {v}");
    }
    // Both match the reference with the other tile as their only neighbour.
    let both = [west, east];
    assert!(mismatches(n, &w1, &reference(m, west, &both)).is_empty());
    assert!(mismatches(n, &e1, &reference(m, east, &both)).is_empty());
    // And the border did change when the neighbour arrived (one-sided before).
    assert!((0..n).any(|v| west_alone[v * n + n - 1] != w1[v * n + n - 1]));
    assert!((0..n).any(|v| east_alone[v * n] != e1[v * n]));
}
