//! `build --crs` and `--bounds`: georeferencing a plain 16-bit PNG from flags (the real
//! Moon mosaic, heights and all), overriding a GeoTIFF's own CRS, reprojecting from an
//! assigned CRS with `--to`, and the errors: each a non-zero exit whose message names
//! the problem, with no output left behind.

#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed test

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;
use std::process::{Command, Output};
use tessera_server::crs::Crs;
use tessera_shared::{Pyramid, RasterType, TileId, testdata};

const MOON: &str = "+proj=longlat +R=1737400 +no_defs";

fn tmpdir(tag: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("tessera-georef-{tag}-"))
        .tempdir()
        .unwrap()
}

fn build(inputs: &[&Path], out: &Path, extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_tessera-server"))
        .arg("build")
        .args(inputs)
        .arg("-o")
        .arg(out)
        .arg("--quiet")
        .args(extra)
        .output()
        .unwrap()
}

/// A `size × size` 16-bit grayscale PNG of a gentle ramp (no georeferencing).
fn tiny_png(path: &Path, size: u32) {
    let mut enc = png::Encoder::new(BufWriter::new(File::create(path).unwrap()), size, size);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Sixteen);
    let mut w = enc.write_header().unwrap();
    let data: Vec<u8> = (0..size * size)
        .flat_map(|i| {
            u16::try_from(1000 + i % size + i / size)
                .unwrap()
                .to_be_bytes()
        })
        .collect();
    w.write_image_data(&data).unwrap();
}

/// The 16-bit value of pixel `(x, y)` of a grayscale PNG, decoded here (not by the
/// server's reader).
fn png_pixel(path: &Path, x: u32, y: u32) -> u16 {
    let mut dec = png::Decoder::new(std::io::BufReader::new(File::open(path).unwrap()));
    dec.set_transformations(png::Transformations::IDENTITY);
    let mut reader = dec.read_info().unwrap();
    assert_eq!(reader.info().bit_depth, png::BitDepth::Sixteen);
    assert_eq!(reader.info().color_type, png::ColorType::Grayscale);
    for _ in 0..y {
        reader.next_row().unwrap().unwrap();
    }
    let row = reader.next_row().unwrap().unwrap();
    let i = 2 * x as usize;
    u16::from_be_bytes([row.data()[i], row.data()[i + 1]])
}

/// The stored height of sample `(x, y)` at the finest level.
fn sample(p: &Pyramid<tessera_shared::FileSource>, x: u32, y: u32) -> f64 {
    let g = *p.geometry();
    let t = g.tile_size();
    let tile = TileId::new(g.finest(), x / t, y / t).unwrap();
    let rec = p.read_tile(tile).unwrap().expect("the tile holds terrain");
    let (cx, cy) = (x % t, y % t);
    // The mask is per cell (the square right of and below a sample): a sample is
    // terrain when a cell it is a corner of is.
    let cell = |dx: u32, dy: u32| {
        cx >= dx && cy >= dy && cx - dx < t && cy - dy < t && rec.mask.is_valid(cx - dx, cy - dy)
    };
    assert!(
        cell(0, 0) || cell(1, 0) || cell(0, 1) || cell(1, 1),
        "sample ({x}, {y}) is no-data"
    );
    p.metadata()
        .quantization
        .height(rec.heights[(cy * (t + 1) + cx) as usize])
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A failure whose stderr says each of `says`, with no output file or partial left.
fn assert_clean_failure(o: &Output, says: &[&str], out: &Path) {
    let err = stderr(o);
    assert!(!o.status.success(), "expected failure, got success: {err}");
    for s in says {
        assert!(err.contains(s), "stderr does not say {s:?}: {err}");
    }
    assert!(!out.exists(), "{} exists after a failure", out.display());
    let left: Vec<_> = std::fs::read_dir(out.parent().unwrap())
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".partial") || n.contains(".tess"))
        .collect();
    assert!(left.is_empty(), "left behind: {left:?}");
}

