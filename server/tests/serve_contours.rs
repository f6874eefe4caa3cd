//! Contour tiles over HTTP with the server's default flags (API.md "Contour tiles"):
//! what a web map on another origin gets, and how bad and hostile intervals are
//! refused — a hostile interval costs a count, never an unbounded trace.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use mvt_reader::feature::Value;
use serve_support::{Server, compute, dem_pyramid, parse_metrics};
use std::io::Read;

/// Each feature's `ele` and `index`.
fn features(body: &[u8]) -> Vec<(f64, bool)> {
    let reader = mvt_reader::Reader::new(body.to_vec()).unwrap();
    assert_eq!(reader.get_layer_names().unwrap(), ["contours"]);
    reader
        .get_features(0)
        .unwrap()
        .into_iter()
        .map(|f| {
            let p = f.properties.unwrap();
            let ele = match p["ele"] {
                Value::SInt(v) => v as f64,
                Value::Double(v) => v,
                ref other => panic!("ele {other:?}"),
            };
            let Value::Bool(index) = p["index"] else {
                panic!("index {:?}", p["index"])
            };
            (ele, index)
        })
        .collect()
}

/// A map on another origin: the TileJSON's vector layer and absolute URL lead to
/// contour tiles at the interval it states for the zoom, with CORS, a strong ETag,
/// 304s and gzip.
#[test]
fn a_map_on_another_origin_gets_contour_tiles() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    let srv = Server::start(&[&pyramid], &[]);
    let origin = [("origin", "https://maps.example.org")];
    let tj = srv
        .get_with(
            "/v1/datasets/N46E008/webmercator/contours/tilejson.json",
            &origin,
        )
        .expect(200);
    assert_eq!(tj.must("access-control-allow-origin"), "*");
    let doc = tj.json();
    assert_eq!(doc["vector_layers"][0]["id"], "contours", "{doc}");
    let fields = &doc["vector_layers"][0]["fields"];
    assert!(
        fields["ele"].is_string() && fields["index"].is_string(),
        "{doc}"
    );
    assert_eq!(doc["minzoom"], 0, "automatic intervals suit every zoom");
    assert_eq!(doc["maxzoom"], 11, "{doc}");
    // The Alps at 46.5° N: 13.2 m pixels at zoom 12, 26.3 m at 11 → 3 px is 79 m → 100 m.
    let interval = doc["contour_intervals"]["11"].as_f64().unwrap();
    assert_eq!(interval, 100.0, "{doc}");
    assert_eq!(doc["contour_intervals"]["9"].as_f64().unwrap(), 500.0);
    let template = doc["tiles"][0].as_str().unwrap();
    assert!(template.starts_with("http://"), "{template}");
    assert!(template.contains("interval=auto&index=5"), "{template}");
    // Andermatt at zoom 11.
    let url = template.replace("{z}/{x}/{y}", "11/1072/724");
    let r = srv.get_with(&url, &origin).expect(200);
    assert_eq!(r.must("access-control-allow-origin"), "*");
    assert_eq!(r.must("content-type"), "application/vnd.mapbox-vector-tile");
    let etag = r.must("etag").to_string();
    assert!(!etag.starts_with("W/"), "{etag}");
    srv.get_with(&url, &[("if-none-match", etag.as_str())])
        .expect(304);
    let lines = features(&r.body);
    assert!(lines.len() > 100, "{} lines", lines.len());
    let mut index_lines = 0;
    for (ele, index) in &lines {
        assert_eq!(
            ele % interval,
            0.0,
            "{ele} m is not a multiple of {interval} m"
        );
        assert_eq!(
            *index,
            ele % (5.0 * interval) == 0.0,
            "index flag of {ele} m"
        );
        index_lines += usize::from(*index);
        // Andermatt's tile spans the Urseren valley (1400 m) to the Gotthard peaks.
        assert!((1000.0..=3700.0).contains(ele), "{ele} m");
    }
    assert!(index_lines > 10, "{index_lines} index contours");
    // Compressed for a client that accepts it.
    let zipped = srv
        .get_with(&url, &[("accept-encoding", "gzip")])
        .expect(200);
    assert_eq!(zipped.must("content-encoding"), "gzip");
    let mut unzipped = Vec::new();
    flate2::read::GzDecoder::new(&zipped.body[..])
        .read_to_end(&mut unzipped)
        .unwrap();
    assert!(unzipped == r.body && zipped.body.len() < r.body.len());
    // Another interval, another tile; beyond the dataset, a 404 with a reason.
    let fifty = srv
        .get("/v1/datasets/N46E008/webmercator/contours/11/1072/724.mvt?interval=50&index=0")
        .expect(200);
    assert_ne!(fifty.must("etag"), etag);
    let f = features(&fifty.body);
    assert!(f.len() > lines.len() && f.iter().all(|(e, i)| e % 50.0 == 0.0 && !i));
    let far = srv
        .get("/v1/datasets/N46E008/webmercator/contours/11/0/0.mvt")
        .expect(404);
    assert!(far.json()["error"].as_str().unwrap().contains("no data"));
    // The geographic grid too.
    let crs = srv
        .get("/v1/datasets/N46E008/crs84/contours/10/1072/247.mvt")
        .expect(200);
    assert!(!features(&crs.body).is_empty());
}

