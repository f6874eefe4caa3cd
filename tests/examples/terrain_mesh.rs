//! The Cesium terrain benchmark's measuring tool (bench/terrain.sh, BENCHMARKS.md):
//! meshes a seeded sample of one zoom's tiles of a geographic pyramid and prints one
//! JSON line per tile — time to mesh (sources already decoded, median of 5) and to
//! encode, triangles, the tile's true worst error against every finest sample (our
//! own decoder), and a regular 65 × 65 heightmap of the same tile: its worst error,
//! and our mesh's triangles at that error.
//!
//! `cargo run --release -p tessera-e2e --example terrain_mesh -- PYRAMID ZOOM TILES [SEED]`
//! (EGM96 pyramids get the geoid from `tessera_server::geoid::find`).
//!
//! With `TERRAIN_WINDOWS=DIR`, each tile wholly inside the data also gets its window
//! of finest samples (the samples the tile covers, heights on the ellipsoid) written
//! as `DIR/Z_X_Y.f32` (little-endian, row-major from the north-west), named in the
//! line as `window` with its `window_size` `[columns, rows]`, for the peer meshers
//! (bench/mesh_peers.py) to mesh the same samples.

#![allow(clippy::unwrap_used)] // a measuring tool: a failed unwrap is a failed run

use std::sync::Arc;
use std::time::Instant;
use tessera_e2e::Rng;
use tessera_e2e::quantized_mesh::decode;
use tessera_e2e::terrain_check::SampleGrid;
use tessera_server::cesium::quantized_mesh::{Extensions, TerrainMesh, encode};
use tessera_server::cesium::terrain::{PyramidLevels, Terrain, ZoomPlan};
use tessera_server::cesium::tiling::CesiumTile;
use tessera_server::geoid::Geoid;
use tessera_shared::{Pyramid, VerticalDatum};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [path, zoom, count, rest @ ..] = args.as_slice() else {
        eprintln!("usage: terrain_mesh PYRAMID ZOOM TILES [SEED]");
        std::process::exit(2);
    };
    let (z, count): (u8, usize) = (zoom.parse().unwrap(), count.parse().unwrap());
    let seed = rest.first().map_or(1, |s| s.parse().unwrap());
    let pyramid = Pyramid::open_file(std::path::Path::new(path)).unwrap();
    let geoid = (pyramid.metadata().vertical_datum == VerticalDatum::Egm96)
        .then(|| tessera_server::geoid::find(None))
        .flatten()
        .map(|g| Arc::new(Geoid::open(&g).unwrap()));
    let terrain = Terrain::new(pyramid.metadata(), geoid.clone()).unwrap();
    let grid = SampleGrid::of(&pyramid, geoid.as_deref());
    let levels = PyramidLevels::new(&pyramid);
    let plan = terrain.plan(z, &levels).unwrap();
    let [x0, y0, x1, y1] = terrain.available(z).expect("zoom has tiles");
    let mut rng = Rng(seed);
    let windows = std::env::var_os("TERRAIN_WINDOWS").map(std::path::PathBuf::from);
    let ext = Extensions {
        normals: true,
        water_mask: None,
        metadata: None,
    };
    let true_error = |tile: CesiumTile, mesh: &TerrainMesh| {
        let bytes = encode(mesh, tile.rect(), &terrain.ellipsoid, &ext).unwrap();
        let d = decode(&bytes).unwrap();
        grid.worst_error(tile.rect(), &d.positions(tile.rect()), &d.triangles)
    };
    for _ in 0..count {
        let x = x0 + (rng.uniform() * f64::from(x1 - x0 + 1)) as u32;
        let y = y0 + (rng.uniform() * f64::from(y1 - y0 + 1)) as u32;
        let tile = CesiumTile::new(z, x, y).unwrap();
        let cold = Instant::now();
        let mesh = terrain.mesh(tile, &levels).unwrap();
        let cold_us = cold.elapsed().as_secs_f64() * 1e6;
        let timed = |plan: &ZoomPlan| {
            let runs: Vec<f64> = (0..5)
                .map(|_| {
                    let t = Instant::now();
                    let m = terrain.mesh_with(tile, plan, &levels).unwrap();
                    std::hint::black_box(m.triangles.len());
                    t.elapsed().as_secs_f64() * 1e6
                })
                .collect();
            median(runs)
        };
        let mesh_us = timed(&plan);
        let t = Instant::now();
        let bytes = encode(&mesh, tile.rect(), &terrain.ellipsoid, &ext).unwrap();
        let encode_us = t.elapsed().as_secs_f64() * 1e6;
        let check = true_error(tile, &mesh);
        let window = windows
            .as_ref()
            .and_then(|dir| write_window(&grid, tile, dir));
        let (rpos, rtris) = grid.regular_grid(tile.rect(), 65);
        let regular = grid.worst_error(tile.rect(), &rpos, &rtris);
        // Our mesh at the regular grid's error: the same 5 % margin as the served
        // plan keeps for vertex quantization, so the true error stays below it.
        let at_regular = terrain
            .mesh_with(tile, &plan.with_tau(0.95 * regular.worst), &levels)
            .unwrap();
        let at_regular_check = true_error(tile, &at_regular);
        println!(
            "{}",
            serde_json::json!({
                "dataset": std::path::Path::new(path).file_stem().unwrap().to_string_lossy(),
                "tile": format!("{z}/{x}/{y}"),
                "level": plan.level.get(),
                "square": plan.square,
                "geometric_error_m": plan.geometric_error,
                "samples": check.samples,
                "cold_us": cold_us,
                "mesh_us": mesh_us,
                "encode_us": encode_us,
                "bytes": bytes.len(),
                "vertices": mesh.vertices.len(),
                "triangles": mesh.triangles.len(),
                "error_m": check.worst,
                "regular_triangles": rtris.len(),
                "regular_error_m": regular.worst,
                "at_regular_triangles": at_regular.triangles.len(),
                "at_regular_error_m": at_regular_check.worst,
                "window": window.as_ref().map(|w| w.0.clone()),
                "window_size": window.as_ref().map(|w| w.1),
            })
        );
    }
}

