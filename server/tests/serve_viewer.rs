//! `tessera-server serve` end to end: the built-in viewer (DECISIONS.md "Real clients"):
//! the landing page `/`, `/viewer/{name}`, its assets under `/viewer/assets/…`,
//! `--no-viewer`, `--viewer-assets`, the preview picture and the dataset document's links
//! (API.md "The built-in viewer"). The browser side (MapLibre and CesiumJS really
//! drawing) is tests/browser/viewer.test.mjs.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{Server, bin, dem_pyramid, parse_metrics, raw_get, serve_must_refuse};
use std::path::{Path, PathBuf};

/// The files a complete assets directory must hold, and a few more of the kinds
/// CesiumJS loads, each with the `Content-Type` it must be served with.
const ASSETS: &[(&str, &str)] = &[
    ("maplibre/maplibre-gl.mjs", "text/javascript; charset=utf-8"),
    (
        "maplibre/maplibre-gl-worker.mjs",
        "text/javascript; charset=utf-8",
    ),
    ("maplibre/maplibre-gl.css", "text/css; charset=utf-8"),
    ("cesium/Cesium.js", "text/javascript; charset=utf-8"),
    ("cesium/Widgets/widgets.css", "text/css; charset=utf-8"),
    (
        "cesium/Workers/createVerticesFromQuantizedTerrainMesh.js",
        "text/javascript; charset=utf-8",
    ),
    ("cesium/ThirdParty/draco_decoder.wasm", "application/wasm"),
    (
        "cesium/Assets/approximateTerrainHeights.json",
        "application/json",
    ),
    (
        "cesium/Assets/Textures/NaturalEarthII/tilemapresource.xml",
        "application/xml",
    ),
    (
        "cesium/Assets/Textures/NaturalEarthII/0/0/0.jpg",
        "image/jpeg",
    ),
    ("cesium/Assets/Images/ion-credit.png", "image/png"),
    ("cesium/Assets/Textures/pin.svg", "image/svg+xml"),
    ("cesium/Assets/model.glb", "model/gltf-binary"),
    ("cesium/Assets/texture.ktx2", "image/ktx2"),
];

/// A stand-in assets directory (what server/viewer-assets.sh writes, with small files),
/// and a secret file beside it that no request may read.
fn fake_assets(root: &Path) -> PathBuf {
    let dir = root.join("assets");
    for (f, _) in ASSETS {
        let p = dir.join(f);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(&p, format!("/* {f} */\n")).unwrap();
    }
    std::fs::write(root.join("secret.txt"), "do not serve me").unwrap();
    // A link inside the directory pointing out of it.
    std::os::unix::fs::symlink(root.join("secret.txt"), dir.join("cesium/escape.js")).unwrap();
    dir
}

/// The N46E008 pyramid (EPSG:4326, SRTM) copied into `dir`, and a pyramid without
/// georeferencing built from a 16-bit PNG whose file name holds every HTML special
/// character (its `source` carries it onto the page), named `odd`.
fn datasets(dir: &Path) -> Option<(PathBuf, PathBuf)> {
    let n46 = dem_pyramid("N46E008.tif", 512)?;
    let png = tessera_shared::testdata::dem_or_skip("sthelens_10m.png")?;
    let ours = dir.join("N46E008.tess");
    std::fs::copy(&n46, &ours).unwrap();
    let odd_input = dir.join("st<b>\"helens\" & 'co'.png");
    std::fs::copy(&png, &odd_input).unwrap();
    let odd = dir.join("odd.tess");
    serve_support::build_pyramid(odd_input.to_str().unwrap(), &odd, 512);
    Some((ours, odd))
}

/// Every `href="…"` and `src="…"` value of an HTML page, unescaped.
fn urls(html: &str) -> Vec<String> {
    let mut out = Vec::new();
    for attr in ["href=\"", "src=\""] {
        let mut rest = html;
        while let Some(i) = rest.find(attr) {
            rest = &rest[i + attr.len()..];
            let end = rest.find('"').unwrap();
            out.push(
                rest[..end]
                    .replace("&amp;", "&")
                    .replace("&lt;", "<")
                    .replace("&gt;", ">")
                    .replace("&quot;", "\"")
                    .replace("&apos;", "'"),
            );
            rest = &rest[end..];
        }
    }
    out
}

