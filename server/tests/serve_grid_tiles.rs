//! Standard-grid web tiles end to end (issue 14): real pyramids built from real DEMs
//! (N46E008, EPSG:4326; aletsch, EPSG:2056), a real `tessera-server serve`, and every
//! pixel of a tile checked against the source DEM sampled independently: pixel
//! centres carried by GDAL's `gdaltransform` (PROJ, not our proj4rs) to the DEM's
//! CRS, then bilinear on the DEM's own samples as GDAL reads them.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

mod gdal;
#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{Server, build_pyramid, parse_metrics};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use tessera_server::crs::Crs;
use tessera_shared::testdata;

/// The pyramids of this test binary, built once into a temporary folder.
struct Built {
    _dir: tempfile::TempDir,
    n46e008: PathBuf,
    aletsch: PathBuf,
}

fn built() -> Option<&'static Built> {
    static B: OnceLock<Option<Built>> = OnceLock::new();
    B.get_or_init(|| {
        let n46 = testdata::dem_or_skip("N46E008.tif")?;
        let aletsch = testdata::dem_or_skip("aletsch.tif")?;
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("N46E008.tess");
        let b = dir.path().join("aletsch.tess");
        build_pyramid(n46.to_str().unwrap(), &a, 256);
        build_pyramid(aletsch.to_str().unwrap(), &b, 64);
        Some(Built {
            _dir: dir,
            n46e008: a,
            aletsch: b,
        })
    })
    .as_ref()
}

/// A DEM as GDAL reads it: samples (NaN for no-data), geotransform, size, CRS.
struct Dem {
    values: Vec<f64>,
    width: usize,
    height: usize,
    gt: [f64; 6],
    epsg: String,
}

impl Dem {
    /// Reads `path` through `gdal_translate` into raw float64, the no-data as NaN.
    fn read(path: &Path, epsg: &str) -> Self {
        let info: serde_json::Value =
            serde_json::from_str(&gdal::run("gdalinfo", &["-json", gdal::path_str(path)])).unwrap();
        let gt: Vec<f64> = info["geoTransform"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let size = info["size"].as_array().unwrap();
        let (width, height) = (
            size[0].as_u64().unwrap() as usize,
            size[1].as_u64().unwrap() as usize,
        );
        let nodata = info["bands"][0]["noDataValue"].as_f64();
        let dir = tempfile::tempdir().unwrap();
        let raw = dir.path().join("dem.bin");
        gdal::run(
            "gdal_translate",
            &[
                "-q",
                "-of",
                "ENVI",
                "-ot",
                "Float64",
                gdal::path_str(path),
                gdal::path_str(&raw),
            ],
        );
        let bytes = std::fs::read(&raw).unwrap();
        let values = bytes
            .chunks_exact(8)
            .map(|c| {
                let v = f64::from_le_bytes(c.try_into().unwrap());
                if Some(v) == nodata { f64::NAN } else { v }
            })
            .collect::<Vec<_>>();
        assert_eq!(values.len(), width * height);
        Self {
            values,
            width,
            height,
            gt: gt.try_into().unwrap(),
            epsg: epsg.to_string(),
        }
    }

    /// Bilinear at CRS point `(x, y)` over the four surrounding samples, `None`
    /// outside the sample grid or where any of the four is no-data.
    fn bilinear(&self, x: f64, y: f64) -> Option<f64> {
        let c = (x - self.gt[0]) / self.gt[1] - 0.5;
        let r = (y - self.gt[3]) / self.gt[5] - 0.5;
        if !(c >= 0.0 && r >= 0.0 && c <= (self.width - 1) as f64 && r <= (self.height - 1) as f64)
        {
            return None;
        }
        let (i, j) = (
            (c.floor() as usize).min(self.width - 2),
            (r.floor() as usize).min(self.height - 2),
        );
        let (u, v) = (c - i as f64, r - j as f64);
        let at = |a: usize, b: usize| self.values[b * self.width + a];
        let (h00, h10, h01, h11) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
        if [h00, h10, h01, h11].iter().any(|h| h.is_nan()) {
            return None;
        }
        let top = h00 + u * (h10 - h00);
        let bottom = h01 + u * (h11 - h01);
        Some(top + v * (bottom - top))
    }
}

/// RGBA pixels of a PNG.
fn decode_rgba(bytes: &[u8]) -> (u32, Vec<u8>) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgba, "want RGBA");
    assert_eq!(info.width, info.height);
    buf.truncate(info.buffer_size());
    (info.width, buf)
}

