//! Two pyramid invariants, checked by brute force on real DEMs:
//! docs/ARCHITECTURE.md#borders-and-decimation and
//! docs/ARCHITECTURE.md#exact-error-tables.
//!
//! Each DEM is built into a pyramid with small tiles (so there are several levels,
//! partial edge tiles and absent tiles), then every sample and every error-table
//! entry of every tile is recomputed from the finest level alone:
//!
//! 1. every sample of every tile at every level equals the padded finest grid at
//!    the same place (borders agree with neighbours; level `L` is the decimation of
//!    level `L+1`), and the finest grid equals the quantized input;
//! 2. every stored block error equals (up to `f32` round-up) the true maximum vertical
//!    distance between that tile's mesh at that within-tile level and the finest
//!    samples over the block, and block min/max equal the true min/max.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

use tessera_server::builder::{BuildOptions, build};
use tessera_server::ingest::{self, Input};
use tessera_shared::tile::BLOCKS;
use tessera_shared::triangulation::Cell;
use tessera_shared::{Pyramid, TileGeometry, testdata};

/// The finest level as one padded grid, from the pyramid's own finest tiles.
struct Finest {
    side: usize,
    values: Vec<u16>,
    /// Finest samples covered by present finest tiles: `x ≤ cover_x`, `y ≤ cover_y`.
    cover_x: usize,
    cover_y: usize,
}

fn load_finest(p: &Pyramid<tessera_shared::FileSource>) -> Finest {
    let g = *p.geometry();
    let side = g.padded_samples() as usize;
    let t = g.tile_size() as usize;
    let mut values = vec![0u16; side * side];
    let mut seen = vec![false; side * side];
    let ts = g.tile_samples();
    for tile in g.present_tiles(g.finest()) {
        let rec = p.read_tile(tile).unwrap().unwrap();
        let (x0, y0) = g.origin(tile);
        for j in 0..ts {
            for i in 0..ts {
                let at = (y0 as usize + j) * side + x0 as usize + i;
                let v = rec.heights[j * ts + i];
                if seen[at] {
                    // Invariant 1 at the finest level: shared borders agree.
                    assert_eq!(values[at], v, "{tile}: border sample ({i},{j}) disagrees");
                }
                values[at] = v;
                seen[at] = true;
            }
        }
    }
    let cover_x = ((g.width() as usize - 1).div_ceil(t)) * t;
    let cover_y = ((g.height() as usize - 1).div_ceil(t)) * t;
    Finest {
        side,
        values,
        cover_x,
        cover_y,
    }
}

impl Finest {
    fn at(&self, x: usize, y: usize) -> u16 {
        self.values[y * self.side + x]
    }
}

fn check_pyramid(name: &str, tile_size: u32, scale: f64, offset: f64) {
    let Some(path) = testdata::dem_or_skip(name) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("p.tess");
    let opts = BuildOptions {
        tile_size,
        scale,
        offset,
        ..BuildOptions::default()
    };
    build(path.to_str().unwrap(), &out, &opts).unwrap();
    let p = Pyramid::open_file(&out).unwrap();
    let g: TileGeometry = *p.geometry();
    let q = p.metadata().quantization;
    assert!(g.finest().get() >= 2, "{name}: want several levels to test");
    let f = load_finest(&p);
    let (w, h) = (g.width() as usize, g.height() as usize);

    // The finest grid inside the DEM is the input, quantized (integer inputs exactly);
    // the padding repeats the edge.
    check_against_input(&path, &f, &p, scale, offset);
    for y in 0..=f.cover_y {
        for x in 0..=f.cover_x {
            assert_eq!(
                f.at(x, y),
                f.at(x.min(w - 1), y.min(h - 1)),
                "{name}: padding at ({x},{y})"
            );
        }
    }

    let t = g.tile_size() as usize;
    let ts = g.tile_samples();
    let block = t / BLOCKS as usize;
    let mut checked_errors = 0u64;
    for level in g.levels() {
        let s = g.spacing(level) as usize;
        for tile in g.present_tiles(level) {
            let rec = p.read_tile(tile).unwrap().unwrap();
            let (x0, y0) = g.origin(tile);
            let (x0, y0) = (x0 as usize, y0 as usize);
            // Invariant 1: every sample is the padded finest sample at its place.
            for j in 0..ts {
                for i in 0..ts {
                    let (x, y) = (x0 + i * s, y0 + j * s);
                    let want = f.at(x.min(w - 1), y.min(h - 1));
                    assert_eq!(
                        rec.heights[j * ts + i],
                        want,
                        "{name} {tile} sample ({i},{j})"
                    );
                }
            }
            // Invariant 2: brute-force block errors and ranges.
            let span = t * s;
            for n in 0..=g.tile_log2() {
                let cell = t >> n; // cell size in tile samples
                let mut err = [0f64; 64];
                let (mut lo, mut hi) = ([u16::MAX; 64], [0u16; 64]);
                for y in y0..=(y0 + span).min(f.cover_y) {
                    for x in x0..=(x0 + span).min(f.cover_x) {
                        // Position in tile samples (may be fractional in finest units).
                        let (lx, ly) = (x - x0, y - y0);
                        let csz = cell * s; // cell size in finest samples
                        let cx = (lx / csz).min((t / cell) - 1);
                        let cy = (ly / csz).min((t / cell) - 1);
                        let hq = |i: usize, j: usize| i64::from(rec.heights[j * ts + i]);
                        let c = Cell {
                            q00: hq(cx * cell, cy * cell),
                            q10: hq(cx * cell + cell, cy * cell),
                            q01: hq(cx * cell, cy * cell + cell),
                            q11: hq(cx * cell + cell, cy * cell + cell),
                        };
                        let e = c.vertical_error(
                            csz as i64,
                            (lx - cx * csz) as i64,
                            (ly - cy * csz) as i64,
                            i64::from(f.at(x, y)),
                        ) * q.scale;
                        // Closed block ranges: a sample on a block border is in both blocks.
                        let bsz = block * s;
                        let bxs = blocks_of(lx, bsz);
                        let bys = blocks_of(ly, bsz);
                        for by in bys.clone() {
                            for bx in bxs.clone() {
                                if !attributed(&f, t, (x, y), (x0 + bx * bsz, y0 + by * bsz), bsz) {
                                    continue;
                                }
                                let i = by * 8 + bx;
                                err[i] = err[i].max(e);
                                if n == 0 {
                                    lo[i] = lo[i].min(f.at(x, y));
                                    hi[i] = hi[i].max(f.at(x, y));
                                }
                            }
                        }
                    }
                }
                for by in 0..8u32 {
                    for bx in 0..8u32 {
                        let i = (by * 8 + bx) as usize;
                        let stored = f64::from(rec.errors.error(n, bx, by));
                        let truth = err[i];
                        assert!(
                            stored >= truth && stored <= truth * (1.0 + 1e-6) + 1e-9,
                            "{name} {tile} n={n} block ({bx},{by}): stored {stored}, brute force {truth}"
                        );
                        checked_errors += 1;
                        if n == 0 {
                            assert_eq!(
                                rec.errors.block_range(bx, by),
                                (lo[i], hi[i]),
                                "{name} {tile} block ({bx},{by}) range"
                            );
                        }
                    }
                }
            }
        }
    }
    assert!(checked_errors > 0);
    eprintln!("{name}: {checked_errors} error-table entries equal brute force");
}