/// Bad parameters name themselves; an interval too fine for the zoom names the
/// finest it accepts; one too dense for the tile is refused after counting, with an
/// interval that draws it — and a crowd of such requests leaves the server serving.
#[test]
fn bad_and_hostile_intervals_are_refused_and_bounded() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    let srv = Server::start(&[&pyramid], &[]);
    let base = "/v1/datasets/N46E008/webmercator/contours";
    for (query, names, says) in [
        (
            "interval=0.001",
            "interval",
            "finer than the finest interval",
        ),
        ("interval=0", "interval", "positive"),
        ("interval=-20", "interval", "positive"),
        ("interval=abc", "interval", "neither a number"),
        ("interval=NaN", "interval", "neither a number"),
        ("index=-1", "index", "count of lines"),
        ("index=many", "index", "count of lines"),
        ("intervall=20", "\"intervall\"", "interval, index"),
        ("ramp=hypsometric", "\"ramp\"", "interval, index"),
    ] {
        let r = srv
            .get(&format!("{base}/11/1072/724.mvt?{query}"))
            .expect(400);
        let why = r.json()["error"].as_str().unwrap().to_string();
        assert!(why.contains(names) && why.contains(says), "{query}: {why}");
    }
    // The example: a 0.01 m interval at zoom 2 (38 km pixels).
    let r = srv
        .get(&format!("{base}/2/2/1.mvt?interval=0.01"))
        .expect(400);
    let why = r.json()["error"].as_str().unwrap().to_string();
    assert!(
        why.contains("zoom 2") && why.contains("finest interval is 200 m"),
        "{why}"
    );
    srv.get(&format!("{base}/2/2/1.mvt?interval=200"))
        .expect(200);
    srv.get(&format!("{base}/11/1072/724.png")).expect(404);
    // 1 m in the Alps at zoom 11: millions of pieces. Refused after one count, with
    // an interval that draws the tile.
    let r = srv
        .get(&format!("{base}/11/1072/724.mvt?interval=1"))
        .expect(400);
    let why = r.json()["error"].as_str().unwrap().to_string();
    assert!(why.contains("line pieces"), "{why}");
    let coarser = why
        .split("an interval of ")
        .nth(1)
        .and_then(|s| s.split(" m").next())
        .unwrap();
    srv.get(&format!("{base}/11/1072/724.mvt?interval={coarser}"))
        .expect(200);
    // A crowd of hostile requests on every tile around: each refused, none traced.
    std::thread::scope(|s| {
        for i in 0..16u32 {
            let srv = &srv;
            s.spawn(move || {
                let (x, y) = (1070 + i % 4, 722 + i / 4);
                srv.get(&format!("{base}/11/{x}/{y}.mvt?interval=1"))
                    .expect(400)
            });
        }
    });
    srv.get(&format!("{base}/11/1072/724.mvt")).expect(200);
    // Every refusal is counted as the caller's error, none as the server's; the dense
    // ones went through compute admission like any tile.
    let samples = parse_metrics(&srv.get("/metrics").expect(200).text());
    let requests = |route: &str, status: &str| -> f64 {
        samples
            .iter()
            .filter(|s| {
                s.name == "tessera_http_requests_total"
                    && s.labels.get("route").is_some_and(|r| r == route)
                    && s.labels.get("status").is_some_and(|v| v == status)
            })
            .map(|s| s.value)
            .sum()
    };
    let route = "/v1/datasets/{name}/{grid}/contours/{z}/{x}/{y}";
    // 9 bad parameters, zoom 2, the dense tile and the crowd of 16.
    assert_eq!(requests(route, "400"), 27.0);
    assert!(
        samples
            .iter()
            .all(|s| s.name != "tessera_http_requests_total"
                || !s.labels.get("status").is_some_and(|v| v.starts_with('5'))),
        "a server error"
    );
    assert!(
        compute(
            &samples,
            "tessera_compute_total",
            "contours",
            Some("started")
        ) >= 17.0
    );
}

/// `unit=ft`: intervals and `ele` in international feet. The 1000-ft lines are the
/// 304.8-m lines of the same heights, line for line.
#[test]
fn feet_lines_are_the_metre_lines_at_the_same_heights() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 256) else {
        return;
    };
    let srv = Server::start(&[&pyramid], &[]);
    let base = "/v1/datasets/N46E008/webmercator/contours";
    let doc = srv
        .get(&format!("{base}/tilejson.json?unit=ft"))
        .expect(200)
        .json();
    assert_eq!(doc["contour_unit"], "ft");
    assert!(
        doc["vector_layers"][0]["fields"]["ele"]
            .as_str()
            .unwrap()
            .contains("feet")
    );
    // 26.3 m pixels at zoom 11 (46.5° N): 3 px is 259 ft, so 500 ft (100 m in metres).
    assert_eq!(
        doc["contour_intervals"]["11"].as_f64().unwrap(),
        500.0,
        "{doc}"
    );
    let feet = features(
        &srv.get(&format!(
            "{base}/11/1072/724.mvt?unit=ft&interval=1000&index=0"
        ))
        .expect(200)
        .body,
    );
    let metres = features(
        &srv.get(&format!("{base}/11/1072/724.mvt?interval=304.8&index=0"))
            .expect(200)
            .body,
    );
    assert!(feet.len() > 50, "{} lines", feet.len());
    let mut a: Vec<i64> = feet
        .iter()
        .map(|(e, _)| {
            assert_eq!(e % 1000.0, 0.0, "{e} ft");
            (e * 0.3048 * 1000.0).round() as i64
        })
        .collect();
    let mut b: Vec<i64> = metres
        .iter()
        .map(|(e, _)| (e * 1000.0).round() as i64)
        .collect();
    a.sort_unstable();
    b.sort_unstable();
    assert_eq!(a, b, "the same lines at the same heights");
    srv.get(&format!("{base}/11/1072/724.mvt?unit=feet"))
        .expect(400);
}
