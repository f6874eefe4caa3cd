//! Rendered terrain tiles over HTTP with the server's default flags (API.md
//! "Rendered terrain tiles"): what a web map on another origin gets, what a colour
//! ramp does to the very heights the height tiles carry, where no data is, and how
//! bad requests and bad ramp files are refused.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{Server, dem_pyramid, png_rgba as rgba, serve_must_refuse};

fn terrarium(p: &[u8]) -> f64 {
    f64::from(p[0]) * 256.0 + f64::from(p[1]) + f64::from(p[2]) / 256.0 - 32768.0
}

/// A map on another origin: the TileJSON's absolute URLs lead to PNG and WebP
/// tiles, with CORS, a strong ETag and 304s.
#[test]
fn a_map_on_another_origin_gets_the_layers() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    let srv = Server::start(&[&pyramid], &[]);
    let origin = [("origin", "https://maps.example.org")];
    for (layer, query) in [
        ("hillshade", "azimuth=200&method=multidirectional"),
        ("color-relief", "ramp=relative"),
        ("slope", "unit=percent"),
    ] {
        for format in ["png", "webp"] {
            let tj = srv
                .get_with(
                    &format!("/v1/datasets/N46E008/webmercator/{layer}/tilejson.json?{query}&format={format}&size=512"),
                    &origin,
                )
                .expect(200);
            assert_eq!(tj.must("access-control-allow-origin"), "*");
            let doc = tj.json();
            assert_eq!(doc["layer"], layer);
            assert_eq!(doc["tileSize"], 512);
            let template = doc["tiles"][0].as_str().unwrap();
            assert!(template.starts_with("http://"), "{template}");
            for option in query.split('&') {
                assert!(template.contains(option), "{template} lacks {option}");
            }
            // Andermatt at zoom 11.
            let url = template.replace("{z}/{x}/{y}", "11/1072/724");
            let r = srv.get_with(&url, &origin).expect(200);
            assert_eq!(r.must("access-control-allow-origin"), "*");
            assert_eq!(r.must("content-type"), format!("image/{format}"));
            let etag = r.must("etag").to_string();
            assert!(!etag.starts_with("W/"), "{etag}");
            srv.get_with(&url, &[("if-none-match", etag.as_str())])
                .expect(304);
            let (side, pixels) = if format == "png" {
                rgba(&r.body)
            } else {
                let mut d = image_webp::WebPDecoder::new(std::io::Cursor::new(&r.body)).unwrap();
                let (w, _) = d.dimensions();
                let mut buf = vec![0; d.output_buffer_size().unwrap()];
                d.read_image(&mut buf).unwrap();
                assert!(d.has_alpha());
                (w, buf)
            };
            assert_eq!(side, 512);
            // Terrain but for SRTM's voids (transparent).
            assert!(pixels.chunks(4).all(|p| p[3] == 0 || p[3] == 255));
            let drawn = pixels.chunks(4).filter(|p| p[3] == 255).count();
            assert!(
                drawn > 512 * 512 * 9 / 10,
                "{layer} {format}: {drawn} pixels drawn"
            );
        }
    }
    // Another option, another ETag.
    let a = srv
        .get("/v1/datasets/N46E008/webmercator/hillshade/11/1072/724.png")
        .expect(200);
    let b = srv
        .get("/v1/datasets/N46E008/webmercator/hillshade/11/1072/724.png?azimuth=90")
        .expect(200);
    assert_ne!(a.must("etag"), b.must("etag"));
    assert_ne!(a.body, b.body);
    // The default options, written out, are the same tile.
    let c = srv
        .get("/v1/datasets/N46E008/webmercator/hillshade/11/1072/724.png?azimuth=315&altitude=45&z_factor=1&method=standard")
        .expect(200);
    assert_eq!(a.must("etag"), c.must("etag"));
}

/// A step ramp loaded with `--ramp` colours each pixel by the height the Terrarium
/// tile of the same z/x/y carries there: one resampling for both.
#[test]
fn a_ramp_file_colours_the_height_tiles_heights() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let ramp = dir.path().join("step.txt");
    // Below 2000 m blue, from 2000 m up white (two entries at 2000 make a step).
    std::fs::write(&ramp, "0 0 0 255\n2000 0 0 255\n2000 white\n9000 white\n").unwrap();
    let flag = format!("step={}", ramp.display());
    let srv = Server::start(&[&pyramid], &["--ramp", &flag]);
    for (grid, tile) in [("webmercator", "12/2144/1448"), ("crs84", "11/2144/494")] {
        let (_, colours) = rgba(
            &srv.get(&format!(
                "/v1/datasets/N46E008/{grid}/color-relief/{tile}.png?ramp=step"
            ))
            .expect(200)
            .body,
        );
        let (_, heights) = rgba(
            &srv.get(&format!(
                "/v1/datasets/N46E008/{grid}/{tile}.png?nodata=transparent"
            ))
            .expect(200)
            .body,
        );
        let (mut high, mut low) = (0, 0);
        for (c, h) in colours.chunks(4).zip(heights.chunks(4)) {
            if h[3] == 0 || c[3] == 0 {
                // Only the height tile's apron may be drawn where the relief is not.
                assert!(c[3] == 0, "relief drawn where the height tile has no data");
                continue;
            }
            let m = terrarium(h);
            // Terrarium rounds down to 1/256 m: skip the ambiguous sliver.
            if (m - 2000.0).abs() < 1.0 / 128.0 {
                continue;
            }
            if m >= 2000.0 {
                assert_eq!(&c[..3], &[255, 255, 255], "{m} m");
                high += 1;
            } else {
                assert_eq!(&c[..3], &[0, 0, 255], "{m} m");
                low += 1;
            }
        }
        eprintln!("{grid} {tile}: {high} pixels at or above 2000 m, {low} below");
        assert!(high > 1000 && low > 1000, "{high} {low}");
    }
}

