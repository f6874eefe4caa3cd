//! Rasters in tests: a file's samples as our reader reads them, a pyramid's finest
//! samples in metres, and the steepest step around a sample (the bound on what a
//! position error of a fraction of a sample can change).

#![allow(dead_code)] // each test binary uses its own subset

use std::path::Path;
use tessera_server::ingest::{self, Input};
use tessera_shared::{FileSource, Pyramid};

/// Samples of a raster file read with our own reader (NaN for its no-data).
pub fn read_raster(path: &Path) -> (u32, u32, Vec<f32>) {
    let Input::Rows(mut rows) = ingest::open(path.to_str().unwrap()).unwrap() else {
        panic!("not a file");
    };
    let info = rows.info().clone();
    let mut v = vec![0f32; (info.width * info.height) as usize];
    rows.read_rows(&mut v).unwrap();
    if let Some(nd) = info.nodata {
        for s in &mut v {
            if f64::from(*s) == nd {
                *s = f32::NAN;
            }
        }
    }
    (info.width, info.height, v)
}

/// The pyramid's finest samples in metres; NaN where no terrain cell touches them.
pub fn finest_samples(p: &Pyramid<FileSource>) -> Vec<f32> {
    let g = *p.geometry();
    let (w, h) = (g.width() as usize, g.height() as usize);
    let t = g.tile_size() as usize;
    let q = p.metadata().quantization;
    let mut out = vec![f32::NAN; w * h];
    for tile in g.present_tiles(g.finest()) {
        let Some(rec) = p.read_tile(tile).unwrap() else {
            continue;
        };
        let (gx, gy) = g.origin(tile);
        let (gx, gy) = (gx as usize, gy as usize);
        for y in 0..=t {
            for x in 0..=t {
                let (sx, sy) = (gx + x, gy + y);
                if sx >= w || sy >= h {
                    continue;
                }
                let cell = |cx: usize, cy: usize| {
                    cx < t && cy < t && rec.mask.is_valid(cx as u32, cy as u32)
                };
                let touched = cell(x, y)
                    || (x > 0 && cell(x - 1, y))
                    || (y > 0 && cell(x, y - 1))
                    || (x > 0 && y > 0 && cell(x - 1, y - 1));
                if touched {
                    out[sy * w + sx] = q.height(rec.heights[y * (t + 1) + x]) as f32;
                }
            }
        }
    }
    out
}

/// The largest height difference between sample `i` of a `w × h` raster and its
/// eight neighbours (NaN neighbours skipped).
pub fn steepest(v: &[f32], w: u32, h: u32, i: usize) -> f64 {
    let (x, y) = ((i % w as usize) as i64, (i / w as usize) as i64);
    let mut most = 0f64;
    for dy in -1..=1i64 {
        for dx in -1..=1i64 {
            let (nx, ny) = (x + dx, y + dy);
            if (dx, dy) != (0, 0) && nx >= 0 && ny >= 0 && nx < i64::from(w) && ny < i64::from(h) {
                let n = v[(ny * i64::from(w) + nx) as usize];
                if !n.is_nan() {
                    most = most.max(f64::from(n - v[i]).abs());
                }
            }
        }
    }
    most
}
