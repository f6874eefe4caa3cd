//! `build DEM --imagery IMAGE --bands 3,2,1` (DECISIONS.md "Imagery pyramids") on the
//! real Olinda data: Landsat 7 (28.5 m, EPSG:31985) over its 90 m DEM. The imagery tiles
//! are compared with GDAL's own resampling of the source onto exactly the tile's texel
//! grid (`gdalwarp -te … -ts n n -r bilinear`), which is independent of our code; the
//! imagery pyramid's tiles are the DEM's; bad inputs name the file and leave nothing.

#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed test

mod gdal;

use gdal::{gdal_or_skip, path_str, run};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use tessera_shared::{FileSource, Pyramid, TileId, testdata};

/// UTM 25S on GRS80, as the DEM's own (EPSG-less) WKT says: a different definition
/// from the image's EPSG:31985 (SIRGAS 2000, the same ellipsoid), so that the
/// DEM→image mapping goes through the projection library.
const DEM_CRS: &str = "+proj=utm +zone=25 +south +ellps=GRS80 +units=m +no_defs";

struct Olinda {
    dem: PathBuf,
    image: PathBuf,
}

fn olinda() -> Option<Olinda> {
    Some(Olinda {
        dem: testdata::imagery_or_skip("olinda_dem_utm25s.tif")?,
        image: testdata::imagery_or_skip("L7_ETMs.tif")?,
    })
}

