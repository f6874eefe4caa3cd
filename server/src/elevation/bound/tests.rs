//! The bound against brute force: a rough synthetic DEM, its coarse levels by
//! decimation and their error tables measured sample by sample with the shared
//! triangulation (as the build measures them), then every level's answer at many
//! points compared with the finest level's.

use super::*;
use tessera_shared::CellMask;
use tessera_shared::triangulation::Cell;

/// Cells per tile.
const T: u32 = 8;
/// Tiles per side at the finest level (level 2).
const NF: u32 = 4;
const FINEST: u32 = 2;

fn height(x: u32, y: u32) -> u16 {
    // Smooth relief plus hash noise: steep, rough, never a plane.
    let smooth = 2000.0 + 300.0 * (f64::from(x) * 0.21).sin() * (f64::from(y) * 0.13).cos();
    let noise = (x.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503)) % 97;
    (smooth as u32 + noise) as u16
}

/// The tiles of level `l`: heights by decimation, block errors by brute force.
fn level_tiles(l: u32) -> Vec<Vec<SourceTile>> {
    let k = FINEST - l;
    let s = 1u32 << k;
    let n = 1u32 << l;
    let side = T + 1;
    let q = Quantization {
        offset: -100.0,
        scale: 0.5,
        max_error: 0.25,
    };
    (0..n)
        .map(|ty| {
            (0..n)
                .map(|tx| {
                    let at = |u: u32, v: u32| height((tx * T + u) * s, (ty * T + v) * s);
                    let heights = (0..side)
                        .flat_map(|v| (0..side).map(move |u| (u, v)))
                        .map(|(u, v)| at(u, v))
                        .collect();
                    let span = T * s;
                    let block = span / 8;
                    let mut errors = [0f32; 64];
                    for (b, e) in errors.iter_mut().enumerate() {
                        let (bx, by) = (b as u32 % 8, b as u32 / 8);
                        let mut worst = 0f64;
                        for gy in ty * span + by * block..=ty * span + (by + 1) * block {
                            for gx in tx * span + bx * block..=tx * span + (bx + 1) * block {
                                let (cx, cy) = ((gx / s).min(n * T - 1), (gy / s).min(n * T - 1));
                                let g = |x: u32, y: u32| i64::from(height(x * s, y * s));
                                let cell = Cell {
                                    q00: g(cx, cy),
                                    q10: g(cx + 1, cy),
                                    q01: g(cx, cy + 1),
                                    q11: g(cx + 1, cy + 1),
                                };
                                let err = cell.vertical_error(
                                    i64::from(s),
                                    i64::from(gx - cx * s),
                                    i64::from(gy - cy * s),
                                    i64::from(height(gx, gy)),
                                );
                                worst = worst.max(err * q.scale);
                            }
                        }
                        *e = tessera_shared::error_table::round_up_f32(worst);
                    }
                    SourceTile {
                        heights,
                        mask: CellMask::all_valid(T),
                        quantization: q,
                        block_errors: Some(Box::new(errors)),
                    }
                })
                .collect()
        })
        .collect()
}

fn evaluate(levels: &[Vec<Vec<SourceTile>>], l: u32, m: Interpolation, p: [f64; 2]) -> Evaluated {
    let tiles = &levels[l as usize];
    let get = |x: u32, y: u32| tiles.get(y as usize).and_then(|r| r.get(x as usize));
    let grid = LevelGrid {
        k: FINEST - l,
        t: T,
        n: 1 << l,
    };
    let view = LevelView::new(grid, &get);
    view.evaluate(m, p, &tiles[0][0].quantization)
        .expect("every tile is there")
}

/// At random points and at every finest sample of a patch, every coarse level's
/// answer is within its bound of the finest level's, and the bound is tight enough
/// that half of it would fail somewhere.
#[test]
fn the_bound_holds_and_is_tight() {
    let levels: Vec<_> = (0..=FINEST).map(level_tiles).collect();
    let last = f64::from(NF * T);
    let mut points: Vec<[f64; 2]> = (0..4000u32)
        .map(|i| {
            let r = |salt: u32| {
                f64::from(i.wrapping_mul(2_246_822_519).wrapping_add(salt) % 100_000) / 100_000.0
            };
            [r(7) * last, r(3_266_489_917) * last]
        })
        .collect();
    points.extend((0..=12).flat_map(|y| (0..=12).map(move |x| [f64::from(x), f64::from(y)])));
    for m in Interpolation::ALL {
        for l in 0..FINEST {
            let mut worst_ratio = 0f64;
            for &p in &points {
                let fine = evaluate(&levels, FINEST, m, p);
                let coarse = evaluate(&levels, l, m, p);
                let diff = (coarse.value - fine.value).abs();
                assert!(
                    diff <= coarse.bound,
                    "{m:?} level {l} at {p:?}: |{} − {}| = {diff} > bound {}",
                    coarse.value,
                    fine.value,
                    coarse.bound
                );
                // Against the source, the finest answer's own bound (quantization).
                assert!((fine.bound - fine_bound(m, p)).abs() < 1e-12);
                worst_ratio = worst_ratio.max(diff / coarse.bound);
            }
            assert!(
                worst_ratio > 0.5,
                "{m:?} level {l}: the bound is loose (worst diff/bound {worst_ratio})"
            );
        }
    }
}

/// Σ|w| · q at the finest level.
fn fine_bound(m: Interpolation, p: [f64; 2]) -> f64 {
    let last = i64::from(NF * T);
    Stencil::new(m, p, [last, last]).abs_weight() * 0.25
}

/// A point the kernel reads beyond a missing tile has no answer, rather than one
/// from a surface the table did not measure.
#[test]
fn a_missing_neighbour_gives_no_answer() {
    let levels: Vec<_> = (0..=FINEST).map(level_tiles).collect();
    let tiles = &levels[FINEST as usize];
    let get = |x: u32, y: u32| (x == 0 && y == 0).then(|| &tiles[0][0]);
    let view = LevelView::new(LevelGrid { k: 0, t: T, n: NF }, &get);
    let q = tiles[0][0].quantization;
    assert!(
        view.evaluate(Interpolation::Bilinear, [3.5, 3.5], &q)
            .is_some()
    );
    // Cubic at the tile's east edge reads column 9, in the missing tile (1, 0).
    assert!(
        view.evaluate(Interpolation::Cubic, [7.5, 3.5], &q)
            .is_none()
    );
    // A sample on the shared edge is read from the tile that has it.
    assert!(
        view.evaluate(Interpolation::Nearest, [8.0, 3.0], &q)
            .is_some()
    );
}
