//! `tessera-server serve` end to end: PNG height tiles (Terrarium and Mapbox
//! encodings) and the TileJSON documents that describe them (API.md).
//!
//! Pyramids are shared by every test (`serve_support`); every test starts its own
//! server on an ephemeral port (killed when the test ends) and checks responses
//! against the pyramid file read independently with the shared reader.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{Server, fixtures, level, open};
use std::path::Path;
use tessera_shared::{TileId, testdata};

// ---------------------------------------------------------------------------
// PNG tiles and TileJSON

/// Decodes an 8-bit RGB PNG into `(width, height, rgb)`.
fn decode_png(bytes: &[u8]) -> (u32, u32, Vec<u8>) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb, "want RGB");
    assert_eq!(info.bit_depth, png::BitDepth::Eight, "want 8-bit");
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

#[test]
fn png_height_tiles_decode_to_the_tile_heights() {
    let f = fixtures();
    let p = open(&f.synth);
    let q = p.metadata().quantization;
    let t = p.geometry().tile_size();
    let srv = Server::start(&[&f.synth], &[]);
    for (z, x, y) in [(0, 0, 0), (2, 1, 3), (4, 15, 0)] {
        let tile = TileId::new(level(z), x, y).unwrap();
        let rec = p.read_tile(tile).unwrap().unwrap();
        let side = t as usize + 1;
        for enc in ["terrarium", "mapbox"] {
            let r = srv
                .get(&format!(
                    "/v1/datasets/synth/{z}/{x}/{y}.png?encoding={enc}"
                ))
                .expect(200);
            assert!(r.must("content-type").starts_with("image/png"));
            let (w, h, rgb) = decode_png(&r.body);
            assert_eq!((w, h), (t, t), "{enc} PNG of {tile} is {w}×{h}");
            let mut worst = 0f64;
            for j in 0..t as usize {
                for i in 0..t as usize {
                    let px = &rgb[(j * t as usize + i) * 3..][..3];
                    let (r8, g8, b8) = (f64::from(px[0]), f64::from(px[1]), f64::from(px[2]));
                    let got = if enc == "mapbox" {
                        -10000.0 + (r8 * 65536.0 + g8 * 256.0 + b8) * 0.1
                    } else {
                        r8 * 256.0 + g8 + b8 / 256.0 - 32768.0
                    };
                    let want = q.height(rec.heights[j * side + i]);
                    worst = worst.max((got - want).abs());
                }
            }
            let tol = if enc == "mapbox" { 0.05 } else { 1.0 / 256.0 } + 1e-9;
            assert!(
                worst <= tol,
                "{enc} {tile}: off by {worst} m (tolerance {tol})"
            );
        }
    }
    let e = srv
        .get("/v1/datasets/synth/0/0/0.png?encoding=jpeg2000")
        .error(400);
    assert!(e.contains("jpeg2000") || e.contains("encoding"), "{e}");
}

/// The `encoding` a TileJSON document declares, after checking that its tile URL
/// template asks for the same one.
fn tilejson_encoding(j: &serde_json::Value) -> String {
    let enc = j["encoding"]
        .as_str()
        .unwrap_or_else(|| panic!("no encoding: {j}"));
    assert!(enc == "terrarium" || enc == "mapbox", "{j}");
    let url = j["tiles"][0]
        .as_str()
        .unwrap_or_else(|| panic!("no tiles: {j}"));
    assert!(url.contains(&format!("encoding={enc}")), "{url} vs {enc}");
    enc.to_string()
}

#[test]
fn tilejson_describes_the_png_tiles() {
    let f = fixtures();
    let p = open(&f.synth);
    let mut files: Vec<&Path> = vec![&f.synth];
    files.extend(f.n44.as_deref());
    files.extend(f.bigtujunga.as_deref());
    let srv = Server::start(&files, &[]);
    for query in ["", "?encoding=terrarium", "?encoding=mapbox"] {
        let j = srv
            .get(&format!("/v1/datasets/synth/tilejson.json{query}"))
            .expect(200)
            .json();
        assert_eq!(j["tilejson"], "3.0.0", "{j}");
        tilejson_encoding(&j);
        // The document describes the encoding asked for (Terrarium by default).
        let want = if query.contains("mapbox") {
            "mapbox"
        } else {
            "terrarium"
        };
        assert_eq!(j["encoding"], want, "{j}");
        assert_eq!(j["tileSize"], p.geometry().tile_size(), "{j}");
        assert_eq!(j["minzoom"], 0, "{j}");
        assert_eq!(j["maxzoom"], p.geometry().finest().get(), "{j}");
        let url = j["tiles"][0].as_str().unwrap();
        assert!(url.contains("/v1/datasets/synth/{z}/{x}/{y}.png"), "{url}");
        assert!(
            j.get("bounds").is_none(),
            "a dataset without georeferencing has no bounds: {j}"
        );
        // The template (server-relative without --public-url) resolves to a PNG
        // tile on this server.
        assert!(url.starts_with("/v1/"), "{url}");
        let path = url
            .replace("{z}", "2")
            .replace("{x}", "1")
            .replace("{y}", "3");
        let png = srv.get(&path).expect(200);
        assert_eq!(decode_png(&png.body).0, p.geometry().tile_size());
    }

    if let Some(path) = f.n44.as_deref() {
        let np = open(path);
        let facts = testdata::facts("N44W072.hgt");
        let j = srv
            .get("/v1/datasets/N44W072/tilejson.json")
            .expect(200)
            .json();
        tilejson_encoding(&j);
        assert_eq!(j["tileSize"], 64, "{j}");
        assert_eq!(j["maxzoom"], np.geometry().finest().get(), "{j}");
        let bounds: Vec<f64> = j["bounds"]
            .as_array()
            .unwrap_or_else(|| panic!("EPSG:4326 dataset needs bounds: {j}"))
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let want = facts.extent.unwrap();
        assert_eq!(bounds.len(), 4);
        for (g, w) in bounds.iter().zip(want) {
            assert!((g - w).abs() < 1e-6, "bounds {bounds:?}, want {want:?}");
        }
    }
    // Projected (UTM) coordinates are not longitudes and latitudes: no bounds.
    if f.bigtujunga.is_some() {
        let j = srv
            .get("/v1/datasets/bigtujunga/tilejson.json")
            .expect(200)
            .json();
        assert!(j.get("bounds").is_none(), "UTM dataset with bounds: {j}");
    }
    assert_eq!(srv.get("/v1/datasets/nope/tilejson.json").status, 404);
}
