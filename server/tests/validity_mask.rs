//! No-data and padding as a mask
//! (DECISIONS.md "Coordinate systems, masks and reprojection"; FORMAT.md "Validity
//! mask"): built from real files, the pyramid's masks must say exactly which cells are
//! terrain at every level, wholly no-data tiles must be absent, and the per-level
//! counts must match the input sample for sample.

#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed test

use std::path::Path;
use tessera_server::builder::{BuildOptions, build};
use tessera_server::ingest::{self, Input};
use tessera_shared::{Pyramid, TileGeometry, testdata};

/// The input's own validity, read with the plain row reader: `valid(x, y)` is true
/// for samples inside the DEM that are not its no-data value.
struct Truth {
    width: u32,
    height: u32,
    valid: Vec<bool>,
}

impl Truth {
    fn read(path: &Path, nodata: Option<f32>) -> Self {
        let Input::Rows(mut rows) = ingest::open(path.to_str().unwrap()).unwrap() else {
            panic!("{} is not a file input", path.display());
        };
        let info = rows.info().clone();
        let mut v = vec![0f32; (info.width * info.height) as usize];
        rows.read_rows(&mut v).unwrap();
        let nodata = nodata.or(info.nodata.map(|n| n as f32));
        Self {
            width: info.width,
            height: info.height,
            valid: v
                .iter()
                .map(|s| !s.is_nan() && Some(*s) != nodata)
                .collect(),
        }
    }

    fn at(&self, x: u64, y: u64) -> bool {
        x < u64::from(self.width)
            && y < u64::from(self.height)
            && self.valid[(y * u64::from(self.width) + x) as usize]
    }

    /// A cell of spacing `s` at global sample `(gx, gy)` is terrain iff every sample
    /// of its closed square is: the AND over the finest cells it covers, stated
    /// without reference to how the builder pools.
    fn cell(&self, gx: u64, gy: u64, s: u64) -> bool {
        (gy..=gy + s).all(|y| (gx..=gx + s).all(|x| self.at(x, y)))
    }
}

fn build_to(
    dir: &Path,
    input: &Path,
    tile_size: u32,
    nodata: Option<f64>,
) -> Pyramid<tessera_shared::FileSource> {
    let out = dir.join("out.tess");
    let opts = BuildOptions {
        tile_size,
        nodata,
        ..BuildOptions::default()
    };
    build(input.to_str().unwrap(), &out, &opts).unwrap();
    let report = tessera_server::verify::verify(&out).unwrap();
    assert!(
        report.is_ok(),
        "verify: {:?} {:?}",
        report.bad,
        report.problems
    );
    Pyramid::open_file(&out).unwrap()
}

/// Every present tile's mask against the truth, every level; returns per level the
/// (terrain, non-terrain) cell counts and the absent-but-inside tiles.
fn check_masks(p: &Pyramid<tessera_shared::FileSource>, truth: &Truth) -> Vec<(u64, u64, usize)> {
    let g: TileGeometry = *p.geometry();
    let t = g.tile_size();
    let mut out = Vec::new();
    for level in g.levels() {
        let s = g.spacing(level);
        let (mut yes, mut no, mut absent) = (0u64, 0u64, 0usize);
        for tile in g.present_tiles(level) {
            let (gx0, gy0) = g.origin(tile);
            let Some(rec) = p.read_tile(tile).unwrap() else {
                // Absent inside the DEM: only when no cell is terrain.
                for cy in 0..u64::from(t) {
                    for cx in 0..u64::from(t) {
                        assert!(
                            !truth.cell(gx0 + cx * s, gy0 + cy * s, s),
                            "{tile} is absent but its cell ({cx}, {cy}) is terrain"
                        );
                    }
                }
                absent += 1;
                continue;
            };
            for cy in 0..t {
                for cx in 0..t {
                    let want = truth.cell(gx0 + u64::from(cx) * s, gy0 + u64::from(cy) * s, s);
                    assert_eq!(rec.mask.is_valid(cx, cy), want, "{tile} cell ({cx}, {cy})");
                    if want {
                        yes += 1;
                    } else {
                        no += 1;
                    }
                }
            }
            assert!(yes > 0 || no > 0);
        }
        out.push((yes, no, absent));
    }
    out
}

