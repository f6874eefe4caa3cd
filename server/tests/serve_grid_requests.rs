//! What the standard-grid tile routes answer: the decoded-tile cache under
//! a burst, TileJSON parameters and empty tiles, a DEM smaller than a pixel at zoom 0,
//! and every tile within the bounds; real pyramids built from real DEMs (N46E008,
//! EPSG:4326; aletsch, EPSG:2056) and a real `tessera-server serve`. Each pixel
//! against GDAL: `serve_grid_tiles.rs`.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod grid_support;
#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use grid_support::{built, decode_rgba, terrarium, tilejson_bounds, xyz_tile};
use serve_support::{Server, parse_metrics};

/// A map's burst of neighbouring tiles decodes each source tile once: the burst
/// decodes exactly the distinct source tiles its tiles need, and a second burst, in
/// the other encoding, finds every one in the cache.
#[test]
fn a_burst_of_neighbouring_tiles_decodes_each_source_tile_once() {
    let Some(b) = built() else { return };
    let srv = Server::start(&[&b.n46e008], &[]);
    let info = srv.get("/v1/datasets/N46E008").expect(200).json();
    let gt: Vec<f64> = info["georef"]["geotransform"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let t = info["tile_size"].as_f64().unwrap();
    let (width, height) = (
        info["width"].as_f64().unwrap(),
        info["height"].as_f64().unwrap(),
    );
    let z = 11;
    let (cx, cy) = xyz_tile(8.5, 46.5, z);
    let tiles: Vec<(u32, u32)> = (0..2)
        .flat_map(|dy| (0..2).map(move |dx| (cx + dx, cy + dy)))
        .collect();
    // The source tiles each needs: at z 11 a 512-px pixel (26 m) is finer than a
    // 3″ sample, so the finest level; a Web Mercator tile is a longitude/latitude
    // rectangle, whose samples (±1 for the nearest-sample rule) name its tiles,
    // those inside the DEM (tiles wholly beyond it are absent).
    let mut needed = std::collections::BTreeSet::new();
    for &(x, y) in &tiles {
        let n = f64::from(1u32 << z);
        let lon = |x: u32| f64::from(x) / n * 360.0 - 180.0;
        let lat = |y: u32| {
            let m = std::f64::consts::PI * (1.0 - 2.0 * f64::from(y) / n);
            m.sinh().atan().to_degrees()
        };
        let col = |lon: f64| (lon - gt[0]) / gt[1] - 0.5;
        let row = |lat: f64| (lat - gt[3]) / gt[5] - 0.5;
        let span = |a: f64, b: f64| {
            let (lo, hi) = (a.min(b) - 1.0, a.max(b) + 1.0);
            (lo.max(0.0) / t).floor() as u32..=(hi / t).floor() as u32
        };
        for ty in span(row(lat(y)), row(lat(y + 1))) {
            for tx in span(col(lon(x)), col(lon(x + 1))) {
                if f64::from(tx) * t < width - 1.0 && f64::from(ty) * t < height - 1.0 {
                    needed.insert((tx, ty));
                }
            }
        }
    }
    let burst = |enc: &'static str| {
        std::thread::scope(|s| {
            for &(x, y) in &tiles {
                let srv = &srv;
                s.spawn(move || {
                    srv.get(&format!(
                        "/v1/datasets/N46E008/webmercator/{z}/{x}/{y}.png?size=512&encoding={enc}"
                    ))
                    .expect(200)
                });
            }
        });
    };
    let source = |name: &str, result: Option<&str>| -> f64 {
        parse_metrics(&srv.get("/metrics").expect(200).text())
            .iter()
            .filter(|s| {
                s.name == name
                    && s.labels.get("cache").map(String::as_str) == Some("source")
                    && result.is_none_or(|r| s.labels.get("result").map(String::as_str) == Some(r))
            })
            .map(|s| s.value)
            .sum()
    };
    burst("terrarium");
    let misses = source("tessera_web_cache_requests_total", Some("miss"));
    let hits = source("tessera_web_cache_requests_total", Some("hit"));
    assert_eq!(
        misses,
        needed.len() as f64,
        "decodes vs distinct source tiles {needed:?}"
    );
    assert!(hits > 0.0, "neighbours share source tiles: {hits} hits");
    burst("mapbox");
    assert_eq!(
        source("tessera_web_cache_requests_total", Some("miss")),
        misses,
        "the second burst decoded again"
    );
    // Each decoded (T+1)² tile holds 2 bytes a sample, all of them kept.
    let bytes = source("tessera_web_cache_bytes", None);
    assert!(
        bytes >= misses * (t + 1.0) * (t + 1.0) * 2.0,
        "{bytes} bytes cached"
    );
}

