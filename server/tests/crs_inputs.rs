//! Inputs whose CRS is not an EPSG code in the file, read as GDAL reads them, with
//! default flags: user-defined GeoKeys (olinda_dem_utm25s.tif), an ESRI `.prj`
//! sidecar, a VRT's `<SRS>`. Each is checked where a user would look: the ground
//! spacing against PROJ's own `proj -S` scale factor, the CRS `info` names against
//! `gdalsrsinfo`, the same georeferencing as the file that states its EPSG code.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

mod gdal;

use gdal::{gdal_or_skip, path_str, run, run_stdin};
use std::path::Path;
use std::process::{Command, Output};
use tessera_shared::{Metadata, Pyramid, testdata};

fn build(input: &Path, out: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_tessera-server"))
        .arg("build")
        .arg(input)
        .args(["--quiet", "-o"])
        .arg(out)
        .output()
        .unwrap()
}

fn built(input: &Path, out: &Path) -> Metadata {
    let o = build(input, out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    Pyramid::open_file(out).unwrap().metadata().clone()
}

fn info(file: &Path) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_tessera-server"))
        .arg("info")
        .arg(file)
        .output()
        .unwrap();
    assert!(o.status.success());
    String::from_utf8(o.stdout).unwrap()
}

/// olinda's GeoKeys name UTM zone 25S by ProjectionGeoKey over a user-defined GRS 1980
/// datum (no EPSG CRS code). It builds with no `--crs`, and its ground spacing is the
/// pixel size over UTM's point scale factor there, as `proj -S` computes it.
#[test]
fn user_defined_geokeys_give_the_ground_spacing_gdal_would() {
    let Some(dem) = testdata::imagery_or_skip("olinda_dem_utm25s.tif") else {
        return;
    };
    if !gdal_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("olinda.tess");
    let m = built(&dem, &out);
    let g = m.georef.as_ref().expect("georeferenced");
    let gs = m.ground_spacing.expect("a ground spacing: the CRS is read");
    // The centre of the grid, to longitude/latitude, then UTM 25S's scale factor there.
    let gt = g.geotransform;
    let (cx, cy) = (gt[0] + 55.5 * gt[1], gt[3] + 55.5 * gt[5]);
    let lonlat = run_stdin(
        "cs2cs",
        &["-f", "%.10f", "EPSG:31985", "EPSG:4326"],
        format!("{cx} {cy}\n"),
    );
    let v: Vec<f64> = lonlat
        .split_whitespace()
        .take(2)
        .map(|t| t.parse().unwrap())
        .collect();
    let (lat, lon) = (v[0], v[1]);
    let factors = run_stdin(
        "proj",
        &["-V", "+proj=utm", "+zone=25", "+south", "+ellps=GRS80"],
        format!("{lon} {lat}\n"),
    );
    // `proj -V` prints "Parallel scale (k) : 1.00012345  (…)"; h = k (conformal).
    let line = factors
        .lines()
        .find(|l| l.starts_with("Parallel scale (k)"))
        .unwrap();
    let k: f64 = line
        .split(':')
        .nth(1)
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap();
    let want = gt[1] / k;
    assert!((gs.x - want).abs() < 1e-3, "{} vs {want} (k = {k})", gs.x);
    assert!((gs.y - want).abs() < 1e-3, "{} vs {want}", gs.y);
    // A wrong reading (no scale factor, or UTM's central scale 0.9996) misses by more.
    assert!((gt[1] - want).abs() > 5e-3 && (gt[1] / 0.9996 - want).abs() > 5e-3);
    // `info` names the CRS as the file's citation does, and its PROJ definition.
    let text = info(&out);
    assert!(text.contains("UTM Zone 25, Southern Hemisphere"), "{text}");
    assert!(text.contains("+proj=utm +zone=25 +south"), "{text}");
}

/// aletsch.tif with its CRS keys replaced by an engineering CRS (what GDAL writes for
/// `LOCAL_CS`), beside an ESRI `.prj` of LV95: the same georeferencing and ground
/// spacing as the original, and `info` names EPSG:2056 (PROJ identifies the ESRI WKT).
/// Through a VRT whose `<SRS>` is LV95, the same. A `.prj` PROJ cannot read is an
/// error naming it, with nothing left behind.
#[test]
fn a_prj_sidecar_and_a_vrt_srs_give_the_crs() {
    let Some(src) = testdata::dem_or_skip("aletsch.tif") else {
        return;
    };
    if !gdal_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let reference = built(&src, &dir.path().join("ref.tess"));
    let local = dir.path().join("local.tif");
    run(
        "gdal_translate",
        &[
            "-q",
            "-a_srs",
            "LOCAL_CS[\"arbitrary\"]",
            path_str(&src),
            path_str(&local),
        ],
    );
    // Without the sidecar: no CRS PROJ can use, so no ground spacing.
    let bare = built(&local, &dir.path().join("bare.tess"));
    assert!(bare.ground_spacing.is_none());
    let esri = run("gdalsrsinfo", &["-o", "wkt_esri", "EPSG:2056"]);
    assert!(esri.contains("PROJCS[\"CH1903+_LV95\""), "{esri}");
    std::fs::write(local.with_extension("prj"), &esri).unwrap();
    let out = dir.path().join("prj.tess");
    let m = built(&local, &out);
    let (g, r) = (
        m.georef.as_ref().unwrap(),
        reference.georef.as_ref().unwrap(),
    );
    assert_eq!(g.epsg, Some(2056));
    assert_eq!(g.geotransform, r.geotransform);
    assert_eq!(m.ground_spacing, reference.ground_spacing);
    assert!(info(&out).contains("EPSG:2056"));

    // A VRT over the engineering-CRS file, its <SRS> LV95 (no .prj now).
    std::fs::remove_file(local.with_extension("prj")).unwrap();
    let vrt = dir.path().join("lv95.vrt");
    run(
        "gdalbuildvrt",
        &[
            "-q",
            "-a_srs",
            "EPSG:2056",
            path_str(&vrt),
            path_str(&local),
        ],
    );
    let v = built(&vrt, &dir.path().join("vrt.tess"));
    assert_eq!(v.georef.as_ref().unwrap().epsg, Some(2056));
    assert_eq!(v.ground_spacing, reference.ground_spacing);

    // A .prj that is not a CRS.
    std::fs::write(local.with_extension("prj"), "PROJCS[\"broken\",").unwrap();
    let bad = dir.path().join("bad.tess");
    let o = build(&local, &bad);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("local.prj") && err.contains("PROJ cannot read"),
        "{err}"
    );
    assert!(!bad.exists());
}