#[test]
fn the_moon_png_georeferenced_from_flags() {
    let Some(png) = testdata::dem_or_skip("moon_crisium_gld100_4096.png") else {
        return;
    };
    let tmp = tmpdir("moon");
    let out = tmp.path().join("moon.tess");
    let o = build(
        &[&png],
        &out,
        &[
            "--offset",
            "-10000",
            "--crs",
            MOON,
            "--bounds",
            "51,8.9921875,67,24.9921875",
            "--vertical-datum",
            "ellipsoid",
        ],
    );
    assert!(o.status.success(), "build failed: {}", stderr(&o));
    let p = Pyramid::open_file(&out).unwrap();
    let m = p.metadata();
    let g = m.georef.as_ref().expect("georeferenced");
    let step = 1.0 / 256.0;
    assert_eq!(g.geotransform, [51.0, step, 0.0, 24.992_187_5, 0.0, -step]);
    assert_eq!(
        g.extent(4096, 4096),
        [51.0, 8.992_187_5, 67.0, 24.992_187_5]
    );
    assert_eq!(g.raster_type, RasterType::PixelIsArea);
    // PROJ's own spelling of the definition.
    assert_eq!(g.proj.as_deref(), Some(&*format!("{MOON} +type=crs")));
    assert_eq!(g.epsg, None);
    let crs = Crs::of(g).expect("the stored PROJ string parses");
    assert!(crs.is_geographic());
    assert_eq!(crs.body_radii(), Some((1_737_400.0, 1_737_400.0)));
    // The data's README: 118.4506 m north–south, 118.45·cos φ east–west (φ ≈ 17° here).
    let gs = m
        .ground_spacing
        .expect("a ground spacing on the Moon's sphere");
    assert!((gs.y - 118.45).abs() < 0.5, "north–south {} m", gs.y);
    let lat = (24.992_187_5f64 - 2048.0 * step).to_radians();
    assert!(
        (gs.x - 118.4506 * lat.cos()).abs() < 0.01,
        "east–west {} m",
        gs.x
    );
    assert_eq!(m.vertical_datum, tessera_shared::VerticalDatum::Ellipsoid);
    // Heights are the PNG's values − 10000, exactly (integers are stored losslessly).
    for (x, y) in [(0, 0), (1234, 2345), (4095, 4095), (2048, 17)] {
        let want = f64::from(png_pixel(&png, x, y)) - 10_000.0;
        let got = sample(&p, x, y);
        assert!(
            (got - want).abs() <= m.quantization.max_error + 1e-9,
            "sample ({x}, {y}): {got} vs {want}"
        );
    }
}

#[test]
fn bounds_without_a_crs_is_an_error() {
    let tmp = tmpdir("nocrs");
    let png = tmp.path().join("plain.png");
    tiny_png(&png, 16);
    let out = tmp.path().join("out.tess");
    let o = build(&[&png], &out, &["--bounds", "0,0,16,16"]);
    assert_clean_failure(&o, &["plain.png", "--bounds needs a CRS"], &out);
    assert_eq!(stderr(&o).trim().lines().count(), 1, "{}", stderr(&o));
}

#[test]
fn crs_without_bounds_for_a_png_is_an_error() {
    let tmp = tmpdir("nogt");
    let png = tmp.path().join("plain.png");
    tiny_png(&png, 16);
    let out = tmp.path().join("out.tess");
    let o = build(&[&png], &out, &["--crs", MOON]);
    assert_clean_failure(&o, &["plain.png", "--crs needs a geotransform"], &out);
}

#[test]
fn bad_bounds_and_crs_values_are_errors() {
    let tmp = tmpdir("bad");
    let png = tmp.path().join("plain.png");
    tiny_png(&png, 16);
    let out = tmp.path().join("out.tess");
    for (bounds, says) in [
        ("67,9,51,25", "west 67 is not less than east 51"),
        ("51,9,51,25", "west 51 is not less than east 51"),
        ("51,25,67,9", "south 25 is not less than north 9"),
        ("51,9,67", "want 4 numbers"),
        ("51,9,67,NaN", "north is NaN"),
        ("-1,-1,west,1", "east \"west\" is not a number"),
    ] {
        let o = build(&[&png], &out, &["--crs", MOON, "--bounds", bounds]);
        assert_clean_failure(&o, &["--bounds", says], &out);
    }
    let o = build(&[&png], &out, &["--crs", "EPSG:1", "--bounds", "0,0,1,1"]);
    assert_clean_failure(
        &o,
        &["--crs", "EPSG:1 is not a CRS in PROJ's database"],
        &out,
    );
    let o = build(&[&png], &out, &["--crs", "moon", "--bounds", "0,0,1,1"]);
    assert_clean_failure(&o, &["--crs", "neither EPSG:CODE nor a PROJ string"], &out);
    // Latitudes past the poles in a geographic CRS (metres by mistake).
    let o = build(
        &[&png],
        &out,
        &[
            "--crs",
            "EPSG:4326",
            "--bounds",
            "500000,4000000,500160,4000160",
        ],
    );
    assert_clean_failure(&o, &["plain.png", "past the poles"], &out);
}

