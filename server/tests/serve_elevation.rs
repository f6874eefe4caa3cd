//! The elevation API end to end (API.md "Elevation queries"): real pyramids of real
//! DEMs (N46E008, EPSG:4326 with voids; aletsch, EPSG:2056), a real `tessera-server
//! serve` with its default flags, real HTTP. Heights are checked against GDAL's own
//! bilinear warp of the source file, error bounds against the finest data at every
//! point and several accuracies, profiles against point queries.
#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

mod gdal;
#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serde_json::{Value, json};
use serve_support::{Server, dem_pyramid};
use std::path::Path;
use tessera_shared::testdata;

/// A small deterministic generator (xorshift64*), so failures reproduce.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }

    fn between(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.next()
    }
}

/// `[west, south, east, north]` of a DEM in WGS 84, as GDAL states it.
fn wgs84_extent(dem: &Path) -> [f64; 4] {
    let info: Value =
        serde_json::from_str(&gdal::run("gdalinfo", &["-json", gdal::path_str(dem)])).unwrap();
    let ring = info["wgs84Extent"]["coordinates"][0].as_array().unwrap();
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for p in ring {
        let (x, y) = (p[0].as_f64().unwrap(), p[1].as_f64().unwrap());
        b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
    }
    b
}

/// One answer, as the API gives it.
#[derive(Debug, Clone, Copy)]
struct Answer {
    lat: f64,
    lon: f64,
    elevation: Option<f64>,
    level: Option<u64>,
    bound: Option<f64>,
}

fn answers(doc: &Value) -> Vec<Answer> {
    doc["results"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| Answer {
            lat: r["lat"].as_f64().unwrap(),
            lon: r["lon"].as_f64().unwrap(),
            elevation: r["elevation"].as_f64(),
            level: r["level"].as_u64(),
            bound: r["error_bound"].as_f64(),
        })
        .collect()
}

/// POSTs `points` (`[lat, lon]`) with `options` (more JSON keys).
fn post(server: &Server, name: &str, points: &[[f64; 2]], options: Value) -> Vec<Answer> {
    let mut body = options;
    body["locations"] = json!(points);
    let r = server
        .post(
            &format!("/v1/datasets/{name}/elevation"),
            "application/json",
            serde_json::to_vec(&body).unwrap(),
        )
        .expect(200);
    let a = answers(&r.json());
    assert_eq!(a.len(), points.len());
    a
}

/// GDAL's bilinear at the pixel centres of a `n × n` lattice in WGS 84 (`gdalwarp -r
/// bilinear -et 0`: exact transforms, the 2 × 2 kernel since the lattice is finer
/// than the DEM), row by row from the north; `None` where GDAL has no value or where
/// the kernel touches a void (the same warp reading the no-data value as a height
/// then differs).
fn gdal_lattice(dem: &Path, te: [f64; 4], n: usize, dir: &Path) -> Vec<([f64; 2], Option<f64>)> {
    let warp = |extra: &[&str], out: &str| -> Vec<(f64, f64, f64)> {
        let tif = dir.join(format!("{out}.tif"));
        let xyz = dir.join(format!("{out}.xyz"));
        let te: Vec<String> = te.iter().map(|v| format!("{v:.12}")).collect();
        let ts = n.to_string();
        let mut args = vec![
            "-q",
            "-overwrite",
            "-et",
            "0",
            "-r",
            "bilinear",
            "-t_srs",
            "EPSG:4326",
            "-te",
            &te[0],
            &te[1],
            &te[2],
            &te[3],
            "-ts",
            &ts,
            &ts,
            "-wt",
            "Float64",
            "-ot",
            "Float64",
            "-dstnodata",
            "-99999",
        ];
        args.extend_from_slice(extra);
        args.extend_from_slice(&[gdal::path_str(dem), gdal::path_str(&tif)]);
        gdal::run("gdalwarp", &args);
        gdal::run(
            "gdal_translate",
            &[
                "-q",
                "-of",
                "XYZ",
                gdal::path_str(&tif),
                gdal::path_str(&xyz),
            ],
        );
        std::fs::read_to_string(&xyz)
            .unwrap()
            .lines()
            .map(|l| {
                let v: Vec<f64> = l.split_whitespace().map(|t| t.parse().unwrap()).collect();
                (v[0], v[1], v[2])
            })
            .collect()
    };
    let with_nodata = warp(&[], "a");
    let as_heights = warp(&["-srcnodata", "None"], "b");
    with_nodata
        .iter()
        .zip(&as_heights)
        .map(|(&(x, y, z), &(_, _, raw))| {
            let ok = z != -99999.0 && (z - raw).abs() < 1e-6;
            ([y, x], ok.then_some(z))
        })
        .collect()
}