/// `url` (relative to the page at `base`, a path ending in `/` or a file) as a path
/// from the server's root.
fn resolve(base: &str, url: &str) -> String {
    if url.starts_with('/') || url.starts_with("data:") {
        return url.to_string();
    }
    let mut parts: Vec<&str> = base.split('/').collect();
    parts.pop(); // the page itself
    for seg in url.split('/') {
        match seg {
            ".." => {
                parts.pop();
            }
            "." => {}
            s => parts.push(s),
        }
    }
    let joined = parts.join("/");
    if joined.starts_with('/') {
        joined
    } else {
        format!("/{joined}")
    }
}

#[test]
fn landing_page_lists_every_dataset_escaped_with_links_that_answer() {
    let tmp = tempfile::tempdir().unwrap();
    let Some((n46, odd)) = datasets(tmp.path()) else {
        return;
    };
    let assets = fake_assets(tmp.path());
    let srv = Server::start(
        &[&n46, &odd],
        &["--viewer-assets", assets.to_str().unwrap()],
    );
    let r = srv.get("/").expect(200);
    assert_eq!(r.must("content-type"), "text/html; charset=utf-8");
    assert_eq!(r.must("cache-control"), "no-cache");
    let html = r.text();
    for name in ["N46E008", "odd"] {
        assert!(
            html.contains(&format!("data-dataset=\"{name}\"")),
            "{name} listed"
        );
    }
    // The source file name is on the page, escaped: nothing of it became markup.
    assert!(
        html.contains("st&lt;b&gt;&quot;helens&quot; &amp; &apos;co&apos;.png"),
        "escaped source name"
    );
    assert!(!html.contains("<b>\"helens"), "raw source name in the page");
    // The georeferenced dataset links every interface; the other says what it lacks.
    let n46_part = &html[html.find("data-dataset=\"N46E008\"").unwrap()
        ..html.find("data-dataset=\"odd\"").unwrap()];
    for (key, href) in [
        ("viewer", "viewer/N46E008"),
        (
            "webmercator-terrarium",
            "v1/datasets/N46E008/webmercator/tilejson.json?encoding=terrarium",
        ),
        (
            "webmercator-mapbox",
            "v1/datasets/N46E008/webmercator/tilejson.json?encoding=mapbox",
        ),
        (
            "crs84-terrarium",
            "v1/datasets/N46E008/crs84/tilejson.json?encoding=terrarium",
        ),
        (
            "crs84-mapbox",
            "v1/datasets/N46E008/crs84/tilejson.json?encoding=mapbox",
        ),
        (
            "wmts",
            "v1/datasets/N46E008/wmts/1.0.0/WMTSCapabilities.xml",
        ),
        ("wmts-all", "wmts/1.0.0/WMTSCapabilities.xml"),
        ("ogcapi", "ogcapi"),
        ("ogcapi-collection", "ogcapi/collections/N46E008"),
        (
            "ogcapi-tilesets",
            "ogcapi/collections/N46E008/coverage/tiles",
        ),
        ("cesium", "v1/datasets/N46E008/cesium/layer.json"),
        ("pyramid", "v1/datasets/N46E008/pyramid"),
        ("document", "v1/datasets/N46E008"),
        ("dataset", "v1/datasets/N46E008"),
    ] {
        let want = format!("href=\"{href}\" data-link=\"{key}\"");
        assert!(n46_part.contains(&want), "N46E008: {want}");
    }
    assert!(
        n46_part.contains("7.9996° E … 9.0004° E, 45.9996° N … 47.0004° N"),
        "WGS 84 extent"
    );
    assert!(n46_part.contains("EPSG:4326"), "CRS");
    assert!(n46_part.contains("1201 × 1201 samples, 3 levels"), "size");
    assert!(n46_part.contains("vertical datum"), "datum");
    let odd_part = &html[html.find("data-dataset=\"odd\"").unwrap()..];
    for key in [
        "viewer",
        "webmercator-terrarium",
        "wmts\"",
        "ogcapi-collection",
        "cesium",
    ] {
        assert!(
            !odd_part.contains(&format!("data-link=\"{key}")),
            "odd links {key}"
        );
    }
    assert!(
        odd_part.contains("unavailable: the dataset has no georeferencing"),
        "odd says why"
    );
    assert!(
        odd_part.contains("data-link=\"pyramid\""),
        "odd still links its pyramid"
    );
    // Every link and picture on the page answers 200.
    let all = urls(&html);
    assert!(all.len() > 30, "{} links", all.len());
    for u in all.iter().filter(|u| !u.starts_with("data:")) {
        let path = resolve("/", u);
        srv.get(&path).expect(200);
    }
}

