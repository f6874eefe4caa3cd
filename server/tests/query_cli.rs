//! `tessera-server query`: the elevation API on the command line (API.md "Elevation
//! queries"): the same answers as the server's for the same points, points from CSV
//! and GeoJSON files, profiles, datum conversion checked against PROJ, and the
//! failure contract (one line naming the input and the problem, exit 1, no output).
#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod cli_support;
mod gdal;
#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use cli_support::{assert_clean_failure, bin, text, tmpdir};
use serde_json::Value;
use serve_support::{Server, dem_pyramid};
use std::path::Path;

fn query(pyramid: &Path, args: &[&str]) -> String {
    let o = bin().arg("query").arg(pyramid).args(args).output().unwrap();
    assert!(
        o.status.success(),
        "query {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8(o.stdout).unwrap()
}

/// The command's JSON equals the server's for the same points and options.
#[test]
fn the_command_answers_as_the_server_does() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 64) else {
        return;
    };
    let points = "46.5,8.1|46.61,8.237|46.2,8.95|47.6,8.1";
    let cli: Value = serde_json::from_str(&query(
        &pyramid,
        &[
            "--at",
            points,
            "--interpolation",
            "cubic",
            "--accuracy",
            "150",
            "--format",
            "json",
        ],
    ))
    .unwrap();
    let srv = Server::start(&[&pyramid], &[]);
    let http = srv
        .get(&format!(
            "/v1/datasets/N46E008/elevation?locations={points}&interpolation=cubic&accuracy=150"
        ))
        .expect(200)
        .json();
    assert_eq!(cli, http);
    assert_eq!(cli["results"][3]["reason"], "outside the dataset");
    let levels: Vec<u64> = (0..3)
        .map(|i| cli["results"][i]["level"].as_u64().unwrap())
        .collect();
    assert!(
        levels.iter().any(|&l| l < 5),
        "accuracy 150 m answers from coarser levels: {levels:?}"
    );
}

/// Points from a CSV file (any column order, extra columns) and a GeoJSON
/// LineString sampled as a profile, written as CSV and as GeoJSON files.
#[test]
fn points_come_from_csv_and_geojson_files() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 512) else {
        return;
    };
    let dir = tmpdir("query");
    let csv = dir.path().join("summits.csv");
    std::fs::write(&csv, "name,longitude,latitude\nA,8.1,46.5\nB, 8.2 ,46.6\n").unwrap();
    let out = dir.path().join("summits.out.csv");
    query(
        &pyramid,
        &[
            "--points",
            text(&csv),
            "--interpolation",
            "nearest",
            "-o",
            text(&out),
        ],
    );
    let rows: Vec<String> = std::fs::read_to_string(&out)
        .unwrap()
        .lines()
        .map(String::from)
        .collect();
    assert_eq!(
        rows[0],
        "lat,lon,elevation,level,error_bound,resolution,datum,reason"
    );
    assert!(rows[1].starts_with("46.5,8.1,3338,2,0,"), "{}", rows[1]);
    assert_eq!(rows.len(), 3);
    let line = dir.path().join("route.geojson");
    std::fs::write(
        &line,
        r#"{"type": "Feature", "properties": {}, "geometry": {"type": "LineString", "coordinates": [[8.1, 46.1], [8.6, 46.5], [8.2, 46.9]]}}"#,
    )
    .unwrap();
    let out = dir.path().join("profile.geojson");
    query(
        &pyramid,
        &["--points", text(&line), "--samples", "50", "-o", text(&out)],
    );
    let doc: Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    let features = doc["features"].as_array().unwrap();
    assert_eq!(features.len(), 50);
    assert_eq!(features[0]["geometry"]["coordinates"][0], 8.1);
    assert_eq!(features[49]["geometry"]["coordinates"][1], 46.9);
    assert!(
        features
            .iter()
            .filter(|f| f["properties"]["elevation"].is_f64())
            .count()
            > 40
    );
}

/// `--datum ellipsoid` adds the EGM96 undulation to SRTM's heights: the same as PROJ
/// carrying EGM96 heights (EPSG:5773) to WGS 84 ellipsoidal ones (EPSG:4979).
#[test]
fn datum_conversion_agrees_with_proj() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 512) else {
        return;
    };
    if !gdal::gdal_or_skip() || !Path::new("/usr/share/proj/egm96_15.gtx").is_file() {
        assert!(
            std::env::var_os("CI").is_none(),
            "CI needs proj-data's EGM96 grid"
        );
        return;
    }
    let pts = [[46.5, 8.1], [46.61, 8.237], [46.2, 8.95]];
    let at: Vec<String> = pts.iter().map(|p| format!("{},{}", p[0], p[1])).collect();
    let at = at.join("|");
    let native: Value =
        serde_json::from_str(&query(&pyramid, &["--at", &at, "--format", "json"])).unwrap();
    let ellipsoid: Value = serde_json::from_str(&query(
        &pyramid,
        &["--at", &at, "--format", "json", "--datum", "ellipsoid"],
    ))
    .unwrap();
    assert_eq!(native["datum"], "egm96");
    assert_eq!(ellipsoid["datum"], "ellipsoid");
    let input = pts.iter().fold(String::new(), |mut s, p| {
        use std::fmt::Write as _;
        let _ = writeln!(s, "{} {} 0", p[1], p[0]);
        s
    });
    let proj = gdal::run_stdin(
        "gdaltransform",
        &["-s_srs", "EPSG:4326+5773", "-t_srs", "EPSG:4979"],
        input,
    );
    for (i, line) in proj.lines().enumerate() {
        let n: f64 = line.split_whitespace().nth(2).unwrap().parse().unwrap();
        let h = native["results"][i]["elevation"].as_f64().unwrap();
        let e = ellipsoid["results"][i]["elevation"].as_f64().unwrap();
        assert!(
            (e - h - n).abs() < 0.01,
            "point {i}: {e} − {h} vs PROJ's undulation {n}"
        );
    }
    // aletsch's datum is unknown: no conversion, a clear refusal.
    let Some(aletsch) = dem_pyramid("aletsch.tif", 512) else {
        return;
    };
    let o = bin()
        .args([
            "query",
            text(&aletsch),
            "--at",
            "46.5,8.0",
            "--datum",
            "egm96",
        ])
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && e.contains("vertical datum is unknown"),
        "{e}"
    );
}

/// Bad input: one line naming it and the problem, exit 1, and no output file.
#[test]
fn bad_input_is_one_clear_line_and_no_output() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 512) else {
        return;
    };
    let dir = tmpdir("query-bad");
    let out = dir.path().join("out.csv");
    let run = |args: &[&str]| {
        bin()
            .arg("query")
            .arg(&pyramid)
            .args(args)
            .arg("-o")
            .arg(&out)
            .output()
            .unwrap()
    };
    assert_clean_failure(&run(&["--at", "91,8.1"]), "--at", "latitude 91", &out);
    let csv = dir.path().join("bad.csv");
    std::fs::write(&csv, "lat,lon\n46.5,8.1\n46.5,east\n").unwrap();
    assert_clean_failure(
        &run(&["--points", text(&csv)]),
        "line 3",
        "longitude \"east\"",
        &out,
    );
    std::fs::write(&csv, "x,y\n46.5,8.1\n").unwrap();
    assert_clean_failure(
        &run(&["--points", text(&csv)]),
        "bad.csv",
        "no lat and lon columns",
        &out,
    );
    assert_clean_failure(&run(&[]), "--at", "no points", &out);
    assert_clean_failure(
        &run(&["--at", "46.5,8.1", "--samples", "10"]),
        "samples",
        "two points",
        &out,
    );
}
