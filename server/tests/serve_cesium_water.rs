//! Cesium terrain's water mask over HTTP (DECISIONS.md "Cesium terrain"): a real
//! `tessera-server serve` of N46E008 with `--sea-level` and with a `--water` raster
//! made by GDAL, the mask read back from the tiles at Urnersee and its shores, and
//! bad water inputs refused at start-up with one line.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod cesium_support;

use cesium_support::{ACCEPT_ALL, built, extensions_of, gdal, run, tile_at};
use serve_support::{Server, bin};
use std::process::Command;
use tessera_shared::testdata;

/// The water-mask cell holding a point, and the mask's bytes: 1 or 65 536.
fn water_at(s: &Server, lon: f64, lat: f64) -> (bool, usize) {
    let t = tile_at(11, lon, lat);
    let r = s
        .get_with(
            &format!("/v1/datasets/N46E008/cesium/11/{}/{}.terrain", t.x, t.y),
            &[("Accept", ACCEPT_ALL)],
        )
        .expect(200);
    assert_eq!(
        r.must("content-type"),
        "application/vnd.quantized-mesh;extensions=octvertexnormals-watermask-metadata"
    );
    let ext = extensions_of(&r.body);
    let ids: Vec<u8> = ext.iter().map(|(id, _)| *id).collect();
    assert_eq!(ids, [1, 2, 4], "extensions in spec order");
    let mask = &ext[1].1;
    let [w, so, e, n] = t.rect();
    let i = ((lon - w) / (e - w) * 256.0) as usize;
    let j = ((n - lat) / (n - so) * 256.0) as usize;
    let v = match mask.len() {
        1 => mask[0],
        65_536 => mask[j * 256 + i],
        other => panic!("water mask of {other} bytes"),
    };
    assert!(v == 0 || v == 255, "{v}");
    (v == 255, mask.len())
}

// Urnersee (Lake Lucerne's south arm) is 431 m in this SRTM tile (EGM96); the slopes
// beside it are land.
const LAKE: [[f64; 2]; 2] = [[8.61, 46.93], [8.50, 46.99]];
const LAND: [[f64; 2]; 2] = [[8.65, 46.93], [8.58, 46.98]];

#[test]
fn water_masks_mark_the_lake_and_not_the_land() {
    let Some(b) = built() else { return };
    let dem = testdata::dem_or_skip("N46E008.tif").unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut servers = vec![(
        "--sea-level 431",
        Server::start(&[&b.srtm], &["--sea-level", "431"]),
    )];
    if gdal() {
        // A water raster: the lake's 431 m cells around Urnersee, EPSG:4326.
        let crop = dir.path().join("crop.tif");
        let water = dir.path().join("water.tif");
        run(Command::new("gdal_translate")
            .args(["-q", "-projwin", "8.40", "47.06", "8.70", "46.85"])
            .arg(&dem)
            .arg(&crop));
        run(Command::new("gdal_calc.py")
            .arg("--quiet")
            .arg("-A")
            .arg(&crop)
            .arg("--outfile")
            .arg(&water)
            .args(["--calc", "A==431", "--type", "Int16"]));
        servers.push((
            "--water",
            Server::start(&[&b.srtm], &["--water", water.to_str().unwrap()]),
        ));
    }
    for (rule, s) in &servers {
        let doc = s
            .get("/v1/datasets/N46E008/cesium/layer.json")
            .expect(200)
            .json();
        assert_eq!(
            doc["extensions"],
            serde_json::json!(["octvertexnormals", "watermask", "metadata"])
        );
        for [lon, lat] in LAKE {
            let (water, bytes) = water_at(s, lon, lat);
            assert!(water, "{rule}: {lon}, {lat} is the lake");
            assert_eq!(bytes, 65_536, "{rule}: lake and shore in one tile");
        }
        for [lon, lat] in LAND {
            assert!(!water_at(s, lon, lat).0, "{rule}: {lon}, {lat} is land");
        }
        // Finsteraarhorn: all land, the one-byte form.
        assert_eq!(water_at(s, 8.1258, 46.5367), (false, 1), "{rule}");
        let t = tile_at(11, LAKE[0][0], LAKE[0][1]);
        let path = format!("/v1/datasets/N46E008/cesium/11/{}/{}.terrain", t.x, t.y);
        let plain = s
            .get_with(
                &path,
                &[(
                    "Accept",
                    "application/vnd.quantized-mesh;extensions=octvertexnormals-metadata",
                )],
            )
            .expect(200);
        let wet = s.get_with(&path, &[("Accept", ACCEPT_ALL)]).expect(200);
        assert_ne!(plain.must("etag"), wet.must("etag"));
        eprintln!(
            "{rule}: tile 11/{}/{} is {} bytes without the water mask, {} with it (uncompressed)",
            t.x,
            t.y,
            plain.body.len(),
            wet.body.len()
        );
    }
}

/// Runs `serve` expecting it to stop at start-up; its stderr.
fn serve_fails(flags: &[&str]) -> String {
    let Some(b) = built() else {
        return String::new();
    };
    let mut child = bin()
        .arg("serve")
        .arg(&b.srtm)
        .args(["--listen", "127.0.0.1:0"])
        .args(flags)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // A server that starts instead would run forever: stop it (and fail).
    for _ in 0..600 {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    if child.try_wait().unwrap().is_none() {
        child.kill().unwrap();
        panic!("serve {flags:?} started");
    }
    let o = child.wait_with_output().unwrap();
    assert!(!o.status.success());
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn bad_water_inputs_stop_the_server_with_one_line() {
    let Some(_) = built() else { return };
    let dir = tempfile::tempdir().unwrap();
    let junk = dir.path().join("junk.tif");
    std::fs::write(&junk, "not a GeoTIFF\n").unwrap();
    let mut cases = vec![(junk, "junk.tif")];
    if gdal() {
        let dem = testdata::dem_or_skip("N46E008.tif").unwrap();
        let merc = dir.path().join("mercator.tif");
        run(Command::new("gdalwarp")
            .args([
                "-q",
                "-t_srs",
                "EPSG:3857",
                "-te_srs",
                "EPSG:4326",
                "-te",
                "8.5",
                "46.9",
                "8.7",
                "47.0",
            ])
            .arg(&dem)
            .arg(&merc));
        cases.push((merc, "EPSG:4326"));
    }
    for (file, needle) in cases {
        let err = serve_fails(&["--water", file.to_str().unwrap()]);
        let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
        assert_eq!(lines.len(), 1, "{err}");
        assert!(
            lines[0].contains(&*file.to_string_lossy()) && lines[0].contains(needle),
            "{err}"
        );
    }
    let err = serve_fails(&["--sea-level", "NaN"]);
    assert!(err.contains("--sea-level"), "{err}");
}
