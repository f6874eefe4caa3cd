//! The vertical datum (DECISIONS.md "Real clients"): a GeoTIFF's heights get the vertical
//! datum the file (or its product's file name) states, and the build says so; a build
//! whose datum stays unknown warns, also under `--quiet`, how far Cesium terrain will
//! misplace the terrain (the EGM96 undulation, checked against PROJ's `cs2cs` when
//! installed) and which flag fixes it; `--vertical-datum` still overrides.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod cli_support;
mod gdal;

use cli_support::{bin, build, tmpdir};
use std::path::Path;
use std::process::Output;
use tessera_server::ingest::vertical_shift::VerticalShift;
use tessera_server::ingest::{self, Input};
use tessera_shared::{Pyramid, VerticalDatum, testdata};

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A build at the default log level (what a user sees without `--quiet`).
fn build_logged(input: &Path, out: &Path, extra: &[&str]) -> Output {
    let o = bin()
        .arg("build")
        .arg(input)
        .arg("-o")
        .arg(out)
        .args(["--tile-size", "256"])
        .args(extra)
        .env("RUST_LOG", "info")
        .output()
        .unwrap();
    assert!(o.status.success(), "build failed: {}", stderr(&o));
    o
}

fn datum_of(pyramid: &Path) -> VerticalDatum {
    Pyramid::open_file(pyramid)
        .unwrap()
        .metadata()
        .vertical_datum
}

fn warnings(o: &Output) -> Vec<String> {
    stderr(o)
        .lines()
        .filter(|l| l.starts_with("warning: "))
        .map(str::to_owned)
        .collect()
}

#[test]
fn n46e008_is_egm96_from_its_dted_metadata_and_the_build_says_why() {
    let Some(dem) = testdata::dem_or_skip("N46E008.tif") else {
        return;
    };
    let tmp = tmpdir("datum-dted");
    let out = tmp.path().join("n46.tess");
    let o = build_logged(&dem, &out, &[]);
    let err = stderr(&o);
    assert!(
        err.contains("vertical datum egm96 (GeoTIFF GDAL metadata DTED_VerticalDatum=E96)"),
        "{err}"
    );
    assert!(warnings(&o).is_empty(), "{err}");
    assert_eq!(datum_of(&out), VerticalDatum::Egm96);
    // What `info` prints.
    let info = bin().arg("info").arg(&out).output().unwrap();
    assert!(
        String::from_utf8_lossy(&info.stdout).contains("heights ref egm96"),
        "{info:?}"
    );
}

#[test]
fn the_flag_still_overrides_what_the_file_states() {
    let Some(dem) = testdata::dem_or_skip("N46E008.tif") else {
        return;
    };
    let tmp = tmpdir("datum-flag");
    let out = tmp.path().join("n46.tess");
    let o = build_logged(&dem, &out, &["--vertical-datum", "ellipsoid"]);
    let err = stderr(&o);
    assert!(
        err.contains("--vertical-datum ellipsoid overrides the input's own egm96 (GeoTIFF GDAL metadata DTED_VerticalDatum=E96)"),
        "{err}"
    );
    assert_eq!(datum_of(&out), VerticalDatum::Ellipsoid);
}