#[test]
fn dataset_names_can_never_carry_markup() {
    // Names are file stems of [A-Za-z0-9_.-] (API.md): one with `<` or `&` stops the
    // server, so it never reaches a page.
    let tmp = tempfile::tempdir().unwrap();
    let Some(n46) = dem_pyramid("N46E008.tif", 512) else {
        return;
    };
    for bad in ["a<b.tess", "a&b.tess"] {
        let f = tmp.path().join(bad);
        std::fs::copy(&n46, &f).unwrap();
        let e = serve_must_refuse(&[f.to_str().unwrap()]);
        assert!(e.contains("must be letters, digits"), "{bad}: {e}");
        std::fs::remove_file(&f).unwrap();
    }
}

#[test]
fn viewer_page_carries_its_config_and_unknown_datasets_are_json_404s() {
    let tmp = tempfile::tempdir().unwrap();
    let Some((n46, odd)) = datasets(tmp.path()) else {
        return;
    };
    let assets = fake_assets(tmp.path());
    let srv = Server::start(
        &[&n46, &odd],
        &["--viewer-assets", assets.to_str().unwrap()],
    );
    let r = srv.get("/viewer/N46E008").expect(200);
    assert_eq!(r.must("content-type"), "text/html; charset=utf-8");
    let html = r.text();
    let start = html.find("id=\"tessera-config\">").unwrap() + "id=\"tessera-config\">".len();
    let end = start + html[start..].find("</script>").unwrap();
    let config: serde_json::Value = serde_json::from_str(&html[start..end]).unwrap();
    assert_eq!(config["name"], "N46E008");
    assert_eq!(
        config["tilejson"],
        "../v1/datasets/N46E008/webmercator/tilejson.json?encoding=terrarium&size=512"
    );
    assert_eq!(config["cesium"], "../v1/datasets/N46E008/cesium/");
    assert_eq!(config["earth"], true);
    let b: Vec<f64> = serde_json::from_value(config["bounds"].clone()).unwrap();
    assert!(
        (b[0] - 7.99958).abs() < 1e-4 && (b[3] - 47.00042).abs() < 1e-4,
        "{b:?}"
    );
    // Every URL of the page (relative to it) answers, the scripts and styles included,
    // and so does the TileJSON the script reads.
    for u in urls(&html).iter().filter(|u| !u.starts_with("data:")) {
        srv.get(&resolve("/viewer/N46E008", u)).expect(200);
    }
    let tilejson = resolve("/viewer/N46E008", config["tilejson"].as_str().unwrap());
    assert_eq!(
        tilejson,
        "/v1/datasets/N46E008/webmercator/tilejson.json?encoding=terrarium&size=512"
    );
    srv.get(&tilejson).expect(200);
    // A dataset without a place on a map: a page saying why, with its preview.
    let page = srv.get("/viewer/odd").expect(200).text();
    assert!(
        page.contains("No map view") && page.contains("no georeferencing"),
        "{page}"
    );
    assert!(
        !page.contains("tessera-config"),
        "no viewer script without a map"
    );
    // Unknown and invalid names are the API's JSON errors.
    let e = srv.get("/viewer/nope").error(404);
    assert!(e.contains("unknown dataset"), "{e}");
    let r = raw_get(srv.addr, "/viewer/%2e%2e");
    assert_eq!(r.status, 400);
    assert!(r.headers["content-type"].starts_with("application/json"));
    srv.get("/viewer/").error(404);
}

