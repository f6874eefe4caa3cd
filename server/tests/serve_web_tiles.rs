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
use tessera_shared::TileId;

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
            "own-grid tiles have no bounds: {j}"
        );
        assert_eq!(j["scheme"], "tessera-dataset", "{j}");
        // The template (absolute on the Host the client used, without
        // --public-url) is a PNG tile on this server.
        let origin = format!("http://{}", srv.addr);
        let path = url
            .strip_prefix(&origin)
            .unwrap_or_else(|| panic!("{url} is not on {origin}"))
            .replace("{z}", "2")
            .replace("{x}", "1")
            .replace("{y}", "3");
        let png = srv.get(&path).expect(200);
        assert_eq!(decode_png(&png.body).0, p.geometry().tile_size());
    }

    // Own-grid tiles are not Web Mercator: the document must not let a map place
    // them as XYZ tiles, even for a dataset in longitude and latitude.
    for (name, crs) in [("N44W072", "EPSG:4326"), ("bigtujunga", "EPSG:32611")] {
        if !files
            .iter()
            .any(|f| f.file_stem().is_some_and(|s| s == name))
        {
            continue;
        }
        let j = srv
            .get(&format!("/v1/datasets/{name}/tilejson.json"))
            .expect(200)
            .json();
        tilejson_encoding(&j);
        assert_eq!(j["tileSize"], 64, "{j}");
        assert_ne!(j["scheme"], "xyz", "own-grid tiles claimed as XYZ: {j}");
        assert_ne!(j["scheme"], "tms", "{j}");
        assert!(
            j.get("bounds").is_none(),
            "bounds invite placing the tiles: {j}"
        );
        assert_eq!(j["crs"], crs, "{j}");
        let web = j["standard_grids"]["WebMercatorQuad"].as_str().unwrap();
        let wj = srv.get(web).expect(200).json();
        assert_eq!(wj["scheme"], "xyz", "{wj}");
    }
    assert_eq!(srv.get("/v1/datasets/nope/tilejson.json").status, 404);
}