/// Writes the finest samples `tile` covers (when it lies wholly inside the data):
/// the file's path and `[columns, rows]`.
fn write_window(
    grid: &SampleGrid,
    tile: CesiumTile,
    dir: &std::path::Path,
) -> Option<(String, [u32; 2])> {
    let [w, s, e, n] = tile.rect();
    let cols = |a: f64, b: f64| ((a - grid.lon0) / grid.dlon, (b - grid.lon0) / grid.dlon);
    let rows = |a: f64, b: f64| ((a - grid.lat0) / grid.dlat, (b - grid.lat0) / grid.dlat);
    let (c0, c1) = cols(w, e);
    let (r0, r1) = rows(n, s);
    let (c0, c1) = (c0.min(c1).ceil(), c0.max(c1).floor());
    let (r0, r1) = (r0.min(r1).ceil(), r0.max(r1).floor());
    if c0 < 0.0 || r0 < 0.0 || c1 > f64::from(grid.width - 1) || r1 > f64::from(grid.height - 1) {
        return None;
    }
    let (c0, c1, r0, r1) = (c0 as u32, c1 as u32, r0 as u32, r1 as u32);
    let mut bytes = Vec::new();
    for r in r0..=r1 {
        for c in c0..=c1 {
            let h = grid.heights[(r * grid.width + c) as usize] as f32;
            bytes.extend_from_slice(&h.to_le_bytes());
        }
    }
    let path = dir.join(format!("{}_{}_{}.f32", tile.z, tile.x, tile.y));
    std::fs::write(&path, bytes).unwrap();
    Some((
        path.to_string_lossy().into_owned(),
        [c1 - c0 + 1, r1 - r0 + 1],
    ))
}