/// Level counts against the truth: level `L` samples every `2^(L_max − L)`-th
/// column and row of the DEM.
fn check_counts(p: &Pyramid<tessera_shared::FileSource>, truth: &Truth) {
    let g = p.geometry();
    let counts = &p.metadata().level_counts;
    assert_eq!(counts.len(), usize::from(g.level_count()));
    for level in g.levels() {
        let s = g.spacing(level);
        let (mut valid, mut filled) = (0u64, 0u64);
        for y in (0..u64::from(truth.height)).step_by(s as usize) {
            for x in (0..u64::from(truth.width)).step_by(s as usize) {
                if truth.at(x, y) {
                    valid += 1;
                } else {
                    filled += 1;
                }
            }
        }
        let c = counts[usize::from(level.get())];
        assert_eq!((c.valid, c.filled), (valid, filled), "level {level}");
    }
}

#[test]
fn luxembourgs_border_mask_holds_at_every_level() {
    let Some(path) = testdata::dem_or_skip("luxembourg_elev.tif") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let p = build_to(dir.path(), &path, 64, None);
    let truth = Truth::read(&path, None);
    // README: 3,942 no-data pixels outside the country.
    assert_eq!(truth.valid.iter().filter(|v| !**v).count(), 3942);
    assert_eq!(p.metadata().nodata_count, 3942);
    let levels = check_masks(&p, &truth);
    for (level, (yes, no, _)) in levels.iter().enumerate() {
        assert!(*yes > 0, "level {level} has no terrain cell");
        assert!(
            *no > 0,
            "level {level} has no masked cell: the border is lost"
        );
    }
    // Masked cells stay masked going up: the terrain share never grows.
    let share: Vec<f64> = levels
        .iter()
        .map(|(y, n, _)| *y as f64 / (*y + *n) as f64)
        .collect();
    assert!(share.windows(2).all(|w| w[0] <= w[1]), "{share:?}");
    check_counts(&p, &truth);
    // The index flags the tiles with a partial mask: here every one (the border and
    // the padding run through all of them).
    for level in p.geometry().levels() {
        for e in p.index(level).unwrap().iter().filter(|e| e.is_present()) {
            assert_eq!(e.flags, tessera_shared::format::FLAG_PARTIAL);
        }
    }
}

#[test]
fn srtm_voids_are_masked_and_counted() {
    let Some(path) = testdata::dem_or_skip("N46E008.tif") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let p = build_to(dir.path(), &path, 256, None);
    let truth = Truth::read(&path, None);
    // README: 103,743 real void pixels.
    assert_eq!(p.metadata().nodata_count, 103_743);
    check_masks(&p, &truth);
    check_counts(&p, &truth);
    let finest = p.metadata().level_counts.last().copied().unwrap();
    assert_eq!(
        (finest.valid, finest.filled),
        (1201 * 1201 - 103_743, 103_743)
    );
}

/// Writes a 16-bit grayscale PNG.
fn write_png(path: &Path, w: u32, h: u32, value: impl Fn(u32, u32) -> u16) {
    let f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut e = png::Encoder::new(f, w, h);
    e.set_color(png::ColorType::Grayscale);
    e.set_depth(png::BitDepth::Sixteen);
    let mut wr = e.write_header().unwrap();
    let mut data = Vec::with_capacity((2 * w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            data.extend_from_slice(&value(x, y).to_be_bytes());
        }
    }
    wr.write_image_data(&data).unwrap();
}

#[test]
fn a_wholly_no_data_tile_is_absent_and_its_parent_masks_its_area() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("hole.png");
    // 200 × 130 samples, 64-cell tiles: the no-data block x 65..=127, y 0..=64 leaves
    // no cell of finest tile (1, 0) (samples x 64..=128, y 0..=64) with four valid
    // corners.
    let hole = |x: u32, y: u32| (65..=127).contains(&x) && y <= 64;
    write_png(&png, 200, 130, |x, y| {
        if hole(x, y) {
            0
        } else {
            1000 + ((x * 7 + y * 3) % 500) as u16
        }
    });
    let p = build_to(dir.path(), &png, 64, Some(0.0));
    let truth = Truth::read(&png, Some(0.0));
    let levels = check_masks(&p, &truth);
    let finest = usize::from(p.geometry().finest().get());
    assert_eq!(
        levels[finest].2, 1,
        "exactly tile (1, 0) of the finest level is absent"
    );
    let t = tessera_shared::TileId::new(p.geometry().finest(), 1, 0).unwrap();
    assert!(p.geometry().is_present(t) && p.entry(t).is_none());
    check_counts(&p, &truth);
    let hole_samples: u64 = (127 - 65 + 1) * 65;
    assert_eq!(p.metadata().nodata_count, hole_samples);
}