/// Reprojection moves the samples, not their reference: an `.hgt` stays EGM96.
#[test]
fn reprojecting_keeps_the_datum() {
    let Some(dem) = testdata::dem_or_skip("N44W072.hgt") else {
        return;
    };
    let tmp = tmpdir("datum-to");
    let out = tmp.path().join("merc.tess");
    let o = build(&dem, &out, &["--to", "EPSG:3857"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(warnings(&o).is_empty(), "{}", stderr(&o));
    assert_eq!(datum_of(&out), VerticalDatum::Egm96);
}

/// luxembourg_elev.tif (geographic, no vertical statement) copied under `name`.
fn renamed_luxembourg(dir: &Path, name: &str) -> Option<std::path::PathBuf> {
    let dem = testdata::dem_or_skip("luxembourg_elev.tif")?;
    let path = dir.join(name);
    std::fs::copy(dem, &path).unwrap();
    Some(path)
}

#[test]
fn a_product_file_name_gives_the_datum() {
    let tmp = tmpdir("datum-name");
    for (name, want, product) in [
        (
            "n46_e008_1arc_v3.tif",
            VerticalDatum::Egm96,
            "USGS SRTM GeoTIFF",
        ),
        (
            "Copernicus_DSM_COG_10_N49_00_E005_00_DEM.tif",
            VerticalDatum::Egm2008,
            "Copernicus DEM",
        ),
    ] {
        let Some(input) = renamed_luxembourg(tmp.path(), name) else {
            return;
        };
        let out = tmp.path().join("named.tess");
        let o = build_logged(&input, &out, &[]);
        let err = stderr(&o);
        assert!(
            err.contains(&format!("(file name {name} matches {product})")),
            "{err}"
        );
        assert!(warnings(&o).is_empty(), "{err}");
        assert_eq!(datum_of(&out), want, "{name}");
    }
}

#[test]
fn a_folder_or_vrt_of_named_tiles_gets_their_datum() {
    let tmp = tmpdir("datum-mosaic");
    let tiles = tmp.path().join("tiles");
    std::fs::create_dir(&tiles).unwrap();
    // The same grid twice: overlapping, and agreeing sample for sample.
    for name in ["n49_e005_3arc_v2.tif", "srtm_38_03.tif"] {
        if renamed_luxembourg(&tiles, name).is_none() {
            return;
        }
    }
    let out = tmp.path().join("dir.tess");
    let o = build(&tiles, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(warnings(&o).is_empty(), "{}", stderr(&o));
    assert_eq!(datum_of(&out), VerticalDatum::Egm96);

    let vrt = tiles.join("tiles.vrt");
    std::fs::write(
        &vrt,
        r#"<VRTDataset rasterXSize="95" rasterYSize="90">
  <GeoTransform>5.741666666666666, 0.008333333333333, 0, 50.191666666666663, 0, -0.008333333333333</GeoTransform>
  <VRTRasterBand dataType="Int16" band="1">
    <SimpleSource>
      <SourceFilename relativeToVRT="1">srtm_38_03.tif</SourceFilename>
      <SourceBand>1</SourceBand>
    </SimpleSource>
  </VRTRasterBand>
</VRTDataset>
"#,
    )
    .unwrap();
    let out = tmp.path().join("vrt.tess");
    let o = build_logged(&vrt, &out, &[]);
    let err = stderr(&o);
    assert!(
        err.contains("file name srtm_38_03.tif matches CGIAR-CSI SRTM 4.1"),
        "{err}"
    );
    assert_eq!(datum_of(&out), VerticalDatum::Egm96);

    // Tiles in different datums cannot be mixed: one line naming two of them and the
    // flag that converts them, and nothing written.
    std::fs::remove_file(&vrt).unwrap();
    let copernicus = "Copernicus_DSM_COG_10_N49_00_E005_00_DEM.tif";
    renamed_luxembourg(&tiles, copernicus).unwrap();
    let out = tmp.path().join("mixed.tess");
    let o = build(&tiles, &out, &[]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("different vertical datums")
            && err.contains(copernicus)
            && err.contains("says egm96")
            && err.contains("egm2008")
            && err.contains("--to-vertical"),
        "{err}"
    );
    assert!(!out.exists());
    // The user's word for all of them settles it.
    let o = build(&tiles, &out, &["--vertical-datum", "egm96"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(datum_of(&out), VerticalDatum::Egm96);
}

/// `cs2cs`'s EGM96 undulations (ellipsoidal height of H = 0) at `lon lat` points,
/// with the grid the server finds; `None` without `cs2cs` or the grid.
fn cs2cs_undulations(points: &[(f64, f64)]) -> Option<Vec<f64>> {
    use std::fmt::Write as _;
    use std::io::Write as _;
    let grid = tessera_server::geoid::find(None).filter(|p| p.is_file())?;
    let mut child = std::process::Command::new("cs2cs")
        .args([
            "-f",
            "%.4f",
            &format!(
                "+proj=longlat +datum=WGS84 +geoidgrids={} +type=crs",
                grid.display()
            ),
            "+to",
            "EPSG:4979",
        ])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .ok()?;
    let mut input = String::new();
    for (x, y) in points {
        writeln!(input, "{x} {y} 0").unwrap();
    }
    child
        .stdin
        .take()
        .unwrap()
        .write_all(input.as_bytes())
        .unwrap();
    let out = child.wait_with_output().ok()?;
    out.status.success().then(|| {
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .map(|l| l.split_whitespace().nth(2).unwrap().parse().unwrap())
            .collect()
    })
}

/// The `A..B m too low` (or `A m too low`) of a warning.
fn too_low(warning: &str) -> (f64, f64) {
    let end = warning.find(" m too low").expect("an error in metres");
    let start = warning[..end].rfind(' ').unwrap() + 1;
    let span = &warning[start..end];
    let (a, b) = span.split_once("..").unwrap_or((span, span));
    (a.parse().unwrap(), b.parse().unwrap())
}

/// Unknown heights on Earth: the warning names the input, Cesium's ellipsoid, the
/// error in metres and the flag; `--vertical-datum egm96` silences it.
fn check_unknown_warning(dem_name: &str, corners: &[(f64, f64)], expect: (f64, f64)) {
    let Some(dem) = testdata::dem_or_skip(dem_name) else {
        return;
    };
    let tmp = tmpdir("datum-unknown");
    let out = tmp.path().join("u.tess");
    // --quiet: the warning still shows, after the summary.
    let o = build(&dem, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(datum_of(&out), VerticalDatum::Unknown);
    let w = warnings(&o);
    assert_eq!(w.len(), 1, "{}", stderr(&o));
    let w = &w[0];
    eprintln!("{w}");
    for says in [
        dem_name,
        "vertical datum is unknown (the input states none)",
        "as heights above the WGS 84 ellipsoid",
        "EGM96 geoid undulation",
        "--vertical-datum egm96",
        "--vertical-datum egm2008",
        "--vertical-datum ellipsoid",
    ] {
        assert!(w.contains(says), "the warning does not say {says:?}: {w}");
    }
    if tessera_server::geoid::find(None).is_some_and(|p| p.is_file()) {
        let (lo, hi) = too_low(w);
        assert!(
            expect.0 <= lo && lo <= hi && hi <= expect.1,
            "{lo}..{hi} m is outside the expected {expect:?}: {w}"
        );
        // PROJ's values at the footprint's corners and centre lie in the range (the
        // warning samples a 5×5 lattice, corners included, so within rounding).
        if let Some(proj) = cs2cs_undulations(corners) {
            for n in proj {
                assert!(
                    lo - 0.06 <= n && n <= hi + 0.06,
                    "cs2cs gives {n} m, outside {lo}..{hi}: {w}"
                );
            }
        } else {
            eprintln!("cs2cs is not installed: checked against the known range only");
        }
    } else {
        assert!(w.contains("up to ~100 m off"), "{w}");
    }
    let o = build(&dem, &out, &["--vertical-datum", "egm96"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(warnings(&o).is_empty(), "{}", stderr(&o));
    assert_eq!(datum_of(&out), VerticalDatum::Egm96);
}

#[test]
fn unknown_swiss_heights_warn_with_the_alpine_undulation() {
    // aletsch.tif: CH1903+/LV95 (EPSG:2056), its corners and centre from gdalinfo.
    // EGM96 lies 49–52 m above the ellipsoid there.
    check_unknown_warning(
        "aletsch.tif",
        &[
            (7.45400, 46.81296),
            (7.45385, 46.25517),
            (8.39221, 46.80899),
            (8.38244, 46.25124),
            (7.92063, 46.53305),
        ],
        (48.5, 52.0),
    );
}

#[test]
fn unknown_luxembourg_heights_warn_with_their_undulation() {
    // luxembourg_elev.tif: WGS 84 lon/lat; EGM96 lies some 47.5–48.5 m up there.
    check_unknown_warning(
        "luxembourg_elev.tif",
        &[
            (5.74583, 50.18750),
            (6.52917, 50.18750),
            (5.74583, 49.44583),
            (6.52917, 49.44583),
            (6.13750, 49.81667),
        ],
        (47.0, 49.0),
    );
}

/// `cs2cs` on (latitude, longitude, height) triples: PROJ's own answer.
fn cs2cs(from: &str, to: &str, points: &[[f64; 3]]) -> Vec<f64> {
    let text = points.iter().fold(String::new(), |mut t, [lat, lon, h]| {
        use std::fmt::Write as _;
        let _ = writeln!(t, "{lat:.12} {lon:.12} {h:.6}");
        t
    });
    gdal::run_stdin("cs2cs", &["-f", "%.6f", from, to], text)
        .lines()
        .map(|l| l.split_whitespace().nth(2).unwrap().parse().unwrap())
        .collect()
}

/// `--to-vertical ellipsoid` on an SRTM tile (EGM96 heights) against PROJ's `cs2cs
/// EPSG:4326+5773 EPSG:4979` (the compound-CRS form: `+geoidgrids=` in a `+to`
/// pipeline is silently ignored by PROJ 9.1's cs2cs) at 20 samples: the converted
/// heights as read, within 1 mm, and the pyramid's within its quantization error more.
/// A conversion that dropped the geoid would be 48–52 m off here.
#[test]
fn srtm_heights_to_the_ellipsoid_match_cs2cs() {
    let Some(dem) = testdata::dem_or_skip("N46E008.tif") else {
        return;
    };
    if std::process::Command::new("cs2cs")
        .arg("--version")
        .output()
        .is_err()
    {
        assert!(
            std::env::var_os("CI").is_none(),
            "cs2cs (proj-bin) is missing and CI is set"
        );
        eprintln!("SKIPPED: cs2cs is absent (apt-get install proj-bin)");
        return;
    }
    let raw = |path: &Path| {
        let Input::Rows(mut r) = ingest::open(path.to_str().unwrap()).unwrap() else {
            panic!()
        };
        let i = r.info().clone();
        let mut v = vec![0f32; (i.width * i.height) as usize];
        r.read_rows(&mut v).unwrap();
        (i, v)
    };
    let (info, original) = raw(&dem);
    let Input::Rows(rows) = ingest::open(dem.to_str().unwrap()).unwrap() else {
        panic!()
    };
    let mut shifted = VerticalShift::new(
        rows,
        VerticalDatum::Egm96,
        VerticalDatum::Ellipsoid,
        1.0,
        &[],
    )
    .unwrap();
    let mut converted = vec![0f32; original.len()];
    ingest::RowSource::read_rows(&mut shifted, &mut converted).unwrap();
    let tmp = tmpdir("datum-to-ellipsoid");
    let out = tmp.path().join("ellipsoid.tess");
    let o = build(&dem, &out, &["--to-vertical", "ellipsoid"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let p = Pyramid::open_file(&out).unwrap();
    assert_eq!(p.metadata().vertical_datum, VerticalDatum::Ellipsoid);
    let g = info.georef.as_ref().unwrap();
    let w = info.width;
    let mut picks = Vec::new();
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    while picks.len() < 20 {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1);
        let i = ((state >> 33) % u64::from(w * info.height)) as usize;
        if f64::from(original[i]) != info.nodata.unwrap_or(f64::NAN) {
            picks.push(i);
        }
    }
    let points: Vec<[f64; 3]> = picks
        .iter()
        .map(|&i| {
            let [lon, lat] = g.sample_centre((i % w as usize) as f64, (i / w as usize) as f64);
            [lat, lon, f64::from(original[i])]
        })
        .collect();
    let want = cs2cs("EPSG:4326+5773", "EPSG:4979", &points);
    let finest = finest_heights(&p);
    let q = p.metadata().quantization.max_error;
    for ((&i, p), want) in picks.iter().zip(&points).zip(&want) {
        let got = f64::from(converted[i]);
        // f32 holds a 4 km height to 0.25 mm.
        assert!((got - want).abs() < 1e-3, "{p:?}: {got} vs cs2cs {want}");
        assert!(
            (want - p[2] - 50.0).abs() < 5.0,
            "the undulation here is about 48-52 m"
        );
        let stored = f64::from(finest[i]);
        assert!(
            (stored - want).abs() <= q + 1e-3,
            "{p:?}: pyramid {stored} vs {want}"
        );
    }
}

/// The pyramid's finest samples in metres (NaN where no terrain cell touches them).
fn finest_heights(p: &Pyramid<tessera_shared::FileSource>) -> Vec<f32> {
    let g = *p.geometry();
    let (w, h, t) = (
        g.width() as usize,
        g.height() as usize,
        g.tile_size() as usize,
    );
    let q = p.metadata().quantization;
    let mut out = vec![f32::NAN; w * h];
    for tile in g.present_tiles(g.finest()) {
        let Some(rec) = p.read_tile(tile).unwrap() else {
            continue;
        };
        let (gx, gy) = g.origin(tile);
        for y in 0..=t {
            for x in 0..=t {
                let (sx, sy) = (gx as usize + x, gy as usize + y);
                if sx < w && sy < h {
                    out[sy * w + sx] = q.height(rec.heights[y * (t + 1) + x]) as f32;
                }
            }
        }
    }
    out
}
