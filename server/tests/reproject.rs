//! `build --to` (DECISIONS.md "Coordinate systems, masks and reprojection") against GDAL
//! on real DEMs: aletsch (EPSG:2056) and bigtujunga (EPSG:32611) to EPSG:4326, and back
//! from GDAL's geographic copies to their own CRSs. Coordinates must agree with
//! `gdaltransform` (PROJ) within 1e-6°, and heights with `gdalwarp -r bilinear -et 0`
//! (exact transforms) resampled onto the very same grid, within the quantization error
//! plus what our interpolated positions (≤ `MAX_ERROR_PX` off) can change.

#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed test

mod gdal;
mod raster_support;

use raster_support::{finest_samples, read_raster, steepest};
use std::path::Path;
use std::process::Command;
use tessera_server::crs::Crs;
use tessera_server::ingest::{self, Input};
use tessera_shared::{Pyramid, testdata};

fn build(input: &Path, out: &Path, to: &str) {
    let o = Command::new(env!("CARGO_BIN_EXE_tessera-server"))
        .arg("build")
        .arg(input)
        .args(["--to", to, "--tile-size", "256", "--quiet", "-o"])
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Builds `src` (in `from`) `--to` `to`, then checks the grid and the heights.
fn check(src: &Path, from: &str, to: &str, dir: &Path) {
    let out = dir.join("out.tess");
    build(src, &out, to);
    let p = Pyramid::open_file(&out).unwrap();
    let m = p.metadata();
    let g = m.georef.as_ref().unwrap();
    assert_eq!(g.crs().as_deref(), Some(to));
    assert!(g.proj.as_deref().is_some_and(|s| s.starts_with("+proj=")));
    let gt = g.geotransform;
    let (w, h) = (m.width, m.height);

    // 1. The source's corners, carried by our projection library and by PROJ.
    let (sw, sh, _) = read_raster(src);
    let Input::Rows(rows) = ingest::open(src.to_str().unwrap()).unwrap() else {
        panic!()
    };
    let sgt = rows.info().georef.as_ref().unwrap().geotransform;
    let corners: Vec<[f64; 2]> = [(0, 0), (sw, 0), (0, sh), (sw, sh)]
        .iter()
        .map(|&(c, r)| {
            [
                sgt[0] + f64::from(c) * sgt[1],
                sgt[3] + f64::from(r) * sgt[5],
            ]
        })
        .collect();
    let theirs = gdal::transform(from, to, &corners);
    let (a, b) = (Crs::parse(from).unwrap(), Crs::parse(to).unwrap());
    let tol = if b.is_geographic() { 1e-6 } else { 0.1 };
    for (c, t) in corners.iter().zip(&theirs) {
        let ours = a.transform_to(&b, c[0], c[1]).unwrap();
        assert!(
            (ours[0] - t[0]).abs() < tol && (ours[1] - t[1]).abs() < tol,
            "{from} {c:?} → ours {ours:?}, gdaltransform {t:?}"
        );
        // The output grid covers the source's footprint.
        assert!(
            t[0] >= gt[0] - tol && t[0] <= gt[0] + f64::from(w) * gt[1] + tol,
            "{t:?}"
        );
        assert!(
            t[1] <= gt[3] + tol && t[1] >= gt[3] + f64::from(h) * gt[5] - tol,
            "{t:?}"
        );
    }

    // 2. Heights against gdalwarp on the same grid, with exact transforms.
    let reference = dir.join("gdalwarp.tif");
    let (e, n) = (gt[0] + f64::from(w) * gt[1], gt[3]);
    let (west, south) = (gt[0], gt[3] + f64::from(h) * gt[5]);
    let te = [west, south, e, n].map(|v| format!("{v:.12}"));
    let (ws, hs) = (w.to_string(), h.to_string());
    gdal::run(
        "gdalwarp",
        &[
            "-q",
            "-overwrite",
            "-t_srs",
            to,
            "-te",
            &te[0],
            &te[1],
            &te[2],
            &te[3],
            "-ts",
            &ws,
            &hs,
            "-r",
            "bilinear",
            "-et",
            "0",
            "-ot",
            "Float32",
            "-dstnodata",
            "-99999",
            gdal::path_str(src),
            gdal::path_str(&reference),
        ],
    );
    let (rw, rh, want) = read_raster(&reference);
    assert_eq!((rw, rh), (w, h));
    let got = finest_samples(&p);
    // Interpolated source positions are within MAX_ERROR_PX of exact, so a height
    // may differ by that fraction of the steepest step between neighbouring samples
    // there, besides the quantization.
    let (mut compared, mut worst_excess, mut theirs_valid) = (0usize, f64::NEG_INFINITY, 0usize);
    for (i, (o, t)) in got.iter().zip(&want).enumerate() {
        if t.is_nan() {
            continue;
        }
        theirs_valid += 1;
        if o.is_nan() {
            continue;
        }
        compared += 1;
        let bound = m.quantization.max_error
            + 1e-3
            + 2.0 * ingest::reproject::MAX_ERROR_PX * steepest(&want, w, h, i);
        worst_excess = worst_excess.max(f64::from(o - t).abs() - bound);
    }
    // Our terrain covers GDAL's but for the outermost samples (a sample counts as
    // ours only where a whole terrain cell touches it).
    assert!(
        compared as f64 > 0.97 * theirs_valid as f64,
        "{compared} of {theirs_valid} of GDAL's samples are terrain here"
    );
    // The same bilinear weights of the same source samples: equal within the bound.
    assert!(
        worst_excess <= 0.0,
        "{} → {to}: a height differs by {worst_excess} m more than its bound",
        src.display()
    );
}

/// `name` (in `crs`) to WGS 84, then GDAL's geographic copy of it back to `crs`.
fn there_and_back(name: &str, crs: &str) {
    let Some(src) = testdata::dem_or_skip(name) else {
        return;
    };
    if !gdal::gdal_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    check(&src, crs, "EPSG:4326", dir.path());
    let geo = dir.path().join("geographic.tif");
    gdal::run(
        "gdalwarp",
        &[
            "-q",
            "-t_srs",
            "EPSG:4326",
            "-r",
            "bilinear",
            gdal::path_str(&src),
            gdal::path_str(&geo),
        ],
    );
    let back = tempfile::tempdir().unwrap();
    check(&geo, "EPSG:4326", crs, back.path());
}

#[test]
fn aletsch_from_lv95_to_wgs84_and_back() {
    there_and_back("aletsch.tif", "EPSG:2056");
}

#[test]
fn bigtujunga_from_utm_to_wgs84_and_back() {
    there_and_back("bigtujunga.tif", "EPSG:32611");
}

#[test]
fn bad_targets_are_one_line_errors_and_leave_nothing() {
    let Some(src) = testdata::dem_or_skip("aletsch.tif") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.tess");
    for (to, says) in [
        ("EPSG:1", "EPSG:1 is not a CRS"),
        ("UTM32", "neither EPSG:CODE"),
    ] {
        let o = Command::new(env!("CARGO_BIN_EXE_tessera-server"))
            .arg("build")
            .arg(&src)
            .args(["--to", to, "--quiet", "-o"])
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success());
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.contains(says), "{err}");
        assert!(
            std::fs::read_dir(dir.path()).unwrap().next().is_none(),
            "left files behind"
        );
    }
}