/// Bilinear heights equal GDAL's bilinear warp of the source file within the
/// quantization error, at 10 000 points each (25 lattices of 20 × 20 at random
/// places, spacings and offsets) on N46E008 (EPSG:4326, pixel-is-point, voids) and
/// aletsch (EPSG:2056, float heights), served with the default flags.
#[test]
fn bilinear_heights_equal_gdals_bilinear_on_the_source() {
    if !gdal::gdal_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    for (file, tile) in [("N46E008.tif", 512), ("aletsch.tif", 64)] {
        let (Some(src), Some(pyramid)) = (testdata::dem_or_skip(file), dem_pyramid(file, tile))
        else {
            return;
        };
        let name = file.trim_end_matches(".tif");
        let server = Server::start(&[&pyramid], &[]);
        let q = server
            .get(&format!("/v1/datasets/{name}"))
            .expect(200)
            .json()["quantization"]["max_error"]
            .as_f64()
            .unwrap();
        let [w, s, e, n] = wgs84_extent(&src);
        let width = gdal::run("gdalinfo", &["-json", gdal::path_str(&src)]);
        let size: Value = serde_json::from_str(&width).unwrap();
        let px = (e - w) / size["size"][0].as_f64().unwrap();
        let py = (n - s) / size["size"][1].as_f64().unwrap();
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15 ^ tile as u64);
        let mut points = Vec::new();
        let mut expected = Vec::new();
        for _ in 0..25 {
            // Finer than the DEM (so GDAL's kernel is 2 × 2), inside it by a margin.
            let step = rng.between(0.3, 0.9);
            let (dx, dy) = (px * step, py * step);
            let x0 = rng.between(w + 0.2 * (e - w), e - 0.2 * (e - w) - 20.0 * dx);
            let y0 = rng.between(s + 0.2 * (n - s), n - 0.2 * (n - s) - 20.0 * dy);
            for (p, z) in gdal_lattice(
                &src,
                [x0, y0, x0 + 20.0 * dx, y0 + 20.0 * dy],
                20,
                dir.path(),
            ) {
                points.push(p);
                expected.push(z);
            }
        }
        assert_eq!(points.len(), 10_000);
        let got = post(&server, name, &points, json!({"interpolation": "bilinear"}));
        let (mut compared, mut worst) = (0, 0f64);
        for (i, (a, z)) in got.iter().zip(&expected).enumerate() {
            let (Some(z), Some(h)) = (z, a.elevation) else {
                continue;
            };
            let d = (h - z).abs();
            // GDAL's kernel runs in single precision for integer sources: 1 mm.
            assert!(
                d <= q + 1e-3,
                "{name} point {i} {:?}: ours {h}, GDAL {z} (|Δ| {d} > q {q})",
                points[i]
            );
            worst = worst.max(d);
            compared += 1;
        }
        eprintln!(
            "{name}: {compared} of 10000 points compared with GDAL, worst |Δ| {worst:.6} m (quantization error {q:.6} m)"
        );
        assert!(
            compared >= 8_000,
            "{name}: only {compared} points comparable"
        );
    }
}