fn terrarium(p: &[u8]) -> f64 {
    f64::from(p[0]) * 256.0 + f64::from(p[1]) + f64::from(p[2]) / 256.0 - 32768.0
}

fn mapbox(p: &[u8]) -> f64 {
    -10000.0 + f64::from(u32::from(p[0]) * 65536 + u32::from(p[1]) * 256 + u32::from(p[2])) * 0.1
}

/// Web Mercator tile `(x, y)` at zoom `z` holding `(lon, lat)` — the XYZ scheme's
/// definition, written out here as an independent check of the server's grid.
fn xyz_tile(lon: f64, lat: f64, z: u8) -> (u32, u32) {
    let n = f64::from(1u32 << z);
    let x = (lon + 180.0) / 360.0 * n;
    let l = lat.to_radians();
    let y = (1.0 - (l.tan() + 1.0 / l.cos()).ln() / std::f64::consts::PI) / 2.0 * n;
    (x as u32, y as u32)
}

/// What comparing one tile with the DEM found.
#[derive(Debug, Default)]
struct Comparison {
    /// Pixels both say are terrain.
    both: usize,
    /// Largest |served − reference| over them, metres, and where: the point in
    /// the DEM's CRS, the served and the reference height.
    worst: f64,
    worst_at: ([f64; 2], f64, f64),
    /// Pixels only the server calls terrain / only the reference does.
    only_served: usize,
    only_reference: usize,
}

/// Every pixel of tile `(z, x, y)` of `grid` (`webmercator`: EPSG:3857; `crs84`:
/// EPSG:4326) of `dataset`, against `dem` at the pixel's centre.
fn compare_tile(
    srv: &Server,
    dem: &Dem,
    dataset: &str,
    grid: &str,
    (z, x, y): (u8, u32, u32),
    px: u32,
    enc: &str,
) -> Comparison {
    let r = srv
        .get(&format!(
            "/v1/datasets/{dataset}/{grid}/{z}/{x}/{y}.png?encoding={enc}&size={px}"
        ))
        .expect(200);
    assert_eq!(r.must("content-type"), "image/png");
    let (side, rgba) = decode_rgba(&r.body);
    assert_eq!(side, px);
    // The standard grids' definitions (OGC 17-083r4 annex D).
    let (grid_epsg, x0, y1, span) = match grid {
        "webmercator" => {
            let half = 20_037_508.342_789_244;
            ("EPSG:3857", -half, half, 2.0 * half / f64::from(1u32 << z))
        }
        _ => ("EPSG:4326", -180.0, 90.0, 180.0 / f64::from(1u32 << z)),
    };
    let cell = span / f64::from(px);
    let centres: Vec<[f64; 2]> = (0..px * px)
        .map(|k| {
            let (i, j) = (f64::from(k % px), f64::from(k / px));
            [
                x0 + f64::from(x) * span + (i + 0.5) * cell,
                y1 - f64::from(y) * span - (j + 0.5) * cell,
            ]
        })
        .collect();
    // GDAL follows EPSG:4326's authority axis order (latitude first); OGC:CRS84 is
    // the same datum with longitude first, as our grids and DEMs write it.
    let from = if grid_epsg == "EPSG:4326" {
        "OGC:CRS84"
    } else {
        grid_epsg
    };
    let to = if dem.epsg == "EPSG:4326" {
        "OGC:CRS84"
    } else {
        &dem.epsg
    };
    // The same CRS needs no transform (and gdaltransform prints 10 decimals: 5e-11°
    // is up to 4e-6 m of height on the Alps' slopes).
    let in_dem = if from == to {
        centres.clone()
    } else {
        gdal::transform(from, to, &centres)
    };
    let mut c = Comparison::default();
    for (k, p) in in_dem.iter().enumerate() {
        let px4 = &rgba[k * 4..k * 4 + 4];
        let served = (px4[3] == 255).then(|| {
            if enc == "mapbox" {
                mapbox(px4)
            } else {
                terrarium(px4)
            }
        });
        assert!(px4[3] == 255 || px4[3] == 0, "alpha is all or nothing");
        match (served, dem.bilinear(p[0], p[1])) {
            (Some(s), Some(want)) => {
                c.both += 1;
                if (s - want).abs() > c.worst {
                    c.worst = (s - want).abs();
                    c.worst_at = (*p, s, want);
                }
            }
            (Some(_), None) => c.only_served += 1,
            (None, Some(_)) => c.only_reference += 1,
            (None, None) => {}
        }
    }
    c
}

