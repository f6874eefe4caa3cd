//! `tessera-server export --pmtiles` (API.md "PMTiles export"): archives read back
//! with the `pmtiles` package from PyPI, the format authors' reader, and every tile
//! compared with the server's tile of the same z/x/y; `--precision auto`'s rounding
//! against its stated bound; deduplication; and bad input.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod cli_support;
#[allow(dead_code)]
mod serve_support;

use cli_support::{assert_clean_failure, bin, text, tmpdir};
use serve_support::{Server, dem_pyramid};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;
use tessera_server::export::precision;
use tessera_server::web::encoding::Encoding;

/// Python with the `pmtiles` package (3.8.1, in a virtualenv under the user's cache,
/// made once); `None` (SKIPPED) where it cannot be installed, a failure under CI.
fn pmtiles_python() -> Option<&'static Path> {
    static PY: OnceLock<Option<PathBuf>> = OnceLock::new();
    PY.get_or_init(|| {
        let cache = std::env::var_os("XDG_CACHE_HOME")
            .map(PathBuf::from)
            .or_else(|| std::env::var_os("HOME").map(|h| Path::new(&h).join(".cache")))?;
        let venv = cache.join("tessera").join("pmtiles-venv");
        let python = venv.join("bin").join("python");
        let ok = |p: &Path| {
            Command::new(p)
                .args(["-c", "import pmtiles.reader"])
                .output()
                .is_ok_and(|o| o.status.success())
        };
        if !ok(&python) {
            let made = Command::new("python3")
                .args(["-m", "venv"])
                .arg(&venv)
                .status()
                .is_ok_and(|s| s.success())
                && Command::new(venv.join("bin").join("pip"))
                    .args(["install", "-q", "pmtiles==3.8.1"])
                    .status()
                    .is_ok_and(|s| s.success());
            if !made || !ok(&python) {
                assert!(
                    std::env::var_os("CI").is_none(),
                    "cannot install the pmtiles package into {} and CI is set",
                    venv.display()
                );
                eprintln!("SKIPPED: the pmtiles package from PyPI could not be installed");
                return None;
            }
        }
        Some(python)
    })
    .as_deref()
}

/// The archive read back: (header and metadata, a folder of z/x/y.bin tiles).
fn read_back(archive: &Path) -> Option<(serde_json::Value, tempfile::TempDir)> {
    let python = pmtiles_python()?;
    let dir = tempfile::tempdir().unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/pmtiles_read.py");
    let o = Command::new(python)
        .arg(script)
        .arg(archive)
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    Some((serde_json::from_slice(&o.stdout).unwrap(), dir))
}

/// Every tile file under `dir`: ((z, x, y), bytes), sorted.
fn tiles(dir: &Path) -> Vec<((u8, u32, u32), Vec<u8>)> {
    let mut out = Vec::new();
    for z in std::fs::read_dir(dir).unwrap().flatten() {
        for x in std::fs::read_dir(z.path()).unwrap().flatten() {
            for y in std::fs::read_dir(x.path()).unwrap().flatten() {
                let num = |p: &Path| {
                    p.file_stem()
                        .unwrap()
                        .to_str()
                        .unwrap()
                        .parse::<u32>()
                        .unwrap()
                };
                let zz = z.file_name().to_str().unwrap().parse::<u8>().unwrap();
                out.push((
                    (zz, num(&x.path()), num(&y.path())),
                    std::fs::read(y.path()).unwrap(),
                ));
            }
        }
    }
    out.sort();
    out
}

fn export(pyramid: &Path, out: &Path, args: &[&str]) -> String {
    let o = bin()
        .arg("export")
        .arg(pyramid)
        .arg("--pmtiles")
        .arg(out)
        .arg("--quiet")
        .args(args)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "export {args:?} failed: {err}");
    err
}

/// Web Mercator tile of (lon, lat) at zoom z.
fn xyz(lon: f64, lat: f64, z: u8) -> (u32, u32) {
    let n = f64::from(1u32 << z);
    let l = lat.to_radians();
    let x = ((lon + 180.0) / 360.0 * n).floor();
    let y = ((1.0 - (l.tan() + 1.0 / l.cos()).ln() / std::f64::consts::PI) / 2.0 * n).floor();
    (x.clamp(0.0, n - 1.0) as u32, y.clamp(0.0, n - 1.0) as u32)
}

