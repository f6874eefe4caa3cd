//! GDAL's command-line tools as the reference in tests (Debian's `gdal-bin`, which
//! `./run test` installs). Without them a test prints `SKIPPED`, or fails when `CI`
//! is set, so CI can never pass by skipping.

#![allow(dead_code)] // each test binary uses its own subset

pub mod dem;
pub mod fusion;
pub mod pieces;

use std::path::Path;
use std::process::Command;
use tessera_server::web::tile_matrix::WebTile;

/// Whether GDAL's tools are here; `SKIPPED` when not, a failure when `CI` is set.
pub fn gdal_or_skip() -> bool {
    let ok = Command::new("gdalinfo")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        assert!(
            std::env::var_os("CI").is_none(),
            "GDAL's tools are missing and CI is set (./run test installs gdal-bin)"
        );
        eprintln!("SKIPPED: GDAL's tools are absent (apt-get install gdal-bin)");
    }
    ok
}

/// Runs a GDAL tool; its stdout. Panics with its stderr when it fails.
pub fn run(program: &str, args: &[&str]) -> String {
    let o = Command::new(program).args(args).output().unwrap();
    assert!(
        o.status.success(),
        "{program} {args:?} failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8(o.stdout).unwrap()
}

/// Runs a command-line tool (GDAL's, PROJ's) with `input` on its standard input; its
/// stdout. Panics with its stderr when it fails.
pub fn run_stdin(program: &str, args: &[&str], input: String) -> String {
    let mut child = Command::new(program)
        .args(args)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Written from a thread: the tools answer as they read, and with many lines their
    // output would fill the pipe while we still write (a deadlock).
    let mut stdin = child.stdin.take().unwrap();
    let writer = std::thread::spawn(move || {
        use std::io::Write;
        stdin.write_all(input.as_bytes()).unwrap();
    });
    let out = child.wait_with_output().unwrap();
    writer.join().unwrap();
    assert!(
        out.status.success(),
        "{program} {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// `gdaltransform`: points of `from` carried to `to` (both `EPSG:CODE`), exactly as
/// PROJ computes them.
pub fn transform(from: &str, to: &str, points: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let mut text = String::with_capacity(points.len() * 32);
    for p in points {
        use std::fmt::Write as _;
        let _ = writeln!(text, "{:.10} {:.10}", p[0], p[1]);
    }
    run_stdin(
        "gdaltransform",
        &["-s_srs", from, "-t_srs", to, "-output_xy"],
        text,
    )
    .lines()
    .map(|l| {
        let v: Vec<f64> = l.split_whitespace().map(|t| t.parse().unwrap()).collect();
        [v[0], v[1]]
    })
    .collect()
}

pub fn path_str(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The DEM warped onto `tile`'s `px × px` pixel centres and `border` more pixels on
/// each side (bilinear, exact transforms), as float32 heights row-major from the
/// north-west (−99999 for no data); with `ignore_nodata`, the voids' stored values
/// are read as heights. `out` is the ENVI file written.
pub fn warp_tile(
    dem: &Path,
    tile: WebTile,
    px: u32,
    border: u32,
    out: &Path,
    ignore_nodata: bool,
) -> Vec<f32> {
    let side = (px + 2 * border).to_string();
    let c = tile.tms.cell_size(tile.z, px) * f64::from(border);
    let [x0, y0, x1, y1] = tile.bounds();
    let te = [x0 - c, y0 - c, x1 + c, y1 + c].map(|v| format!("{v:.9}"));
    let srs = format!("EPSG:{}", tile.tms.epsg());
    let mut args = vec![
        "-q",
        "-overwrite",
        "-t_srs",
        &srs,
        "-te",
        &te[0],
        &te[1],
        &te[2],
        &te[3],
        "-ts",
        &side,
        &side,
        "-r",
        "bilinear",
        "-et",
        "0",
        "-ot",
        "Float32",
        "-dstnodata",
        "-99999",
        "-of",
        "ENVI",
    ];
    if ignore_nodata {
        args.extend(["-srcnodata", "None"]);
    }
    args.extend([path_str(dem), path_str(out)]);
    run("gdalwarp", &args);
    std::fs::read(out)
        .unwrap()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect()
}
