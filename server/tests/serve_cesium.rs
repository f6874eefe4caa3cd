//! Cesium terrain over HTTP (DECISIONS.md "Cesium terrain"): a real
//! `tessera-server serve` of N46E008 (SRTM, EGM96), `layer.json` as CesiumJS reads it,
//! and `.terrain` tiles byte for byte what the mesher and encoder make in-process — with
//! the extensions the `Accept` header asks for, gzipped when the client accepts it,
//! cacheable and revalidated like every other tile. Heights and errors are checked by
//! tests/tests/cesium_terrain.rs; CesiumJS itself in tests/browser/.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod cesium_support;

use serve_support::{Server, bin, parse_metrics};
use std::io::Read;
use std::path::Path;
use std::process::Command;
use std::sync::Arc;
use tessera_server::cesium::quantized_mesh::{Extensions, encode};
use tessera_server::cesium::terrain::availability::{Availability, Stored};
use tessera_server::cesium::terrain::{PyramidLevels, Terrain};
use tessera_server::cesium::tiling::CesiumTile;
use tessera_server::geoid::Geoid;
use tessera_server::serve::routes::cesium::metadata_json;
use tessera_shared::format::FLAG_PARTIAL;
use tessera_shared::{Pyramid, testdata};

use cesium_support::{ACCEPT_ALL, Built, built, gdal, listed, metadata_of, run, tile_at};

fn gunzip(bytes: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    flate2::read::GzDecoder::new(bytes)
        .read_to_end(&mut out)
        .unwrap();
    out
}

/// The availability of a pyramid made in-process, from its index and masks.
fn availability_of(path: &Path) -> Availability {
    let p = Pyramid::open_file(path).unwrap();
    let terrain = Terrain::new(p.metadata(), None).unwrap();
    let levels = PyramidLevels::new(&p);
    let stored = |t| match p.entry(t) {
        Some(e) if e.flags & FLAG_PARTIAL != 0 => Stored::Partial,
        Some(_) => Stored::Full,
        None => Stored::Absent,
    };
    terrain.availability(stored, &levels).unwrap()
}

/// The tile as the mesher and encoder make it here, with the server's geoid.
fn expected(b: &Built, tile: CesiumTile, normals: bool, metadata: bool) -> Vec<u8> {
    let p = Pyramid::open_file(&b.srtm).unwrap();
    let geoid = tessera_server::geoid::find(None).map(|g| Arc::new(Geoid::open(&g).unwrap()));
    let terrain = Terrain::new(p.metadata(), geoid).unwrap();
    let levels = PyramidLevels::new(&p);
    let plan = terrain.plan(tile.z, &levels).unwrap();
    let mesh = terrain.mesh(tile, &levels).unwrap();
    let available = availability_of(&b.srtm);
    let ext = Extensions {
        normals,
        water_mask: None,
        metadata: metadata
            .then(|| metadata_json(&available, tile, plan.geometric_error, plan.level)),
    };
    encode(&mesh, tile.rect(), &terrain.ellipsoid, &ext).unwrap()
}