/// Terrarium heights of an RGBA image.
fn heights(rgba: &[u8]) -> Vec<f64> {
    rgba.chunks(4)
        .map(|p| f64::from(p[0]) * 256.0 + f64::from(p[1]) + f64::from(p[2]) / 256.0 - 32768.0)
        .collect()
}

fn webp_rgba(bytes: &[u8]) -> Vec<u8> {
    let mut d = image_webp::WebPDecoder::new(std::io::Cursor::new(bytes)).unwrap();
    let mut buf = vec![0; d.output_buffer_size().unwrap()];
    d.read_image(&mut buf).unwrap();
    if d.has_alpha() {
        buf
    } else {
        buf.chunks(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect()
    }
}

/// The whole archive, tile by tile, is the server's tiles; and it holds exactly the
/// tiles the server answers 200 for within the TileJSON's bounds, at every zoom.
#[test]
fn every_tile_is_the_servers_tile() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    let dir = tmpdir("export");
    let archive = dir.path().join("n46.pmtiles");
    let said = export(&pyramid, &archive, &[]);
    assert!(said.contains("tiles/s") && said.contains("MB/s"), "{said}");
    let Some((doc, folder)) = read_back(&archive) else {
        return;
    };
    let h = &doc["header"];
    assert_eq!(h["tile_type"], "PNG");
    assert_eq!(h["clustered"], true);
    assert_eq!(h["tile_compression"], "NONE");
    assert_eq!(doc["metadata"]["encoding"], "terrarium");
    let srv = Server::start(&[&pyramid], &[]);
    let tj = srv
        .get("/v1/datasets/N46E008/webmercator/tilejson.json")
        .expect(200)
        .json();
    let max = tj["maxzoom"].as_u64().unwrap() as u8;
    assert_eq!(h["min_zoom"], 0);
    assert_eq!(h["max_zoom"], max);
    let b: Vec<f64> = tj["bounds"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!((h["min_lon_e7"].as_f64().unwrap() / 1e7 - b[0]).abs() < 1e-6);
    assert!((h["max_lat_e7"].as_f64().unwrap() / 1e7 - b[3]).abs() < 1e-6);
    let got = tiles(folder.path());
    assert_eq!(doc["tiles"].as_u64().unwrap() as usize, got.len());
    let mut want = Vec::new();
    for z in 0..=max {
        let (x0, y0) = xyz(b[0], b[3], z);
        let (x1, y1) = xyz(b[2], b[1], z);
        for x in x0..=x1 {
            for y in y0..=y1 {
                let r = srv.get(&format!("/v1/datasets/N46E008/webmercator/{z}/{x}/{y}.png"));
                match r.status {
                    200 => want.push(((z, x, y), r.body)),
                    404 => {}
                    s => panic!("{z}/{x}/{y}: {s}"),
                }
            }
        }
    }
    assert_eq!(
        got.len(),
        want.len(),
        "tiles in the archive vs the server's"
    );
    for (g, w) in got.iter().zip(&want) {
        assert_eq!(g.0, w.0);
        assert!(g.1 == w.1, "tile {:?} differs from the server's", g.0);
    }
    let bytes: usize = got.iter().map(|t| t.1.len()).sum();
    let size = std::fs::metadata(&archive).unwrap().len();
    eprintln!(
        "{} tiles, {bytes} bytes of tiles, archive {size} bytes",
        got.len()
    );
}

/// `--precision auto`: every height within half its zoom's step of the exact
/// archive's (which is the server's), a multiple of the step, and a smaller archive.
#[test]
fn precision_auto_rounds_within_its_bound() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    let dir = tmpdir("export-auto");
    let (exact, auto) = (
        dir.path().join("exact.pmtiles"),
        dir.path().join("auto.pmtiles"),
    );
    let common = ["--format", "webp", "--size", "512", "--minzoom", "6"];
    export(&pyramid, &exact, &common);
    export(
        &pyramid,
        &auto,
        &[&common[..], &["--precision", "auto"]].concat(),
    );
    let (Some((_, e)), Some((doc, a))) = (read_back(&exact), read_back(&auto)) else {
        return;
    };
    let srv = Server::start(&[&pyramid], &[]);
    let (e, a) = (tiles(e.path()), tiles(a.path()));
    assert_eq!(e.len(), a.len());
    let mut worst = 0.0f64;
    for (te, ta) in e.iter().zip(&a) {
        let (z, x, y) = te.0;
        assert_eq!(te.0, ta.0);
        let served = srv
            .get(&format!(
                "/v1/datasets/N46E008/webmercator/{z}/{x}/{y}.webp?size=512"
            ))
            .expect(200);
        assert!(
            served.body == te.1,
            "exact tile {z}/{x}/{y} differs from the server's"
        );
        let q = precision::step(z, 512, Encoding::Terrarium);
        let stated = doc["metadata"]["tessera"]["rounding_step_m"][z.to_string()]
            .as_f64()
            .unwrap();
        assert_eq!(q, stated, "zoom {z}'s step in the metadata");
        for (he, ha) in heights(&webp_rgba(&te.1))
            .iter()
            .zip(heights(&webp_rgba(&ta.1)))
        {
            assert_eq!((ha / q).fract(), 0.0, "{ha} is not a multiple of {q}");
            let d = (ha - he).abs();
            // Terrarium truncates to 1/256 m: the exact tile's height may sit up to
            // 1/256 below the value that was rounded.
            assert!(
                d <= q / 2.0 + 1.0 / 256.0,
                "{z}/{x}/{y}: {he} → {ha} (step {q})"
            );
            worst = worst.max(d / q);
        }
    }
    let (se, sa) = (
        std::fs::metadata(&exact).unwrap().len(),
        std::fs::metadata(&auto).unwrap().len(),
    );
    eprintln!(
        "exact {se} bytes, auto {sa} bytes ({:.1} %); worst |Δ| {worst:.3} steps",
        100.0 * sa as f64 / se as f64
    );
    assert!(sa < se, "auto {sa} is not smaller than exact {se}");
    assert!(worst > 0.25, "nothing was rounded: worst {worst}");
}