/// At 10 000 random points on each DEM (pyramids of 64-cell tiles, so 4 to 6
/// levels) and a patch of exact sample positions, for each kernel and several
/// accuracies: every answer is within its `error_bound` of the finest data's answer,
/// the bound meets the accuracy unless the finest data answers, coarser levels do
/// answer, and somewhere the difference is more than half the bound (so a halved
/// bound would fail).
#[test]
fn every_error_bound_holds_against_the_finest_data() {
    for file in ["N46E008.tif", "aletsch.tif"] {
        let (Some(src), Some(pyramid)) = (testdata::dem_or_skip(file), dem_pyramid(file, 64))
        else {
            return;
        };
        let name = file.trim_end_matches(".tif");
        let server = Server::start(&[&pyramid], &[]);
        let [w, s, e, n] = if gdal::gdal_or_skip() {
            wgs84_extent(&src)
        } else {
            return;
        };
        let mut rng = Rng(0x5eed ^ file.len() as u64);
        let mut points: Vec<[f64; 2]> = (0..10_000)
            .map(|_| [rng.between(s, n), rng.between(w, e)])
            .collect();
        // A patch on the finest samples near the middle, where kernels read samples
        // exactly (N46E008's samples are at whole 1/1200 degrees).
        let (clat, clon) = (f64::midpoint(s, n), f64::midpoint(w, e));
        for j in 0..30 {
            for i in 0..30 {
                let (lat, lon) = (
                    (clat * 1200.0).round() / 1200.0 - f64::from(j) / 1200.0,
                    (clon * 1200.0).round() / 1200.0 + f64::from(i) / 1200.0,
                );
                points.push([lat, lon]);
            }
        }
        for (method, count) in [
            ("bilinear", points.len()),
            ("nearest", 3000),
            ("cubic", 3000),
        ] {
            let pts = &points[..count];
            let fine = post(&server, name, pts, json!({"interpolation": method}));
            let finest = fine.iter().filter_map(|a| a.level).max().unwrap();
            let mut worst_ratio = 0f64;
            for accuracy in [2.0, 10.0, 40.0, 150.0, 600.0] {
                let got = post(
                    &server,
                    name,
                    pts,
                    json!({"interpolation": method, "accuracy": accuracy}),
                );
                let mut coarse = 0;
                for (i, (a, f)) in got.iter().zip(&fine).enumerate() {
                    let (Some(h), Some(hf), Some(bound)) = (a.elevation, f.elevation, a.bound)
                    else {
                        continue;
                    };
                    let d = (h - hf).abs();
                    assert!(
                        d <= bound + 1e-9,
                        "{name} {method} accuracy {accuracy} point {i} {:?}: level {:?} answers {h}, the finest {hf}: |Δ| {d} > bound {bound}",
                        pts[i],
                        a.level
                    );
                    assert!(
                        bound <= accuracy || a.level == f.level,
                        "{name} {method}: bound {bound} > {accuracy} from level {:?}",
                        a.level
                    );
                    if a.level < f.level {
                        coarse += 1;
                        worst_ratio = worst_ratio.max(d / bound);
                    }
                }
                eprintln!(
                    "{name} {method} accuracy {accuracy} m: {coarse} of {count} answered by a coarser level than the finest ({finest})"
                );
                if accuracy >= 150.0 {
                    assert!(
                        coarse > count / 10,
                        "{name} {method} accuracy {accuracy}: only {coarse} coarser answers"
                    );
                }
            }
            eprintln!("{name} {method}: worst |Δ| / bound {worst_ratio:.3}");
            assert!(
                worst_ratio > 0.5,
                "{name} {method}: the bound is never more than twice the difference it bounds"
            );
        }
    }
}

/// A profile's points asked for again as locations get the very same answers; a
/// polyline path and `spacing=` work; the first and last points are the path's ends.
#[test]
fn profiles_equal_point_queries_at_the_same_positions() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 64) else {
        return;
    };
    let server = Server::start(&[&pyramid], &[]);
    let base = "/v1/datasets/N46E008/elevation";
    for (query, count) in [
        ("path=46.1,8.1|46.5,8.6|46.9,8.2&samples=257", 257),
        // Google's encoded polyline of the same three vertices.
        (
            "path=enc:_%7CjxG_%60mp@_cmA_t%60B_cmA~bmA&samples=100&interpolation=cubic",
            100,
        ),
        ("locations=46.1,8.1|46.9,8.2&spacing=500&accuracy=20", 0),
    ] {
        let profile = answers(&server.get(&format!("{base}?{query}")).expect(200).json());
        if count > 0 {
            assert_eq!(profile.len(), count, "{query}");
        }
        assert!((profile[0].lat - 46.1).abs() < 1e-9 && (profile[0].lon - 8.1).abs() < 1e-9);
        let last = profile.last().unwrap();
        assert!(
            (last.lat - 46.9).abs() < 1e-9 && (last.lon - 8.2).abs() < 1e-9,
            "{query}: ends at {last:?}"
        );
        let points: Vec<[f64; 2]> = profile.iter().map(|a| [a.lat, a.lon]).collect();
        let method = if query.contains("cubic") {
            "cubic"
        } else {
            "bilinear"
        };
        let mut options = json!({"interpolation": method});
        if query.contains("accuracy=20") {
            options["accuracy"] = json!(20.0);
        }
        let again = post(&server, "N46E008", &points, options);
        for (p, a) in profile.iter().zip(&again) {
            assert_eq!(
                (p.elevation, p.level, p.bound),
                (a.elevation, a.level, a.bound),
                "{query} at {p:?}"
            );
        }
        // Inside the DEM: heights everywhere but over the radar voids it crosses.
        let voids = profile.iter().filter(|a| a.elevation.is_none()).count();
        assert!(
            voids * 4 < profile.len(),
            "{query}: {voids} points without a height"
        );
    }
}