/// N46E008 as GDAL reads it, a server of its pyramid, and the TileJSON `maxzoom` of
/// `grid` at `px` pixels; `None` (skipped) without GDAL or the DEM.
fn n46e008_at_max_zoom(grid: &str, px: u32) -> Option<(Dem, Server, u8)> {
    if !gdal::gdal_or_skip() {
        return None;
    }
    let b = built()?;
    let dem = Dem::read(&testdata::dem_or_skip("N46E008.tif")?, "EPSG:4326");
    let srv = Server::start(&[&b.n46e008], &[]);
    let tj = srv
        .get(&format!(
            "/v1/datasets/N46E008/{grid}/tilejson.json?size={px}"
        ))
        .expect(200)
        .json();
    let z = tj["maxzoom"].as_u64().unwrap() as u8;
    Some((dem, srv, z))
}

/// Every pixel of the Web Mercator tiles at the dataset's max zoom holding two
/// landmarks (Urnersee 431 m, Andermatt 1436 m), in both encodings, against the
/// DEM through PROJ: within the encoding's precision (Terrarium rounds down to
/// 1/256 m; Terrain-RGB rounds to 0.1 m, so 0.05 m) plus 0.1 mm: the server
/// transforms each column and row exactly (proj4rs agrees with PROJ to 1e-6 m, see
/// `our_projections_agree_with_proj`), and gdaltransform prints 10 decimals (5e-11°:
/// up to 4e-6 m of height on the Alps' slopes).
#[test]
fn webmercator_tiles_carry_the_dem_heights_at_every_pixel() {
    let Some((dem, srv, z)) = n46e008_at_max_zoom("webmercator", 512) else {
        return;
    };
    for (lon, lat) in [(8.61, 46.93), (8.5911, 46.6350)] {
        let (x, y) = xyz_tile(lon, lat, z);
        for (enc, precision) in [("terrarium", 1.0 / 256.0), ("mapbox", 0.05)] {
            let c = compare_tile(&srv, &dem, "N46E008", "webmercator", (z, x, y), 512, enc);
            eprintln!("{enc} z{z}/{x}/{y}: {c:?}");
            // Both tiles reach beyond the DEM (47° N) or over voids; most is terrain.
            assert!(c.both > 150_000, "{c:?}");
            assert!(
                c.worst <= precision + 1e-4,
                "{enc}: worst {} m: {c:?}",
                c.worst
            );
            // The server serves pixels beside voids that the 4-sample reference
            // cannot (nearest-sample validity, web/resample.rs), never fewer.
            assert!(c.only_reference == 0, "{c:?}");
        }
    }
}

/// The geographic grid in the DEM's own CRS: no projection at all, so heights
/// agree to the encoding's precision alone.
#[test]
fn crs84_tiles_carry_the_dem_heights_exactly() {
    let Some((dem, srv, z)) = n46e008_at_max_zoom("crs84", 256) else {
        return;
    };
    let n = f64::from(1u32 << z);
    // WorldCRS84Quad: 2^(z+1) × 2^z tiles of 180/2^z degrees, row 0 at 90° N.
    let (x, y) = (
        ((8.5911 + 180.0) / 180.0 * n) as u32,
        ((90.0 - 46.635) / 180.0 * n) as u32,
    );
    let c = compare_tile(&srv, &dem, "N46E008", "crs84", (z, x, y), 256, "terrarium");
    eprintln!("crs84 z{z}/{x}/{y}: {c:?}");
    assert!(c.both > 50_000, "{c:?}");
    // 1 µm of slack: f64 rounding of positions (1e-11 samples on 100 m/sample
    // slopes) can put a height either side of a 1/256 m step.
    assert!(c.worst <= 1.0 / 256.0 + 1e-6, "worst {} m: {c:?}", c.worst);
    assert_eq!(c.only_reference, 0, "{c:?}");
}