#[test]
fn layer_json_describes_the_terrain_as_cesium_reads_it() {
    let Some(b) = built() else { return };
    let s = Server::start(&[&b.srtm], &[]);
    let r = s
        .get_with(
            "/v1/datasets/N46E008/cesium/layer.json",
            &[("Origin", "https://globe.example")],
        )
        .expect(200);
    assert_eq!(r.must("access-control-allow-origin"), "*");
    let doc = r.json();
    assert_eq!(doc["format"], "quantized-mesh-1.0");
    assert_eq!(doc["scheme"], "tms");
    assert_eq!(doc["projection"], "EPSG:4326");
    assert_eq!(doc["maxzoom"], 16);
    let hash = Pyramid::open_file(&b.srtm)
        .unwrap()
        .metadata()
        .content_hash
        .clone();
    assert_eq!(
        doc["tiles"][0],
        format!("{{z}}/{{x}}/{{y}}.terrain?v={hash}")
    );
    // Metadata availability: layer.json lists zooms 0-10, tiles the rest.
    assert_eq!(doc["metadataAvailability"], 10);
    let available = doc["available"].as_array().unwrap();
    assert_eq!(available.len(), 11);
    // Both roots, as CesiumJS assumes with metadataAvailability.
    assert_eq!(
        available[0],
        serde_json::json!([{"startX": 0, "startY": 0, "endX": 1, "endY": 0}])
    );
    // 0.703125° tiles at zoom 8: 8–9° E, 46–47° N.
    assert_eq!(
        available[8],
        serde_json::json!([{"startX": 267, "startY": 193, "endX": 268, "endY": 194}])
    );
    let ext: Vec<&str> = doc["extensions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    // No water rule given: no water mask.
    assert_eq!(ext, ["octvertexnormals", "metadata"]);
    assert_eq!(doc["metadata"]["verticalDatum"], "egm96");
    let e0 = doc["metadata"]["levelZeroGeometricError"].as_f64().unwrap();
    assert!((e0 - 77_067.34).abs() < 0.01, "{e0}");
    if tessera_server::geoid::find(None).is_some() {
        assert!(doc["metadata"].get("warning").is_none(), "{doc}");
    }
    let etag = r.must("etag").to_string();
    s.get_with(
        "/v1/datasets/N46E008/cesium/layer.json",
        &[("If-None-Match", &etag)],
    )
    .expect(304);
}

#[test]
fn terrain_tiles_are_the_mesh_with_the_extensions_asked_for() {
    let Some(b) = built() else { return };
    let s = Server::start(&[&b.srtm], &[]);
    let tile = CesiumTile::new(8, 267, 193).unwrap();
    let path = "/v1/datasets/N46E008/cesium/8/267/193.terrain";
    // As CesiumJS asks: every extension it knows, gzip accepted.
    let r = s
        .get_with(path, &[("Accept", ACCEPT_ALL), ("Accept-Encoding", "gzip")])
        .expect(200);
    assert_eq!(
        r.must("content-type"),
        "application/vnd.quantized-mesh;extensions=octvertexnormals-metadata"
    );
    assert_eq!(r.must("content-encoding"), "gzip");
    assert!(
        r.must("vary").to_ascii_lowercase().contains("accept"),
        "{:?}",
        r.headers
    );
    assert_eq!(gunzip(&r.body), expected(b, tile, true, true));
    // Revalidation, and the pinned URL layer.json hands out is immutable.
    let etag = r.must("etag").to_string();
    s.get_with(path, &[("Accept", ACCEPT_ALL), ("If-None-Match", &etag)])
        .expect(304);
    let hash = Pyramid::open_file(&b.srtm)
        .unwrap()
        .metadata()
        .content_hash
        .clone();
    let pinned = s
        .get_with(&format!("{path}?v={hash}"), &[("Accept", ACCEPT_ALL)])
        .expect(200);
    assert!(pinned.must("cache-control").contains("immutable"));
    // A plain client gets no extensions, and a different ETag.
    let plain = s.get(path).expect(200);
    assert_eq!(plain.must("content-type"), "application/vnd.quantized-mesh");
    assert_eq!(plain.body, expected(b, tile, false, false));
    assert_ne!(plain.must("etag"), etag);
    // Normals only.
    let normals = s
        .get_with(
            path,
            &[(
                "Accept",
                "application/vnd.quantized-mesh;extensions=octvertexnormals",
            )],
        )
        .expect(200);
    assert_eq!(normals.body, expected(b, tile, true, false));
    let m = parse_metrics(&s.get("/metrics").expect(200).text());
    let hits: f64 = m
        .iter()
        .filter(|x| {
            x.name == "tessera_web_cache_requests_total"
                && x.labels.get("cache").is_some_and(|c| c == "terrain")
        })
        .map(|x| x.value)
        .sum();
    assert!(hits >= 4.0, "terrain cache lookups: {hits}");
}

#[test]
fn bad_terrain_requests_get_reasons() {
    let Some(b) = built() else { return };
    let s = Server::start(&[&b.srtm, &b.synthetic], &[]);
    for (path, needle) in [
        ("/v1/datasets/N46E008/cesium/8/0/0.terrain", "holds no data"),
        (
            "/v1/datasets/N46E008/cesium/17/0/0.terrain",
            "holds no data",
        ),
        (
            "/v1/datasets/N46E008/cesium/23/0/0.terrain",
            "not in the EPSG:4326 TMS grid",
        ),
        (
            "/v1/datasets/N46E008/cesium/0/2/0.terrain",
            "not in the EPSG:4326 TMS grid",
        ),
        (
            "/v1/datasets/N46E008/cesium/8/267/x.terrain",
            "not in the EPSG:4326 TMS grid",
        ),
        (
            "/v1/datasets/N46E008/cesium/8/267/193.png",
            "terrain tiles are",
        ),
        (
            "/v1/datasets/synthetic/cesium/layer.json",
            "no georeferencing",
        ),
        ("/v1/datasets/nope/cesium/layer.json", "nope"),
    ] {
        let r = s.get(path);
        assert_eq!(r.status, 404, "{path}: {}", r.text());
        let reason = r.json_error();
        assert!(reason.contains(needle), "{path}: {reason}");
    }
}

#[test]
fn tiles_carry_the_availability_of_the_zooms_below_them() {
    let Some(b) = built() else { return };
    let s = Server::start(&[&b.srtm], &[]);
    let doc = s
        .get("/v1/datasets/N46E008/cesium/layer.json")
        .expect(200)
        .json();
    let meta = |z: u8, x: u32, y: u32| {
        let r = s
            .get_with(
                &format!("/v1/datasets/N46E008/cesium/{z}/{x}/{y}.terrain"),
                &[("Accept", ACCEPT_ALL)],
            )
            .expect(200);
        metadata_of(&r.body)
    };
    // The eastern root carries zooms 1-10, as layer.json lists them.
    let root = meta(0, 1, 0);
    let carried = root["available"].as_array().unwrap();
    assert_eq!(carried.len(), 10);
    for (k, ranges) in carried.iter().enumerate() {
        assert_eq!(ranges, &doc["available"][k + 1], "zoom {}", k + 1);
    }
    // The western root holds no data but exists (CesiumJS assumes both roots):
    // nothing under it.
    let west = meta(0, 0, 0);
    assert!(
        west["available"]
            .as_array()
            .unwrap()
            .iter()
            .all(|r| r.as_array().unwrap().is_empty()),
        "{west}"
    );
    // A zoom-10 tile carries zooms 11-16 under it; a zoom-8 one nothing.
    let t = tile_at(10, 8.5, 46.5);
    let m = meta(10, t.x, t.y);
    let carried = m["available"].as_array().unwrap();
    assert_eq!(carried.len(), 6);
    assert!(listed(&carried[5], t.x << 6, t.y << 6), "{m}");
    assert!(meta(8, 267, 193).get("available").is_none());
    // The server's availability is the pyramid's.
    let a = availability_of(&b.srtm);
    for z in 0..=10 {
        let ranges: Vec<serde_json::Value> = a
            .ranges(z)
            .iter()
            .map(|&[x0, y0, x1, y1]| {
                serde_json::json!({"startX": x0, "startY": y0, "endX": x1, "endY": y1})
            })
            .collect();
        assert_eq!(doc["available"][usize::from(z)], serde_json::json!(ranges));
    }
}

#[test]
fn a_hole_in_a_mosaic_is_no_tile() {
    let Some(_) = built() else { return };
    if !gdal() {
        eprintln!("skipped: no gdal_translate");
        return;
    }
    // N46E008 (1201² samples, 3″) in two pieces with 199 columns (0.1658°,
    // 8.4167–8.5833° E) missing.
    let dir = tempfile::tempdir().unwrap();
    let dem = testdata::dem_or_skip("N46E008.tif").unwrap();
    let (west, east) = (dir.path().join("west.tif"), dir.path().join("east.tif"));
    for (win, out) in [
        (["0", "0", "501", "1201"], &west),
        (["700", "0", "501", "1201"], &east),
    ] {
        run(Command::new("gdal_translate")
            .args(["-q", "-srcwin"])
            .args(win)
            .arg(&dem)
            .arg(out));
    }
    let holed = dir.path().join("holed.tess");
    run(bin()
        .args(["build"])
        .arg(&west)
        .arg(&east)
        .arg("-o")
        .arg(&holed)
        .args(["--tile-size", "256", "--quiet", "--vertical-datum", "egm96"]));
    let s = Server::start(&[&holed], &[]);
    let doc = s
        .get("/v1/datasets/holed/cesium/layer.json")
        .expect(200)
        .json();
    let gap = tile_at(12, 8.5, 46.5);
    let beside = tile_at(12, 8.6, 46.5);
    let parent = tile_at(10, 8.5, 46.5);
    assert_eq!((gap.x >> 2, gap.y >> 2), (parent.x, parent.y));
    assert_eq!((beside.x >> 2, beside.y >> 2), (parent.x, parent.y));
    // Over the hole: not listed by the zoom-10 tile that carries zoom 12, and 404.
    let r = s
        .get_with(
            &format!(
                "/v1/datasets/holed/cesium/10/{}/{}.terrain",
                parent.x, parent.y
            ),
            &[("Accept", ACCEPT_ALL)],
        )
        .expect(200);
    let m = metadata_of(&r.body);
    assert!(!listed(&m["available"][1], gap.x, gap.y), "{m}");
    assert!(listed(&m["available"][1], beside.x, beside.y), "{m}");
    let r = s.get(&format!(
        "/v1/datasets/holed/cesium/12/{}/{}.terrain",
        gap.x, gap.y
    ));
    assert_eq!(r.status, 404);
    assert!(
        r.json_error().contains("holds no data"),
        "{}",
        r.json_error()
    );
    s.get(&format!(
        "/v1/datasets/holed/cesium/12/{}/{}.terrain",
        beside.x, beside.y
    ))
    .expect(200);
    // Zoom 10 tiles wholly in the hole: none (0.176° tiles, a 0.167° hole); zoom 9's
    // available ranges are one rectangle, zoom 12's (from the tiles) leave the hole.
    assert_eq!(doc["available"][9].as_array().unwrap().len(), 1);
    let a = availability_of(&holed);
    assert!(!a.contains(gap) && a.contains(beside));
    let holes_12 = a.ranges(12).len();
    assert!(holes_12 > 1, "zoom 12: {holes_12} ranges");
}

#[test]
fn accept_headers_without_quantized_mesh_get_406() {
    let Some(b) = built() else { return };
    let s = Server::start(&[&b.srtm], &[]);
    let path = "/v1/datasets/N46E008/cesium/8/267/193.terrain";
    for accept in ["image/png", "application/vnd.quantized-mesh;q=0, text/html"] {
        let r = s.get_with(path, &[("Accept", accept)]);
        assert_eq!(r.status, 406, "{accept}: {}", r.text());
        assert!(
            r.json_error().contains("application/vnd.quantized-mesh"),
            "{}",
            r.json_error()
        );
    }
    // Unknown extension names are ignored (CesiumJS asks only for listed ones), and
    // the water mask without a water rule is not made.
    let r = s
        .get_with(
            path,
            &[(
                "Accept",
                "application/vnd.quantized-mesh;extensions=bogus-watermask",
            )],
        )
        .expect(200);
    assert_eq!(r.must("content-type"), "application/vnd.quantized-mesh");
    s.get_with(path, &[("Accept", "*/*")]).expect(200);
}