/// Every malformed request is a 4xx with a JSON reason naming the parameter, with
/// the default limits (100 000 points, 16 MiB bodies).
#[test]
fn bad_requests_name_the_parameter() {
    let Some(pyramid) = dem_pyramid("N46E008.tif", 512) else {
        return;
    };
    let server = Server::start(&[&pyramid], &[]);
    let base = "/v1/datasets/N46E008/elevation";
    for (query, want) in [
        ("locations=46.5,8.1|46.6", "locations: point 2"),
        ("locations=91,8", "latitude 91"),
        ("locations=46.5,181", "longitude 181"),
        ("locations=46.5,8.1&interpolation=spline", "interpolation="),
        ("locations=46.5,8.1&accuracy=0", "accuracy="),
        ("locations=46.5,8.1&datum=navd88", "datum="),
        (
            "locations=46.5,8.1&colour=red",
            "unknown parameter \"colour\"",
        ),
        (
            "path=46.5,8.1|46.6,8.2",
            "samples= (a number of points) or spacing=",
        ),
        (
            "path=46.5,8.1|46.6,8.2&samples=100001",
            "more than the 100000",
        ),
        (
            "path=46.5,8.1|46.6,8.2&spacing=0.001",
            "more than the 100000",
        ),
        ("", "locations= or path= is required"),
    ] {
        let e = server.get(&format!("{base}?{query}")).error(400);
        assert!(e.contains(want), "{query}: {e}");
    }
    let post = |ct: &str, body: Vec<u8>| server.post(base, ct, body);
    // 100 001 points: one more than allowed, refused while parsing.
    let many: Vec<[f64; 2]> = (0..100_001)
        .map(|i| [46.5, 8.0 + f64::from(i) * 1e-6])
        .collect();
    let e = post(
        "application/json",
        serde_json::to_vec(&json!({"locations": many})).unwrap(),
    )
    .error(400);
    assert!(e.contains("more than the 100000 points"), "{e}");
    // More than 16 MiB: refused by its Content-Length before a byte of it is read.
    {
        use std::io::{Read, Write};
        let mut s = std::net::TcpStream::connect(server.addr).unwrap();
        write!(
            s,
            "POST {base} HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{{\"locations\": ",
            17 << 20
        )
        .unwrap();
        let mut head = vec![0u8; 4096];
        let n = s.read(&mut head).unwrap();
        let text = String::from_utf8_lossy(&head[..n]);
        assert!(text.starts_with("HTTP/1.1 413"), "{text}");
        assert!(
            text.contains("--max-body-mib") && text.contains("application/json"),
            "{text}"
        );
    }
    // Chunked (no Content-Length): refused once more than 16 MiB has come.
    {
        use std::io::{Read, Write};
        let mut s = std::net::TcpStream::connect(server.addr).unwrap();
        write!(
            s,
            "POST {base} HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n"
        )
        .unwrap();
        let chunk = format!("100000\r\n{}\r\n", " ".repeat(1 << 20));
        // The server stops reading after 16 MiB: later writes may fail.
        for _ in 0..20 {
            if s.write_all(chunk.as_bytes()).is_err() {
                break;
            }
        }
        let mut all = Vec::new();
        let _ = s.read_to_end(&mut all);
        let text = String::from_utf8_lossy(&all);
        assert!(
            text.starts_with("HTTP/1.1 413"),
            "{}",
            &text[..text.len().min(300)]
        );
        assert!(text.contains("--max-body-mib"), "{text}");
    }
    for (body, want) in [
        (
            r#"{"locations": [[46.5, 8.1]], "colour": 1}"#,
            "unknown parameter \"colour\"",
        ),
        (r#"{"locations": [[46.5, 8.1], [46.6]]}"#, "point 2"),
        (
            r#"{"locations": [{"lat": 46.5, "lng": 200}]}"#,
            "longitude 200",
        ),
        (r#"{"locations": "#, "body:"),
        (
            r#"{"locations": [[46.5, 8.1]], "accuracy": -2}"#,
            "accuracy=",
        ),
    ] {
        let e = post("application/json", body.as_bytes().to_vec()).error(400);
        assert!(e.contains(want), "{body}: {e}");
    }
    let e = post("text/csv", b"46.5,8.1".to_vec()).error(415);
    assert!(e.contains("Content-Type"), "{e}");
    // A form body works as the query does.
    let ok = post(
        "application/x-www-form-urlencoded",
        b"locations=46.5%2C8.1&interpolation=nearest".to_vec(),
    )
    .expect(200);
    assert_eq!(ok.json()["results"][0]["elevation"], 3338.0);
    // Outside and void points are answered, not refused.
    let r = server
        .get(&format!(
            "{base}?locations=47.5,8.5|46.5,8.1&nodata_value=-9999"
        ))
        .expect(200)
        .json();
    assert_eq!(r["results"][0]["elevation"], -9999.0);
    assert_eq!(r["results"][0]["reason"], "outside the dataset");
    assert_eq!(r["results"][1]["elevation"], 3338.0);
}