/// A DEM in Swiss LV95 (EPSG:2056) lands in the Bernese Alps with its heights, not
/// stretched over the world: the Web Mercator tile over the Aletsch glacier matches
/// the DEM through PROJ, and tiles elsewhere hold nothing.
#[test]
fn a_projected_dem_lands_in_its_place() {
    if !gdal::gdal_or_skip() {
        return;
    }
    let Some(b) = built() else { return };
    let dem = Dem::read(&testdata::dem_or_skip("aletsch.tif").unwrap(), "EPSG:2056");
    let srv = Server::start(&[&b.aletsch], &[]);
    let tj = srv
        .get("/v1/datasets/aletsch/webmercator/tilejson.json")
        .expect(200)
        .json();
    let bounds: Vec<f64> = tj["bounds"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    // gdalinfo's wgs84Extent of aletsch.tif: 7.4529–8.3911° E, 46.2500–46.8117° N.
    for (got, want) in bounds.iter().zip([7.4529, 46.2500, 8.3911, 46.8117]) {
        assert!((got - want).abs() < 2e-4, "bounds {bounds:?}");
    }
    let q: f64 = {
        let info = srv.get("/v1/datasets/aletsch").expect(200).json();
        info["quantization"]["max_error"].as_f64().unwrap()
    };
    // The Aletsch glacier (8.03° E, 46.50° N) at zoom 11.
    let (x, y) = xyz_tile(8.03, 46.50, 11);
    let c = compare_tile(
        &srv,
        &dem,
        "aletsch",
        "webmercator",
        (11, x, y),
        256,
        "terrarium",
    );
    eprintln!("aletsch z11/{x}/{y}: {c:?} (quantization error {q} m)");
    assert!(c.both > 60_000, "{c:?}");
    // Float32 heights are stored quantized: their error adds to the encoding's.
    assert!(
        c.worst <= q + 1.0 / 256.0 + 0.005,
        "worst {} m: {c:?}",
        c.worst
    );
    // The same ground a whole tile west, beyond the DEM, has no data at all.
    let r = srv.get(&format!(
        "/v1/datasets/aletsch/webmercator/11/{}/{y}.png",
        x - 8
    ));
    assert_eq!(r.status, 404, "{}", r.text());
    // Nor does the other side of the world.
    assert_eq!(
        srv.get("/v1/datasets/aletsch/webmercator/3/1/5.png").status,
        404
    );
}

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

/// Where our projection library (proj4rs) puts points against PROJ (through
/// `gdaltransform`), for the grids' CRSs and the DEMs', both ways: longitude and
/// latitude into the CRS, and the CRS's points back (the way the server carries
/// pixel centres to a dataset). The positional part of the tolerances above.
#[test]
fn our_projections_agree_with_proj() {
    if !gdal::gdal_or_skip() {
        return;
    }
    let merc = Crs::from_epsg(3857).unwrap();
    let lv95 = Crs::from_epsg(2056).unwrap();
    let geo = Crs::from_epsg(4326).unwrap();
    let lon_lat: Vec<[f64; 2]> = (0..400)
        .map(|k| {
            [
                7.4 + f64::from(k % 20) * 0.05,
                46.2 + f64::from(k / 20) * 0.03,
            ]
        })
        .collect();
    // Limits: 1e-6 m and 1e-5 of a 3″ sample (8.3e-9°) for Web Mercator; 1 cm and
    // 1e-7° for LV95 (its datum shift is a towgs84 whose inverse iterates).
    for (crs, code, limit_m, limit_deg) in [
        (&merc, "EPSG:3857", 1e-6, 1e-5 / 1200.0),
        (&lv95, "EPSG:2056", 0.01, 1e-7),
    ] {
        let proj = gdal::transform("OGC:CRS84", code, &lon_lat);
        let (mut forward, mut back) = (0f64, 0f64);
        for (p, want) in lon_lat.iter().zip(&proj) {
            let got = crs.from_lon_lat(p[0], p[1]).unwrap();
            forward = forward.max((got[0] - want[0]).hypot(got[1] - want[1]));
            let [lon, lat] = crs.transform_to(&geo, want[0], want[1]).unwrap();
            back = back.max((lon - p[0]).abs().max((lat - p[1]).abs()));
        }
        eprintln!("{code}: proj4rs vs PROJ, worst {forward} m forward, {back}° back");
        assert!(forward < limit_m, "{code}: {forward} m");
        assert!(back < limit_deg, "{code}: {back}°");
    }
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
/// every other pixel is the dataset's lowest height (issue 33: never −32768 m),
/// opaque by default and transparent with `nodata=transparent`.
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
/// (issue 33): web maps ask for each of them, and a 404 is an error in their
/// console. aletsch is EPSG:2056, a rotated rectangle in Web Mercator, so some tiles
/// at the corners of its bounds hold no data: those are the flat fill, the
/// dataset's lowest height, opaque (wholly transparent with `nodata=transparent`).
#[test]
fn every_tile_within_the_bounds_is_served_and_plausible() {
    let Some(b) = built() else { return };
    let srv = Server::start(&[&b.aletsch], &[]);
    let tj = srv
        .get("/v1/datasets/aletsch/webmercator/tilejson.json")
        .expect(200)
        .json();
    let bounds: Vec<f64> = tj["bounds"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
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