/// A rendered layer with options: the server's tiles with the same options.
#[test]
fn a_hillshade_archive_is_the_servers_hillshade() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    let dir = tmpdir("export-shade");
    let archive = dir.path().join("shade.pmtiles");
    export(
        &pyramid,
        &archive,
        &[
            "--layer",
            "hillshade",
            "--option",
            "azimuth=200",
            "--option",
            "method=combined",
            "--minzoom",
            "10",
            "--maxzoom",
            "11",
        ],
    );
    let Some((doc, folder)) = read_back(&archive) else {
        return;
    };
    assert!(
        doc["metadata"]["description"]
            .as_str()
            .unwrap()
            .contains("azimuth=200")
    );
    let srv = Server::start(&[&pyramid], &[]);
    let got = tiles(folder.path());
    assert!(got.len() > 20, "{}", got.len());
    for ((z, x, y), bytes) in got {
        let r = srv
            .get(&format!("/v1/datasets/N46E008/webmercator/hillshade/{z}/{x}/{y}.png?azimuth=200&method=combined"))
            .expect(200);
        assert!(r.body == bytes, "{z}/{x}/{y} differs from the server's");
    }
}

/// Contour lines: a vector archive whose tiles are the server's contour tiles, with
/// the `vector_layers` a map reads.
#[test]
fn a_contour_archive_is_the_servers_contours() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    let dir = tmpdir("export-contours");
    let archive = dir.path().join("contours.pmtiles");
    export(
        &pyramid,
        &archive,
        &[
            "--layer",
            "contours",
            "--option",
            "interval=50",
            "--minzoom",
            "9",
            "--maxzoom",
            "11",
        ],
    );
    let Some((doc, folder)) = read_back(&archive) else {
        return;
    };
    assert_eq!(doc["header"]["tile_type"], "MVT", "{doc}");
    // Vector tiles are stored gzipped, as PMTiles readers expect them.
    assert_eq!(doc["header"]["tile_compression"], "GZIP", "{doc}");
    let layers = &doc["metadata"]["vector_layers"];
    assert_eq!(layers[0]["id"], "contours", "{doc}");
    assert!(layers[0]["fields"]["ele"].is_string(), "{doc}");
    let srv = Server::start(&[&pyramid], &[]);
    let got = tiles(folder.path());
    assert!(got.len() > 10, "{}", got.len());
    for ((z, x, y), zipped) in got {
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(&zipped[..]), &mut bytes)
            .unwrap();
        let r = srv
            .get(&format!(
                "/v1/datasets/N46E008/webmercator/contours/{z}/{x}/{y}.mvt?interval=50"
            ))
            .expect(200);
        assert!(r.body == bytes, "{z}/{x}/{y} differs from the server's");
    }
}