#[test]
fn tilejson_parameters_and_empty_tiles() {
    let Some(b) = built() else { return };
    let srv = Server::start(&[&b.n46e008], &["--attribution", "SRTM <NASA>"]);
    let tj = srv
        .get("/v1/datasets/N46E008/webmercator/tilejson.json?encoding=mapbox&size=512")
        .expect(200)
        .json();
    assert_eq!(tj["tilejson"], "3.0.0");
    assert_eq!(tj["scheme"], "xyz");
    assert_eq!(tj["tileSize"], 512);
    assert_eq!(tj["encoding"], "mapbox");
    assert_eq!(tj["attribution"], "SRTM &lt;NASA&gt;");
    assert_eq!(tj["minzoom"], 0);
    // The first zoom whose pixels are at most half the DEM's finer spacing (3″ at
    // 46.5° N: 63.8 m east–west, so 31.9 m): at 512 px, z 11 (26.3 m), not z 10.
    let z = tj["maxzoom"].as_u64().unwrap();
    let pixel =
        |z: u64| 40_075_016.686 * 46.5f64.to_radians().cos() / (512.0 * 2f64.powi(z as i32));
    assert!(pixel(z) <= 31.9 && pixel(z - 1) > 31.9, "maxzoom {z}");
    let bounds: Vec<f64> = tj["bounds"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let half = 1.0 / 2400.0;
    for (g, w) in bounds
        .iter()
        .zip([8.0 - half, 46.0 - half, 9.0 + half, 47.0 + half])
    {
        assert!((g - w).abs() < 1e-9, "{bounds:?}");
    }
    let centre = tj["center"].as_array().unwrap();
    assert!((centre[0].as_f64().unwrap() - 8.5).abs() < 1e-9);
    let template = tj["tiles"][0].as_str().unwrap();
    assert!(
        template.contains("encoding=mapbox") && template.contains("size=512"),
        "{template}"
    );
    // Absolute, on the origin the client used (default flags: from its Host), so a
    // page on another origin fetches the tiles from this server.
    let origin = format!("http://{}", srv.addr);
    let template = template
        .strip_prefix(&origin)
        .unwrap_or_else(|| panic!("{template} is not on {origin}"));
    let (x, y) = xyz_tile(8.5911, 46.635, 9);
    let path = template
        .replace("{z}", "9")
        .replace("{x}", &x.to_string())
        .replace("{y}", &y.to_string());
    let png = srv.get(&path).expect(200);
    assert!(
        png.must("cache-control").contains("immutable"),
        "pinned by v="
    );
    // WebP: the same pixels.
    let webp = srv
        .get(&format!(
            "/v1/datasets/N46E008/webmercator/9/{x}/{y}.webp?encoding=mapbox&size=512"
        ))
        .expect(200);
    assert_eq!(webp.must("content-type"), "image/webp");
    let (_, from_png) = decode_rgba(&png.body);
    let mut dec = image_webp::WebPDecoder::new(std::io::Cursor::new(&webp.body[..])).unwrap();
    let mut from_webp = vec![0; dec.output_buffer_size().unwrap()];
    dec.read_image(&mut from_webp).unwrap();
    for (a, b) in from_png.chunks(4).zip(from_webp.chunks(4)) {
        assert!(a == b || (a[3] == 0 && b[3] == 0), "{a:?} vs {b:?}");
    }

    for (path, status, says) in [
        ("/v1/datasets/N46E008/utm/tilejson.json", 404, "webmercator"),
        (
            "/v1/datasets/N46E008/webmercator/tilejson.json?size=300",
            400,
            "256 and 512",
        ),
        (
            "/v1/datasets/N46E008/webmercator/tilejson.json?encoding=jpeg",
            400,
            "terrarium",
        ),
        (
            "/v1/datasets/N46E008/webmercator/25/0/0.png",
            404,
            "zooms 0-24",
        ),
        ("/v1/datasets/N46E008/webmercator/2/4/0.png", 404, "x 0-3"),
        ("/v1/datasets/N46E008/crs84/0/2/0.png", 404, "x 0-1"),
        ("/v1/datasets/N46E008/webmercator/2/0/0.jpg", 404, ".webp"),
        (
            "/v1/datasets/N46E008/webmercator/2/0/0.png",
            404,
            "holds no data",
        ),
    ] {
        let r = srv.get(path);
        assert_eq!(r.status, status, "{path}: {}", r.text());
        assert!(r.error(status).contains(says), "{path}: {}", r.text());
    }
    // CRS84's two root tiles: the eastern one holds the DEM, the western one nothing.
    srv.get("/v1/datasets/N46E008/crs84/0/1/0.png").expect(200);
    assert_eq!(srv.get("/v1/datasets/N46E008/crs84/0/0/0.png").status, 404);
    let quiet = Server::start(&[&b.n46e008], &["--empty-tiles", "204"]);
    let r = quiet.get("/v1/datasets/N46E008/webmercator/2/0/0.png");
    assert_eq!(r.status, 204);
    assert!(r.body.is_empty());
    assert!(
        r.header("etag").is_some(),
        "an empty tile is as cacheable as a full one"
    );
}

/// Web Mercator zoom 0 of N46E008 was a 404 although the TileJSON says `minzoom` 0:
/// a 1° tile is 0.7 of a zoom-0 pixel, and no pixel centre fell inside it. Now the
/// pixels the DEM covers show it (the DEM's heights), with the apron around them;
/// every other pixel is the dataset's lowest height (never −32768 m:
/// DECISIONS.md "Real clients"), opaque by default and transparent with
/// `nodata=transparent`.
#[test]
fn zoom_0_shows_a_dem_smaller_than_a_pixel() {
    let Some(b) = built() else { return };
    let srv = Server::start(&[&b.n46e008], &[]);
    for px in [256u32, 512] {
        let tj = srv
            .get(&format!(
                "/v1/datasets/N46E008/webmercator/tilejson.json?size={px}"
            ))
            .expect(200)
            .json();
        assert_eq!(tj["minzoom"], 0);
        let png = srv
            .get(&format!(
                "/v1/datasets/N46E008/webmercator/0/0/0.png?size={px}&nodata=transparent"
            ))
            .expect(200);
        let (side, rgba) = decode_rgba(&png.body);
        assert_eq!(side, px);
        // By default the same pixels, all opaque: the data where it is, its lowest
        // height (187 m) everywhere else.
        let opaque_png = srv
            .get(&format!(
                "/v1/datasets/N46E008/webmercator/0/0/0.png?size={px}"
            ))
            .expect(200);
        let (_, all) = decode_rgba(&opaque_png.body);
        for (k, (a, b)) in rgba.chunks(4).zip(all.chunks(4)).enumerate() {
            assert_eq!(b[3], 255, "{px} px: pixel {k} is not opaque by default");
            if a[3] == 255 {
                assert_eq!(a, b, "{px} px: pixel {k}");
            } else {
                assert_eq!(terrarium(b), 187.0, "{px} px: pixel {k} beyond the DEM");
                assert_eq!(
                    &a[..3],
                    &b[..3],
                    "{px} px: pixel {k}'s colour is the fill in both"
                );
            }
        }
        // The DEM's pixel box (sample areas: half a 3″ sample beyond 8°..9°, 46°..47°),
        // by the XYZ scheme's own formulas.
        let n = f64::from(px);
        let x = |lon: f64| (lon + 180.0) / 360.0 * n;
        let y = |lat: f64| {
            let l = f64::to_radians(lat);
            (1.0 - (l.tan() + 1.0 / l.cos()).ln() / std::f64::consts::PI) / 2.0 * n
        };
        let half = 1.0 / 2400.0;
        let (x0, x1) = (x(8.0 - half), x(9.0 + half));
        let (y0, y1) = (y(47.0 + half), y(46.0 - half));
        // A pixel touching the box shows the DEM; the apron reaches two more.
        let slack = 1.0 + 2.0;
        let mut opaque = 0;
        for (k, p) in rgba.chunks(4).enumerate() {
            if p[3] == 0 {
                continue;
            }
            opaque += 1;
            let (i, j) = ((k as u32 % px) as f64, (k as u32 / px) as f64);
            assert!(
                i + 1.0 >= x0 - slack
                    && i <= x1 + slack
                    && j + 1.0 >= y0 - slack
                    && j <= y1 + slack,
                "{px} px: pixel ({i}, {j}) is far from the DEM's box x {x0}..{x1}, y {y0}..{y1}"
            );
            let h = terrarium(p);
            assert!((187.0..=4173.0).contains(&h), "{px} px: ({i}, {j}) {h} m");
        }
        // The pixels inside the box at least (x 133..=134 and y 90..=91 at 256 px).
        let inside = (x1.floor() - x0.floor() + 1.0) * (y1.floor() - y0.floor() + 1.0);
        assert!(
            f64::from(opaque) >= inside,
            "{px} px: {opaque} opaque pixels"
        );
    }
}

/// Every tile within the TileJSON's `bounds` answers 200 with plausible heights
/// (DECISIONS.md "Real clients"): web maps ask for each of them, and a 404 is an error in
/// their console. aletsch is EPSG:2056, a rotated rectangle in Web Mercator, so some
/// tiles at the corners of its bounds hold no data: those are the flat fill, the
/// dataset's lowest height, opaque (wholly transparent with `nodata=transparent`).
#[test]
fn every_tile_within_the_bounds_is_served_and_plausible() {
    let Some(b) = built() else { return };
    let srv = Server::start(&[&b.aletsch], &[]);
    let bounds = tilejson_bounds(&srv, "aletsch");
    let doc = srv.get("/v1/datasets/aletsch").expect(200).json();
    let lowest = doc["metadata"]["min_height"]
        .as_f64()
        .or_else(|| doc["min_height"].as_f64())
        .unwrap_or_else(|| panic!("no min_height in {doc}"));
    let highest = 4216.3;
    let mut flat = 0;
    let mut check = |z: u8, x: u32, y: u32| {
        let url = format!("/v1/datasets/aletsch/webmercator/{z}/{x}/{y}.png");
        let (_, rgba) = decode_rgba(&srv.get(&url).expect(200).body);
        let heights: Vec<f64> = rgba
            .chunks(4)
            .map(|p| {
                assert_eq!(p[3], 255, "{url}: not opaque");
                terrarium(p)
            })
            .collect();
        assert!(
            heights
                .iter()
                .all(|h| (lowest - 0.01..=highest + 0.01).contains(h)),
            "{url}: a height outside {lowest}..{highest} m"
        );
        if heights.iter().all(|&h| (h - lowest).abs() < 0.01) {
            flat += 1;
            let t = srv.get(&format!("{url}?nodata=transparent")).expect(200);
            let (_, rgba) = decode_rgba(&t.body);
            assert!(
                rgba.chunks(4).all(|p| p[3] == 0),
                "{url}: no data, yet opaque pixels"
            );
        }
    };
    // Every tile of zoom 11, and the four corner tiles of the bounds at deeper zooms
    // (where a corner tile is small enough to miss the rotated footprint).
    let corners = |z: u8| {
        let (x0, y0) = xyz_tile(bounds[0], bounds[3], z);
        let (x1, y1) = xyz_tile(bounds[2], bounds[1], z);
        (x0, y0, x1, y1)
    };
    let (x0, y0, x1, y1) = corners(11);
    for x in x0..=x1 {
        for y in y0..=y1 {
            check(11, x, y);
        }
    }
    for z in 12..=18 {
        let (x0, y0, x1, y1) = corners(z);
        for (x, y) in [(x0, y0), (x1, y0), (x0, y1), (x1, y1)] {
            check(z, x, y);
        }
    }
    assert!(
        flat > 0,
        "no tile of the bounds' corners lies off the rotated footprint"
    );
    // Beyond the bounds: 404 as before.
    let (_, y0, x1, _) = corners(11);
    srv.get(&format!(
        "/v1/datasets/aletsch/webmercator/11/{}/{y0}.png",
        x1 + 2
    ))
    .expect(404);
}