/// Whether finest sample `(x, y)` counts in the block whose area starts at `(bx0, by0)`
/// with side `size` (finest samples): it must lie in the closed range of a present
/// finest tile whose area overlaps the block's area. (A finest tile that only touches
/// the block along a border does not count: that is what pooling blocks of present
/// tiles up the quadtree computes, and FORMAT.md defines.)
fn attributed(
    f: &Finest,
    t: usize,
    (x, y): (usize, usize),
    (bx0, by0): (usize, usize),
    size: usize,
) -> bool {
    let tiles_holding = |v: usize| {
        let hi = v / t;
        let lo = if v > 0 && v.is_multiple_of(t) {
            hi - 1
        } else {
            hi
        };
        lo..=hi
    };
    // Finest tiles overlapping the block's open area along one axis.
    let overlapping = |start: usize| (start / t)..=((start + size - 1) / t);
    let (px, py) = (f.cover_x / t, f.cover_y / t); // present finest tiles per axis
    let ok_x = tiles_holding(x).any(|tx| tx < px && overlapping(bx0).contains(&tx));
    let ok_y = tiles_holding(y).any(|ty| ty < py && overlapping(by0).contains(&ty));
    ok_x && ok_y
}

/// Blocks whose closed range `[b·size, (b+1)·size]` holds offset `v`.
fn blocks_of(v: usize, size: usize) -> std::ops::RangeInclusive<usize> {
    let hi = (v / size).min(7);
    let lo = if v > 0 && v.is_multiple_of(size) {
        v / size - 1
    } else {
        hi
    };
    lo..=hi
}

/// The finest grid inside the DEM equals the input's samples, quantized, wherever the
/// input had data (voids are filled, so only valid samples are compared).
fn check_against_input(
    path: &std::path::Path,
    f: &Finest,
    p: &Pyramid<tessera_shared::FileSource>,
    scale: f64,
    offset: f64,
) {
    let Input::Rows(mut src) = ingest::open(path.to_str().unwrap()).unwrap() else {
        panic!("not a file input");
    };
    let info = src.info().clone();
    let q = p.metadata().quantization;
    let w = info.width as usize;
    let mut row = vec![0f32; w];
    let mut worst = 0f64;
    for y in 0..info.height as usize {
        src.read_rows(&mut row).unwrap();
        for (x, raw) in row.iter().enumerate() {
            if raw.is_nan() || info.nodata.is_some_and(|nd| *raw == nd as f32) {
                continue;
            }
            let stored = q.height(f.at(x, y));
            let metres = offset + scale * f64::from(*raw);
            worst = worst.max((stored - metres).abs());
        }
    }
    let tolerance = q.max_error * (1.0 + 1e-9) + 1e-9;
    assert!(
        worst <= tolerance,
        "stored heights differ from the input by {worst} m (quantization error {})",
        q.max_error
    );
}

#[test]
fn jacksboro_png_invariants() {
    check_pyramid("jacksboro_fault_dem.png", 64, 1.0, 0.0);
}

#[test]
fn srtm_hgt_invariants() {
    check_pyramid("N44W072.hgt", 64, 1.0, 0.0);
}

/// int16 GeoTIFF with 103,743 radar voids, filled from their nearest valid samples.
#[test]
fn srtm_geotiff_with_voids_invariants() {
    check_pyramid("N46E008.tif", 64, 1.0, 0.0);
}

/// float32 GeoTIFF: quantized, so stored heights are within `max_error` of the input.
#[test]
fn float_geotiff_invariants() {
    check_pyramid("aletsch.tif", 64, 1.0, 0.0);
}

/// Non-square tiled int16 GeoTIFF: absent tiles along the south edge at every level.
#[test]
fn non_square_tiled_geotiff_invariants() {
    check_pyramid("bigtujunga.tif", 64, 1.0, 0.0);
}

/// Decimetre heights (`--scale 0.1`) in bigger tiles.
#[test]
fn scaled_png_invariants() {
    check_pyramid("sthelens_10m.png", 128, 0.1, 0.0);
}