#[test]
fn assets_are_served_with_their_types_and_never_from_outside() {
    let tmp = tempfile::tempdir().unwrap();
    let Some(n46) = dem_pyramid("N46E008.tif", 512) else {
        return;
    };
    let assets = fake_assets(tmp.path());
    let srv = Server::start(&[&n46], &["--viewer-assets", assets.to_str().unwrap()]);
    for (file, kind) in ASSETS {
        let r = srv.get(&format!("/viewer/assets/{file}")).expect(200);
        assert_eq!(r.must("content-type"), *kind, "{file}");
        assert_eq!(r.must("cache-control"), "public, max-age=86400", "{file}");
        assert_eq!(r.text(), format!("/* {file} */\n"), "{file}");
        let etag = r.must("etag").to_string();
        r.must("last-modified");
        srv.get_with(
            &format!("/viewer/assets/{file}"),
            &[("if-none-match", &etag)],
        )
        .expect(304);
    }
    // The viewer's own files, from the binary.
    let js = srv.get("/viewer/assets/tessera/viewer.js").expect(200);
    assert_eq!(js.must("content-type"), "text/javascript; charset=utf-8");
    assert!(js.text().contains("window.tessera"));
    srv.get("/viewer/assets/tessera/viewer.css").expect(200);
    srv.get("/viewer/assets/tessera/nope.js").error(404);
    srv.get("/viewer/assets/other/Cesium.js").error(404);
    // Traversal, raw (no client normalises these away): never the secret, always JSON.
    for target in [
        "/viewer/assets/cesium/../../secret.txt",
        "/viewer/assets/cesium/../../../etc/passwd",
        "/viewer/assets/cesium/%2e%2e/%2e%2e/secret.txt",
        "/viewer/assets/cesium/%2E%2E/%2E%2E/etc/passwd",
        "/viewer/assets/cesium/..%2f..%2fsecret.txt",
        "/viewer/assets/cesium/Assets%5c..%5c..%5csecret.txt",
        "/viewer/assets/cesium/%2fetc%2fpasswd",
        "/viewer/assets/cesium//etc/passwd",
        "/viewer/assets/cesium/./Cesium.js",
        "/viewer/assets/cesium/escape.js",
        "/viewer/assets/cesium/Assets%00.js",
        "/viewer/assets/maplibre/../cesium/Cesium.js",
    ] {
        let r = raw_get(srv.addr, target);
        assert!(r.status == 404 || r.status == 400, "{target}: {}", r.status);
        let body = String::from_utf8_lossy(&r.body);
        assert!(
            !body.contains("do not serve me") && !body.contains("root:"),
            "{target}: {body}"
        );
        assert!(
            r.headers["content-type"].starts_with("application/json"),
            "{target}"
        );
    }
}

#[test]
fn missing_assets_give_a_page_that_says_how_to_prepare_them() {
    let tmp = tempfile::tempdir().unwrap();
    let Some(n46) = dem_pyramid("N46E008.tif", 512) else {
        return;
    };
    let empty = tmp.path().join("no-assets-here");
    std::fs::create_dir(&empty).unwrap();
    let srv = Server::start(&[&n46], &["--viewer-assets", empty.to_str().unwrap()]);
    let page = srv.get("/viewer/N46E008").expect(200).text();
    let dir = empty.canonicalize().unwrap_or(empty.clone());
    assert!(
        page.contains(&empty.display().to_string()) || page.contains(&dir.display().to_string()),
        "{page}"
    );
    assert!(
        page.contains(&format!("server/viewer-assets.sh {}", empty.display())),
        "the command: {page}"
    );
    assert!(
        !page.contains("tessera-config"),
        "no viewer script without its libraries"
    );
    // The landing page needs no library, and says the same.
    let landing = srv.get("/").expect(200).text();
    assert!(landing.contains("data-dataset=\"N46E008\""));
    assert!(landing.contains("server/viewer-assets.sh"));
    let e = srv.get("/viewer/assets/cesium/Cesium.js").error(404);
    assert!(e.contains("server/viewer-assets.sh"), "{e}");
    // One warning at start-up.
    std::thread::sleep(std::time::Duration::from_millis(200));
    let warnings = srv
        .log()
        .lines()
        .filter(|l| l.contains("WARN") && l.contains("viewer assets"))
        .count();
    assert_eq!(warnings, 1, "{}", srv.log());
}

