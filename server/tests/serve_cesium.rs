//! Cesium terrain over HTTP (DECISIONS.md "Cesium terrain"): a real
//! `tessera-server serve` of N46E008 (SRTM, EGM96), `layer.json` as CesiumJS reads it,
//! and `.terrain` tiles byte for byte what the mesher and encoder make in-process — with
//! the extensions the `Accept` header asks for, gzipped when the client accepts it,
//! cacheable and revalidated like every other tile. Heights and errors are checked by
//! tests/tests/cesium_terrain.rs; CesiumJS itself in tests/browser/.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{Server, bin, parse_metrics};
use std::io::Read;
use std::path::PathBuf;
use std::sync::{Arc, OnceLock};
use tessera_server::cesium::quantized_mesh::{Extensions, encode};
use tessera_server::cesium::terrain::{PyramidLevels, Terrain};
use tessera_server::cesium::tiling::CesiumTile;
use tessera_server::geoid::Geoid;
use tessera_shared::{Pyramid, testdata};

const ACCEPT_ALL: &str = "application/vnd.quantized-mesh;extensions=octvertexnormals-watermask-metadata,application/octet-stream;q=0.9,*/*;q=0.01";

struct Built {
    _dir: tempfile::TempDir,
    srtm: PathBuf,
    synthetic: PathBuf,
}

fn built() -> Option<&'static Built> {
    static B: OnceLock<Option<Built>> = OnceLock::new();
    B.get_or_init(|| {
        let dem = testdata::dem_or_skip("N46E008.tif")?;
        let dir = tempfile::tempdir().unwrap();
        let srtm = dir.path().join("N46E008.tess");
        let synthetic = dir.path().join("synthetic.tess");
        for (input, out, extra) in [
            (
                dem.to_str().unwrap(),
                &srtm,
                &["--vertical-datum", "egm96"][..],
            ),
            ("synthetic:257", &synthetic, &[][..]),
        ] {
            let o = bin()
                .args(["build", input, "-o"])
                .arg(out)
                .args(["--tile-size", "256", "--quiet"])
                .args(extra)
                .output()
                .unwrap();
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        }
        Some(Built {
            _dir: dir,
            srtm,
            synthetic,
        })
    })
    .as_ref()
}

fn gunzip(bytes: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    flate2::read::GzDecoder::new(bytes)
        .read_to_end(&mut out)
        .unwrap();
    out
}

/// The tile as the mesher and encoder make it here, with the server's geoid.
fn expected(b: &Built, tile: CesiumTile, normals: bool, metadata: bool) -> Vec<u8> {
    let p = Pyramid::open_file(&b.srtm).unwrap();
    let geoid = tessera_server::geoid::find(None).map(|g| Arc::new(Geoid::open(&g).unwrap()));
    let terrain = Terrain::new(p.metadata(), geoid).unwrap();
    let levels = PyramidLevels::new(&p);
    let plan = terrain.plan(tile.z, &levels).unwrap();
    let mesh = terrain.mesh(tile, &levels).unwrap();
    let ext = Extensions {
        normals,
        metadata: metadata.then(|| {
            serde_json::json!({"geometricError": plan.geometric_error, "level": plan.level.get()})
                .to_string()
        }),
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
    let available = doc["available"].as_array().unwrap();
    assert_eq!(available.len(), 17);
    assert_eq!(
        available[0],
        serde_json::json!([{"startX": 1, "startY": 0, "endX": 1, "endY": 0}])
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
    assert_eq!(ext, ["octvertexnormals"]);
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