#[test]
fn bounds_are_refused_for_a_mosaic() {
    let tmp = tmpdir("mosaic");
    let (a, b) = (tmp.path().join("a.png"), tmp.path().join("b.png"));
    tiny_png(&a, 16);
    tiny_png(&b, 16);
    let out = tmp.path().join("out.tess");
    let o = build(&[&a, &b], &out, &["--crs", MOON, "--bounds", "0,0,1,1"]);
    assert_clean_failure(&o, &["a.png", "--bounds places one raster"], &out);
}

/// `--to` starts from the CRS `--crs` assigns: a UTM 32N square near the central
/// meridian (9° E) lands at 9° E, 45.1° N in WGS 84.
#[test]
fn to_reprojects_from_the_assigned_crs() {
    let tmp = tmpdir("to");
    let png = tmp.path().join("utm.png");
    tiny_png(&png, 16);
    let out = tmp.path().join("out.tess");
    let o = build(
        &[&png],
        &out,
        &[
            "--crs",
            "EPSG:32632",
            "--bounds",
            "500000,5000000,500160,5000160",
            "--to",
            "EPSG:4326",
        ],
    );
    assert!(o.status.success(), "build failed: {}", stderr(&o));
    let p = Pyramid::open_file(&out).unwrap();
    let m = p.metadata();
    let g = m.georef.as_ref().unwrap();
    assert_eq!(g.epsg, Some(4326));
    let [w, s, e, n] = g.extent(m.width, m.height);
    let utm = Crs::from_epsg(32632).unwrap();
    let [lon, lat] = utm.to_lon_lat(500_080.0, 5_000_080.0).unwrap();
    assert!(
        w < lon && lon < e && s < lat && lat < n,
        "{lon} {lat} in {w} {s} {e} {n}"
    );
    assert!(
        (lon - 9.0).abs() < 0.01 && (lat - 45.15).abs() < 0.01,
        "{lon} {lat}"
    );
}

/// A GeoTIFF's own CRS gives way to `--crs`, with a warning naming both; its grid stays.
#[test]
fn crs_overrides_a_geotiffs_own_with_a_warning() {
    let Some(tif) = testdata::dem_or_skip("luxembourg_elev.tif") else {
        return;
    };
    let tmp = tmpdir("override");
    let out = tmp.path().join("out.tess");
    let plain = tmp.path().join("plain.tess");
    let o = build(&[&tif], &plain, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let own = Pyramid::open_file(&plain)
        .unwrap()
        .metadata()
        .georef
        .clone()
        .unwrap();
    assert_eq!(own.epsg, Some(4326));
    // Not --quiet: the warning is what is checked.
    let o = Command::new(env!("CARGO_BIN_EXE_tessera-server"))
        .args(["build", tif.to_str().unwrap(), "-o", out.to_str().unwrap()])
        .args(["--crs", "EPSG:4258"])
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("--crs EPSG:4258 overrides the input's own CRS EPSG:4326"),
        "{err}"
    );
    let g = Pyramid::open_file(&out)
        .unwrap()
        .metadata()
        .georef
        .clone()
        .unwrap();
    assert_eq!(g.epsg, Some(4258));
    assert_eq!(g.crs_name.as_deref(), Some("ETRS89"));
    assert_eq!(g.geotransform, own.geotransform);
    assert_eq!(g.raster_type, own.raster_type);
}