#[test]
fn no_viewer_turns_the_pages_off_and_keeps_the_api() {
    let tmp = tempfile::tempdir().unwrap();
    let Some(n46) = dem_pyramid("N46E008.tif", 512) else {
        return;
    };
    let assets = fake_assets(tmp.path());
    let on = Server::start(&[&n46], &["--viewer-assets", assets.to_str().unwrap()]);
    let doc_on = on.get("/v1/datasets/N46E008").expect(200);
    assert_eq!(doc_on.json()["links"]["viewer"], "/viewer/N46E008");
    let cfg = tmp.path().join("t.toml");
    std::fs::write(&cfg, "no_viewer = true\n").unwrap();
    for (flags, env) in [
        (vec!["--no-viewer"], vec![]),
        (vec![], vec![("TESSERA_NO_VIEWER", "true")]),
        (vec!["--config", cfg.to_str().unwrap()], vec![]),
    ] {
        let mut f = flags.clone();
        f.extend(["--viewer-assets", assets.to_str().unwrap()]);
        let srv = Server::start_with(&[&n46], &f, &env);
        for path in [
            "/",
            "/viewer/N46E008",
            "/viewer/assets/tessera/viewer.js",
            "/viewer/assets/cesium/Cesium.js",
        ] {
            let e = srv.get(path).error(404);
            assert!(
                e.contains("no such endpoint"),
                "{flags:?} {env:?} {path}: {e}"
            );
        }
        let doc = srv.get("/v1/datasets/N46E008").expect(200);
        let links = &doc.json()["links"];
        assert!(links.get("viewer").is_none(), "{links}");
        assert_eq!(links["cesium"], "/v1/datasets/N46E008/cesium/layer.json");
        // The document's tag says which it is.
        assert_ne!(doc.must("etag"), doc_on.must("etag"));
        srv.get("/v1/datasets/N46E008/preview.png").expect(200);
    }
}

#[test]
fn document_links_answer_and_name_only_what_applies() {
    let tmp = tempfile::tempdir().unwrap();
    let Some((n46, odd)) = datasets(tmp.path()) else {
        return;
    };
    let srv = Server::start(&[&n46, &odd], &[]);
    let doc = srv.get("/v1/datasets/N46E008").expect(200).json();
    let links = doc["links"].as_object().unwrap();
    let mut strings = Vec::new();
    for (k, v) in links {
        match v {
            serde_json::Value::String(s) => strings.push((k.clone(), s.clone())),
            serde_json::Value::Object(grids) => {
                for (tms, encodings) in grids {
                    for (enc, url) in encodings.as_object().unwrap() {
                        strings.push((
                            format!("{k}.{tms}.{enc}"),
                            url.as_str().unwrap().to_string(),
                        ));
                    }
                }
            }
            other => panic!("link {k}: {other}"),
        }
    }
    for key in [
        "self",
        "tilejson",
        "pyramid",
        "tiles",
        "errors",
        "tile",
        "png",
        "bootstrap",
        "preview",
        "wmts",
        "ogcapi_collection",
        "ogcapi_tilesets",
        "cesium",
        "viewer",
        "standard_grids.WebMercatorQuad.terrarium",
        "standard_grids.WebMercatorQuad.mapbox",
        "standard_grids.WorldCRS84Quad.terrarium",
        "standard_grids.WorldCRS84Quad.mapbox",
    ] {
        assert!(
            strings.iter().any(|(k, _)| k == key),
            "no link {key}: {links:?}"
        );
    }
    // Each answers 200 (templates filled with the root tile).
    for (k, url) in &strings {
        let url = url
            .replace("{level}", "0")
            .replace("{ranges}", "0")
            .replace("{x}", "0")
            .replace("{y}", "0")
            .replace("{z}", "0");
        let r = srv.get(&url);
        // The viewer page only when its assets are found beside the binary; either way 200.
        assert_eq!(r.status, 200, "{k}: {url}: {}", r.text());
    }
    // Without georeferencing: the grids, WMTS, OGC API, Cesium and the viewer are not
    // linked, and indeed answer 404.
    let doc = srv.get("/v1/datasets/odd").expect(200).json();
    let links = doc["links"].as_object().unwrap();
    for key in [
        "standard_grids",
        "wmts",
        "ogcapi_collection",
        "ogcapi_tilesets",
        "cesium",
        "viewer",
    ] {
        assert!(!links.contains_key(key), "odd links {key}");
    }
    for path in [
        "/v1/datasets/odd/webmercator/tilejson.json",
        "/v1/datasets/odd/wmts/1.0.0/WMTSCapabilities.xml",
        "/ogcapi/collections/odd",
        "/v1/datasets/odd/cesium/layer.json",
    ] {
        srv.get(path).error(404);
    }
    srv.get(links["preview"].as_str().unwrap()).expect(200);
    // The list carries the same links.
    let list = srv.get("/v1/datasets").expect(200).json();
    assert_eq!(list["datasets"][0]["links"]["viewer"], "/viewer/N46E008");
}