fn build(dem: &Path, out: &Path, extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_tessera-server"))
        .arg("build")
        .arg(dem)
        .args(["--tile-size", "64", "--quiet", "-o"])
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

fn build_ok(dem: &Path, out: &Path, extra: &[&str]) {
    let o = build(dem, out, extra);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// RGB texels of a finest tile's record.
fn texels(p: &Pyramid<FileSource>, tile: TileId) -> (u32, Vec<u8>) {
    let bytes = p.read_record(tile).unwrap().expect("present");
    let img = image::load_from_memory_with_format(&bytes, image::ImageFormat::Jpeg).unwrap();
    (img.width(), img.to_rgb8().into_raw())
}

/// GDAL's bilinear resampling of `rgb_source` (bands already R, G, B) onto the texel
/// grid of finest tile `tile`: texel `(u, v)` is centred at tile sample
/// `((u + ½)·T/n, (v + ½)·T/n)` (FORMAT.md), so the texel grid's outer edge runs
/// through the centres of the tile's corner samples: that is `-te`.
fn gdal_tile(
    rgb_source: &Path,
    dem_gt: [f64; 6],
    tile: TileId,
    t: u32,
    n: u32,
    dir: &Path,
) -> Vec<u8> {
    let (x0, y0) = (f64::from(tile.x() * t), f64::from(tile.y() * t));
    let west = dem_gt[0] + (x0 + 0.5) * dem_gt[1];
    let north = dem_gt[3] + (y0 + 0.5) * dem_gt[5];
    let east = west + f64::from(t) * dem_gt[1];
    let south = north + f64::from(t) * dem_gt[5];
    let out = dir.join(format!("gdal-{}-{}.tif", tile.x(), tile.y()));
    let _ = std::fs::remove_file(&out);
    run(
        "gdalwarp",
        &[
            "-q",
            "-r",
            "bilinear",
            "-et",
            "0",
            "-t_srs",
            "EPSG:31985",
            "-te",
            &west.to_string(),
            &south.to_string(),
            &east.to_string(),
            &north.to_string(),
            "-ts",
            &n.to_string(),
            &n.to_string(),
            path_str(rgb_source),
            path_str(&out),
        ],
    );
    let mut d = tiff::decoder::Decoder::new(std::fs::File::open(&out).unwrap()).unwrap();
    match d.read_image().unwrap() {
        tiff::decoder::DecodingResult::U8(v) => v,
        _ => panic!("8-bit"),
    }
}

/// Mean absolute channel difference over the texels GDAL filled (not 0,0,0: outside
/// the image), and how many there were.
fn mean_abs_diff(ours: &[u8], gdal: &[u8]) -> (f64, usize) {
    let (mut sum, mut n) = (0u64, 0usize);
    for (a, b) in ours.chunks_exact(3).zip(gdal.chunks_exact(3)) {
        if b == [0, 0, 0] {
            continue;
        }
        sum += a
            .iter()
            .zip(b)
            .map(|(x, y)| u64::from(x.abs_diff(*y)))
            .sum::<u64>();
        n += 1;
    }
    (sum as f64 / (3 * n) as f64, n)
}

/// The source's bands 3, 2, 1 as an RGB GeoTIFF (GDAL, for the references).
fn rgb_copy(image: &Path, dir: &Path) -> PathBuf {
    let out = dir.join("rgb.tif");
    run(
        "gdal_translate",
        &[
            "-q",
            "-b",
            "3",
            "-b",
            "2",
            "-b",
            "1",
            path_str(image),
            path_str(&out),
        ],
    );
    out
}

/// JPEG at quality 90 and our bilinear against GDAL's over the same grid: within
/// this mean channel error. Misaligned by one DEM cell (4 texels), the same tiles
/// differ by several times more (asserted below), so the bound has teeth.
const MEAN_TOLERANCE: f64 = 3.0;

#[test]
fn imagery_tiles_have_the_source_colours_on_the_dems_tiles() {
    let Some(o) = olinda() else { return };
    if !gdal_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("olinda.tess");
    // No --crs: the DEM's own CRS is user-defined GeoKeys (UTM zone 25S by
    // ProjectionGeoKey over a GRS 1980 datum, no EPSG code), read as GDAL reads them.
    build_ok(
        &o.dem,
        &out,
        &["--imagery", path_str(&o.image), "--bands", "3,2,1"],
    );
    let img_path = out.with_extension("tessimg");
    let dem = Pyramid::open_file(&out).unwrap();
    let img = Pyramid::open_imagery(FileSource::open(&img_path).unwrap()).unwrap();
    let meta = img.imagery().unwrap();

    // Aligned with the DEM: its metadata verbatim, the same levels and the same tiles
    // (ids and partial flags), and nothing else.
    assert_eq!(&meta.dem, dem.metadata());
    assert_eq!(meta.bands, [3, 2, 1]);
    // 90 m cells, 28.5 m pixels: 4 texels per cell (the documented rule).
    assert_eq!(meta.texels, 256);
    let g = *dem.geometry();
    assert_eq!(img.geometry(), &g);
    let mut tiles = 0;
    for level in g.levels() {
        let a = dem.index(level).unwrap();
        let b = img.index(level).unwrap();
        for (m, (d, i)) in a.iter().zip(b).enumerate() {
            assert_eq!(d.is_present(), i.is_present(), "level {level} morton {m}");
            assert_eq!(d.flags, i.flags, "level {level} morton {m}");
            tiles += usize::from(i.is_present());
        }
    }
    assert_eq!(tiles, 5, "2 levels: the root and 4 finest tiles");

    // Colours: every finest tile against GDAL's resampling of the source.
    let rgb = rgb_copy(&o.image, dir.path());
    let gt = dem.metadata().georef.as_ref().unwrap().geotransform;
    let mut worst = 0f64;
    for tile in g.present_tiles(g.finest()) {
        let (n, ours) = texels(&img, tile);
        assert_eq!(n, 256);
        let reference = gdal_tile(&rgb, gt, tile, 64, n, dir.path());
        let (err, filled) = mean_abs_diff(&ours, &reference);
        assert!(
            filled > 1000,
            "{tile}: only {filled} texels inside the image"
        );
        assert!(err <= MEAN_TOLERANCE, "{tile}: mean channel error {err:.2}");
        worst = worst.max(err);
        // The same comparison one DEM cell off: a misplaced drape would look like this.
        let mut shifted = reference.clone();
        let row = n as usize * 3;
        for y in 0..n as usize {
            shifted[y * row..(y + 1) * row].rotate_left(4 * 3);
        }
        let (off, _) = mean_abs_diff(&ours, &shifted);
        assert!(
            off > 2.0 * err.max(1.0),
            "{tile}: shifted {off:.2} vs aligned {err:.2}"
        );
    }
    eprintln!("worst mean channel error against gdalwarp: {worst:.2}");

    // A known ground point (pixel (300, 150) of the image: the sea east of Olinda)
    // has the colour gdallocationinfo reads there, in the tile that covers it.
    let [e, n] = [288_776.25 + 300.5 * 28.5, 9_120_760.75 - 150.5 * 28.5];
    let want: Vec<u8> = run(
        "gdallocationinfo",
        &[
            "-valonly",
            "-geoloc",
            "-b",
            "3",
            "-b",
            "2",
            "-b",
            "1",
            path_str(&o.image),
            &e.to_string(),
            &n.to_string(),
        ],
    )
    .split_whitespace()
    .map(|v| v.parse().unwrap())
    .collect();
    let col = (e - gt[0]) / gt[1] - 0.5;
    let row = (n - gt[3]) / gt[5] - 0.5;
    let tile = TileId::new(g.finest(), (col / 64.0) as u32, (row / 64.0) as u32).unwrap();
    let (tn, ours) = texels(&img, tile);
    let u = ((col - f64::from(tile.x() * 64)) * f64::from(tn) / 64.0) as usize;
    let v = ((row - f64::from(tile.y() * 64)) * f64::from(tn) / 64.0) as usize;
    let got = &ours[(v * tn as usize + u) * 3..][..3];
    for c in 0..3 {
        assert!(
            got[c].abs_diff(want[c]) <= 6,
            "at E {e} N {n}: texel {got:?}, gdallocationinfo {want:?}"
        );
    }

    // And verify accepts the file.
    let v = Command::new(env!("CARGO_BIN_EXE_tessera-server"))
        .arg("verify")
        .arg(&img_path)
        .output()
        .unwrap();
    assert!(v.status.success(), "{}", String::from_utf8_lossy(&v.stdout));
}

/// Any CRS: the same scene warped by GDAL to geographic coordinates (EPSG:4326) drapes
/// onto the same tiles with the same colours, within the extra blur of a second
/// resampling; and a PNG of bands 3,2,1 with a world file and `.prj` gives exactly
/// the records of the GeoTIFF it was made from.
#[test]
fn imagery_in_another_crs_or_format_drapes_the_same() {
    let Some(o) = olinda() else { return };
    if !gdal_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let utm = dir.path().join("utm.tess");
    build_ok(
        &o.dem,
        &utm,
        &[
            "--crs",
            DEM_CRS,
            "--imagery",
            path_str(&o.image),
            "--bands",
            "3,2,1",
        ],
    );
    let rgb = rgb_copy(&o.image, dir.path());
    let geographic = dir.path().join("rgb4326.tif");
    run(
        "gdalwarp",
        &[
            "-q",
            "-t_srs",
            "EPSG:4326",
            "-r",
            "bilinear",
            "-tr",
            "0.00025",
            "0.00025",
            path_str(&rgb),
            path_str(&geographic),
        ],
    );
    let wgs = dir.path().join("wgs.tess");
    build_ok(
        &o.dem,
        &wgs,
        &["--crs", DEM_CRS, "--imagery", path_str(&geographic)],
    );
    let a =
        Pyramid::open_imagery(FileSource::open(&utm.with_extension("tessimg")).unwrap()).unwrap();
    let b =
        Pyramid::open_imagery(FileSource::open(&wgs.with_extension("tessimg")).unwrap()).unwrap();
    // 0.00025° is ~27.6 m east-west there: as for the UTM scene, 4 texels per cell.
    assert_eq!(b.imagery().unwrap().texels, a.imagery().unwrap().texels);
    let g = *a.geometry();
    for tile in g.present_tiles(g.finest()) {
        let (_, x) = texels(&a, tile);
        let (_, y) = texels(&b, tile);
        let (err, filled) = mean_abs_diff(&x, &y);
        assert!(filled > 1000);
        assert!(
            err <= 2.0 * MEAN_TOLERANCE,
            "{tile}: EPSG:4326 source differs by {err:.2}"
        );
    }

    let png = dir.path().join("rgb.png");
    run(
        "gdal_translate",
        &[
            "-q",
            "-of",
            "PNG",
            "-co",
            "WORLDFILE=YES",
            path_str(&rgb),
            path_str(&png),
        ],
    );
    std::fs::write(dir.path().join("rgb.prj"), "EPSG:31985\n").unwrap();
    let from_png = dir.path().join("png.tess");
    build_ok(
        &o.dem,
        &from_png,
        &["--crs", DEM_CRS, "--imagery", path_str(&png)],
    );
    let c = Pyramid::open_imagery(FileSource::open(&from_png.with_extension("tessimg")).unwrap())
        .unwrap();
    for level in g.levels() {
        for tile in g.present_tiles(level) {
            assert_eq!(
                a.read_record(tile).unwrap(),
                c.read_record(tile).unwrap(),
                "{tile}"
            );
        }
    }
}

/// Each bad input fails naming the file and the problem, and leaves no output at all.
#[test]
fn bad_imagery_is_an_error_naming_the_file_and_leaves_nothing() {
    let Some(o) = olinda() else { return };
    if !gdal_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let not_tiff = dir.path().join("garbage.tif");
    std::fs::write(&not_tiff, b"this is not a TIFF").unwrap();
    let far = dir.path().join("far.tif");
    // The same scene placed 500 km east: no ground in common with the DEM.
    run(
        "gdal_translate",
        &[
            "-q",
            "-a_ullr",
            "788776.25",
            "9120760.75",
            "798722.75",
            "9110728.75",
            path_str(&o.image),
            path_str(&far),
        ],
    );
    let png = dir.path().join("nocrs.png");
    run(
        "gdal_translate",
        &[
            "-q",
            "-of",
            "PNG",
            "-b",
            "1",
            "-co",
            "WORLDFILE=YES",
            path_str(&o.image),
            path_str(&png),
        ],
    );
    let image = path_str(&o.image);
    let cases: Vec<(Vec<&str>, &Path, &str)> = vec![
        (
            vec!["--crs", DEM_CRS, "--imagery", path_str(&not_tiff)],
            &not_tiff,
            "not a readable TIFF",
        ),
        (
            vec!["--crs", DEM_CRS, "--imagery", image, "--bands", "7,2,1"],
            &o.image,
            "band 7 is out of range",
        ),
        (
            vec!["--crs", DEM_CRS, "--imagery", path_str(&far)],
            &far,
            "does not overlap",
        ),
        (
            vec!["--crs", DEM_CRS, "--imagery", path_str(&png)],
            &png,
            "no CRS",
        ),
    ];
    for (args, named, problem) in cases {
        let out = dir.path().join("out.tess");
        let r = build(&o.dem, &out, &args);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "{args:?} succeeded");
        assert!(err.contains(problem), "{args:?}: {err}");
        let file_named = err.contains(path_str(named))
            || err.contains(path_str(&o.dem))
            || err.contains(path_str(&out));
        assert!(file_named, "{args:?}: the message names no file: {err}");
        assert!(!err.contains("panicked"), "{err}");
        let left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.contains("out."))
            .collect();
        assert!(left.is_empty(), "{args:?} left {left:?}");
    }
}