/// At the DEM's western edge (8° E) a tile is transparent beyond the data and
/// opaque over it; tiles beyond the dataset's bounds are 404s with a reason, as
/// the height tiles'.
#[test]
fn no_data_is_transparent_and_tiles_beyond_the_bounds_are_404() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    let srv = Server::start(&[&pyramid], &[]);
    // crs84 zoom 9: 0.3515625° tiles; x = allows 7.73°–8.09° E, y 46.41°–46.76° N.
    let (side, px) = rgba(
        &srv.get("/v1/datasets/N46E008/crs84/hillshade/9/534/123.png")
            .expect(200)
            .body,
    );
    let width = f64::from(side);
    let west = -180.0 + 534.0 * 180.0 / 512.0;
    let deg_per_px = 180.0 / 512.0 / width;
    // Half a 3″ sample beyond the edge still reads it, and the 3 × 3 window needs
    // one more pixel: two pixels of slack around 8° − 1/2400.
    let edge = 8.0 - 1.0 / 2400.0;
    let (mut east, mut drawn) = (0, 0);
    for j in 0..side as usize {
        for i in 0..side as usize {
            let lon = west + (i as f64 + 0.5) * deg_per_px;
            let alpha = px[(j * side as usize + i) * 4 + 3];
            if lon < edge - 2.0 * deg_per_px {
                assert_eq!(alpha, 0, "pixel ({i}, {j}) at {lon}° E");
            } else if lon > edge + 2.0 * deg_per_px {
                east += 1;
                drawn += usize::from(alpha == 255);
            }
        }
    }
    // East of the edge: terrain, but for SRTM's voids (8 % of the samples there,
    // each blanking its 3 × 3 window at the coarser level this zoom reads).
    assert!(
        drawn * 4 > east * 3,
        "{drawn} of {east} pixels east of 8° E drawn"
    );
    let r = srv.get("/v1/datasets/N46E008/webmercator/slope/12/100/100.png");
    assert!(r.error(404).contains("no data"), "{}", r.text());
}

#[test]
fn bad_requests_name_the_parameter() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    let srv = Server::start(&[&pyramid], &[]);
    let base = "/v1/datasets/N46E008/webmercator";
    for (path, status, says) in [
        ("/hillshade/11/1072/724.png?z_factor=0", 400, "z_factor"),
        ("/hillshade/11/1072/724.png?z_factor=-2", 400, "z_factor"),
        ("/hillshade/11/1072/724.png?z_factor=abc", 400, "z_factor"),
        ("/hillshade/11/1072/724.png?altitude=95", 400, "altitude"),
        ("/hillshade/11/1072/724.png?method=igor", 400, "method"),
        ("/hillshade/11/1072/724.png?azimuth=nan", 400, "azimuth"),
        ("/hillshade/11/1072/724.png?ramp=grey", 400, "\"ramp\""),
        (
            "/color-relief/11/1072/724.png?ramp=rainbow",
            400,
            "unknown ramp \"rainbow\"",
        ),
        ("/slope/11/1072/724.png?unit=radians", 400, "unit"),
        ("/slope/11/1072/724.png?ramp=relative", 400, "percentages"),
        ("/slope/11/1072/724.png?colour=red", 400, "\"colour\""),
        ("/slope/11/1072/724.png?size=300", 400, "size"),
        ("/hillshade/tilejson.json?format=gif", 400, "format"),
        ("/shaded/11/1072/724.png", 404, "unknown layer \"shaded\""),
        ("/hillshade/11/1072/724.jpg", 404, "rendered tiles are"),
        (
            "/hillshade/11/5000/724.png",
            404,
            "not in WebMercatorQuad zoom 11",
        ),
    ] {
        let r = srv.get(&format!("{base}{path}"));
        let reason = r.error(status);
        assert!(reason.contains(says), "{path}: {reason}");
    }
}

#[test]
fn bad_ramp_files_stop_the_server_with_the_file_and_line() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.txt");
    std::fs::write(&bad, "0 0 0 0\n500 12 300 4\n").unwrap();
    let p = pyramid.to_str().unwrap();
    let flag = format!("mine={}", bad.display());
    let e = serve_must_refuse(&[p, "--ramp", &flag]);
    assert!(
        e.contains("bad.txt") && e.contains("line 2") && e.contains("green \"300\""),
        "{e}"
    );
    let e = serve_must_refuse(&[p, "--ramp", "slope=/dev/null"]);
    assert!(e.contains("built-in"), "{e}");
    let e = serve_must_refuse(&[p, "--ramp", "mine"]);
    assert!(e.contains("NAME=FILE"), "{e}");
    let missing = format!("mine={}", dir.path().join("absent.txt").display());
    let e = serve_must_refuse(&[p, "--ramp", &missing]);
    assert!(e.contains("absent.txt"), "{e}");
}