#[test]
fn the_preview_is_a_computed_cacheable_png() {
    let Some(n46) = dem_pyramid("N46E008.tif", 512) else {
        return;
    };
    let srv = Server::start(&[&n46], &[]);
    let r = srv.get("/v1/datasets/N46E008/preview.png").expect(200);
    assert_eq!(r.must("content-type"), "image/png");
    let etag = r.must("etag").to_string();
    assert!(r.must("cache-control").starts_with("public, max-age="));
    let mut reader = png::Decoder::new(std::io::Cursor::new(r.body.clone()))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    // 1° × 1° at 46° N: narrower than tall, the longer side 256.
    assert_eq!((info.width, info.height), (177, 256));
    assert_eq!(info.color_type, png::ColorType::Rgba);
    let px = &buf[..info.buffer_size()];
    let opaque = px.chunks_exact(4).filter(|p| p[3] == 255).count();
    let n = (info.width * info.height) as usize;
    // SRTM voids (7 % of the samples) are transparent; the rest is terrain.
    assert!(opaque > n * 8 / 10 && opaque < n, "{opaque} of {n} opaque");
    srv.get_with(
        "/v1/datasets/N46E008/preview.png",
        &[("if-none-match", &etag)],
    )
    .expect(304);
    let hash = srv.get("/v1/datasets/N46E008").json()["content_hash"]
        .as_str()
        .unwrap()
        .to_string();
    let pinned = srv
        .get(&format!("/v1/datasets/N46E008/preview.png?v={hash}"))
        .expect(200);
    assert_eq!(
        pinned.must("cache-control"),
        "public, max-age=31536000, immutable"
    );
    assert_eq!(pinned.body, r.body, "the same picture every time");
    // Made by the compute admission (a kind of its own in /metrics).
    let m = parse_metrics(&srv.get("/metrics").text());
    let started: f64 = m
        .iter()
        .filter(|s| {
            s.name == "tessera_compute_total"
                && s.labels.get("kind").map(String::as_str) == Some("preview")
                && s.labels.get("outcome").map(String::as_str) == Some("started")
        })
        .map(|s| s.value)
        .sum();
    assert_eq!(started, 2.0, "two made (the 304 made none)");
    srv.get("/v1/datasets/nope/preview.png").error(404);
}

#[test]
fn help_names_the_viewer_flags() {
    let o = bin().args(["serve", "--help"]).output().unwrap();
    let help = String::from_utf8_lossy(&o.stdout);
    assert!(
        help.contains("--no-viewer") && help.contains("--viewer-assets"),
        "{help}"
    );
}
