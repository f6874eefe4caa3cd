//! Standard-grid web tiles end to end (DECISIONS.md "Standard-grid web tiles"): real
//! pyramids built from real DEMs (N46E008, EPSG:4326; aletsch, EPSG:2056), a real
//! `tessera-server serve`, and every pixel of a tile checked against the source DEM
//! sampled independently: pixel centres carried by GDAL's `gdaltransform` (PROJ, not our
//! proj4rs) to the DEM's CRS, then bilinear on the DEM's own samples as GDAL reads them.
#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

mod gdal;
#[allow(dead_code)] // each test binary uses some of the shared helpers
mod grid_support;
#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use gdal::dem::Dem;
use grid_support::{built, decode_rgba, terrarium, tilejson_bounds, xyz_tile};
use serve_support::Server;
use tessera_server::crs::Crs;
use tessera_shared::testdata;

fn mapbox(p: &[u8]) -> f64 {
    -10000.0 + f64::from(u32::from(p[0]) * 65536 + u32::from(p[1]) * 256 + u32::from(p[2])) * 0.1
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

/// N46E008 moved by GDAL to 179.5° E – 180.5° E (half of it east of the
/// antimeridian) is served on both sides of it: the tiles at the world's east edge
/// and those at its west edge carry the DEM's heights at every pixel, in both
/// grids; TileJSON states every longitude (a box whose east is less than its west
/// is not one MapLibre reads).
#[test]
fn a_dem_across_the_antimeridian_is_served_on_both_sides() {
    if !gdal::gdal_or_skip() {
        return;
    }
    let Some(src) = testdata::dem_or_skip("N46E008.tif") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let moved = dir.path().join("N46E179.tif");
    let h = 0.5 / 1200.0;
    let ullr = [179.5 - h, 47.0 + h, 180.5 + h, 46.0 - h].map(|v| v.to_string());
    let mut args = vec!["-q", "-a_ullr"];
    args.extend(ullr.iter().map(String::as_str));
    args.extend([gdal::path_str(&src), gdal::path_str(&moved)]);
    gdal::run("gdal_translate", &args);
    let pyramid = dir.path().join("N46E179.tess");
    serve_support::build_pyramid(moved.to_str().unwrap(), &pyramid, 256);
    let dem = Dem::read(&moved, "EPSG:4326");
    let srv = Server::start(&[&pyramid], &[]);
    let bounds = tilejson_bounds(&srv, "N46E179");
    assert_eq!((bounds[0], bounds[2]), (-180.0, 180.0), "{bounds:?}");
    // At each grid's deepest zoom (where tiles are the DEM's samples), the tiles
    // either side of the antimeridian at 46.5° N.
    for (grid, px, precision) in [
        ("crs84", 256, 1.0 / 256.0 + 1e-6),
        ("webmercator", 256, 1.0 / 256.0 + 1e-4),
    ] {
        let tj = srv
            .get(&format!(
                "/v1/datasets/N46E179/{grid}/tilejson.json?size={px}"
            ))
            .expect(200)
            .json();
        let z = tj["maxzoom"].as_u64().unwrap() as u8;
        for lon in [179.95, -179.95] {
            let (x, y) = if grid == "crs84" {
                let n = f64::from(1u32 << z);
                (
                    ((lon + 180.0) / 180.0 * n) as u32,
                    ((90.0 - 46.5) / 180.0 * n) as u32,
                )
            } else {
                xyz_tile(lon, 46.5, z)
            };
            let c = compare_tile(&srv, &dem, "N46E179", grid, (z, x, y), px, "terrarium");
            eprintln!("{grid} z{z}/{x}/{y}: {c:?}");
            assert!(c.both > 10_000, "{grid} {lon}: {c:?}");
            assert!(
                c.worst <= precision,
                "{grid} {lon}: worst {} m: {c:?}",
                c.worst
            );
            assert_eq!(c.only_reference, 0, "{grid} {lon}: {c:?}");
        }
    }
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
    let bounds = tilejson_bounds(&srv, "aletsch");
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