/// A flat DEM: its inner tiles are identical and stored once.
#[test]
fn identical_tiles_are_stored_once() {
    let dir = tmpdir("export-flat");
    let png = dir.path().join("flat.png");
    let side = 1201u32;
    let mut enc = png::Encoder::new(std::fs::File::create(&png).unwrap(), side, side);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Sixteen);
    let mut w = enc.write_header().unwrap();
    w.write_image_data(&vec![0x01u8; (side * side * 2) as usize])
        .unwrap(); // 257 m
    w.finish().unwrap();
    let tess = dir.path().join("flat.tess");
    let o = bin()
        .args([
            "build",
            text(&png),
            "--crs",
            "EPSG:4326",
            "--bounds",
            "8,46,9,47",
            "--vertical-datum",
            "egm96",
            "-o",
            text(&tess),
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let archive = dir.path().join("flat.pmtiles");
    export(&tess, &archive, &["--minzoom", "10"]);
    let Some((doc, _)) = read_back(&archive) else {
        return;
    };
    let h = &doc["header"];
    let (addressed, contents) = (
        h["addressed_tiles_count"].as_u64().unwrap(),
        h["tile_contents_count"].as_u64().unwrap(),
    );
    eprintln!("{addressed} tiles addressed, {contents} stored");
    assert!(
        addressed > 200 && contents * 4 < addressed,
        "{addressed} addressed, {contents} stored"
    );
}

#[test]
fn bad_input_is_one_clear_line_and_no_archive() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    let dir = tmpdir("export-bad");
    let out = dir.path().join("out.pmtiles");
    let run = |args: &[&str]| {
        bin()
            .arg("export")
            .arg(&pyramid)
            .arg("--pmtiles")
            .arg(&out)
            .args(args)
            .output()
            .unwrap()
    };
    assert_clean_failure(
        &run(&["--grid", "crs84"]),
        "--grid crs84",
        "Web Mercator",
        &out,
    );
    assert_clean_failure(
        &run(&["--maxzoom", "20"]),
        "--maxzoom 20",
        "beyond the data",
        &out,
    );
    assert_clean_failure(&run(&["--size", "300"]), "--size 300", "256 and 512", &out);
    assert_clean_failure(
        &run(&["--layer", "shade"]),
        "--layer shade",
        "hillshade",
        &out,
    );
    assert_clean_failure(
        &run(&["--layer", "hillshade", "--option", "z_factor=0"]),
        "z_factor",
        "exaggeration",
        &out,
    );
    assert_clean_failure(
        &run(&["--layer", "color-relief", "--option", "ramp=rainbow"]),
        "ramp",
        "unknown ramp",
        &out,
    );
    assert_clean_failure(
        &run(&["--layer", "slope", "--precision", "auto"]),
        "--precision auto",
        "height tiles",
        &out,
    );
    assert_clean_failure(&run(&["--encoding", "rgb"]), "encoding", "terrarium", &out);
    // A contour interval too fine for the first zoom names the zoom and the finest.
    assert_clean_failure(
        &run(&["--layer", "contours", "--option", "interval=1"]),
        "interval",
        "finest interval",
        &out,
    );
    assert_clean_failure(
        &run(&["--layer", "contours", "--option", "interval=-5"]),
        "interval",
        "positive",
        &out,
    );
    // Nothing else was left in the folder.
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert!(left.is_empty(), "{left:?}");
}
