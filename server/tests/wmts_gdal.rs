//! WMTS capabilities and OGC API – Tiles against GDAL (DECISIONS.md "WMTS capabilities"):
//! what GDAL's WMTS and OGCAPI drivers (Debian's gdal-bin) make of a real server on the
//! real N46E008 pyramid, and whether the heights they read back match GDAL's own bilinear
//! resampling of the source DEM onto exactly the same grid.
//!
//! Tolerances: Terrarium rounds down to 1/256 m, Terrain-RGB to the nearest 0.1 m;
//! both sides interpolate the same integer heights bilinearly at the same pixel
//! centres, so beyond the encoding step only float rounding (and, on
//! WebMercatorQuad, proj4rs against PROJ) remains.

#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed test

mod gdal;
#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{Server, dem_pyramid};
use std::path::{Path, PathBuf};
use std::process::Command;

/// The N46E008 pyramid, or `None` (SKIPPED) without the DEM or GDAL.
fn setup() -> Option<(PathBuf, PathBuf)> {
    if !gdal::gdal_or_skip() {
        return None;
    }
    let dem = tessera_shared::testdata::dem_or_skip("N46E008.tif")?;
    Some((dem_pyramid("N46E008.tif", 256)?, dem))
}

/// A GDAL tool run with its HTTP cache in `cache` and no proxy for loopback; stdout.
fn gdal_run(cache: &Path, program: &str, args: &[&str]) -> String {
    let o = Command::new(program)
        .args(args)
        .env("GDAL_DEFAULT_WMS_CACHE_PATH", cache)
        .env("NO_PROXY", "127.0.0.1")
        .env("no_proxy", "127.0.0.1")
        .env_remove("http_proxy")
        .env_remove("HTTP_PROXY")
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{program} {args:?} failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8(o.stdout).unwrap()
}

/// `(width, height, geotransform)` of a raster, from `gdalinfo -json`.
fn grid_of(cache: &Path, file: &str) -> (usize, usize, [f64; 6]) {
    let j: serde_json::Value =
        serde_json::from_str(&gdal_run(cache, "gdalinfo", &["-json", file])).unwrap();
    let size = j["size"].as_array().unwrap();
    let gt: Vec<f64> = j["geoTransform"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    (
        size[0].as_u64().unwrap() as usize,
        size[1].as_u64().unwrap() as usize,
        gt.try_into().unwrap(),
    )
}

#[test]
fn gdalinfo_lists_every_layer_on_both_grids() {
    let Some((pyramid, _)) = setup() else { return };
    let srv = Server::start(&[&pyramid], &[]);
    let cache = tempfile::tempdir().unwrap();
    let url = srv.url("/v1/datasets/N46E008/wmts/1.0.0/WMTSCapabilities.xml");
    let info = gdal_run(cache.path(), "gdalinfo", &[&format!("WMTS:{url}")]);
    for layer in [
        "N46E008_terrarium",
        "N46E008_mapbox",
        "N46E008_hillshade",
        "N46E008_color-relief",
        "N46E008_slope",
    ] {
        for tms in ["WebMercatorQuad", "WorldCRS84Quad"] {
            let want = format!("WMTS:{url},layer={layer},tilematrixset={tms}");
            assert!(
                info.lines()
                    .any(|l| l.contains("_NAME=") && l.ends_with(&want)),
                "no subdataset {want} in:\n{info}"
            );
        }
    }
    // The all-datasets document lists the same layers.
    let all = srv.url("/wmts/1.0.0/WMTSCapabilities.xml");
    let info = gdal_run(cache.path(), "gdalinfo", &[&format!("WMTS:{all}")]);
    assert_eq!(info.matches("_NAME=WMTS:").count(), 10, "{info}");

    // Each grid opens in its CRS, over the dataset (8°–9° E, 46°–47° N, plus half a
    // 3″ sample), at the max zoom of the TileJSON.
    for (tms, grid, epsg) in [
        ("WorldCRS84Quad", "crs84", "CRS84"),
        ("WebMercatorQuad", "webmercator", "3857"),
    ] {
        let ds = format!("WMTS:{url},layer=N46E008_terrarium,tilematrixset={tms}");
        let j: serde_json::Value =
            serde_json::from_str(&gdal_run(cache.path(), "gdalinfo", &["-json", &ds])).unwrap();
        let wkt = j["coordinateSystem"]["wkt"].as_str().unwrap();
        assert!(wkt.contains(epsg), "{tms}: {wkt}");
        let ring = j["wgs84Extent"]["coordinates"][0].as_array().unwrap();
        let (mut w, mut s, mut e, mut n) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for p in ring {
            let (x, y) = (p[0].as_f64().unwrap(), p[1].as_f64().unwrap());
            (w, s, e, n) = (w.min(x), s.min(y), e.max(x), n.max(y));
        }
        let pixel = j["geoTransform"][1].as_f64().unwrap();
        let slack = if tms == "WorldCRS84Quad" {
            2.0 * pixel
        } else {
            0.002
        };
        for (got, want) in [(w, 8.0), (s, 46.0), (e, 9.0), (n, 47.0)] {
            assert!(
                (got - want).abs() < 1.0 / 2400.0 + slack,
                "{tms}: extent {w} {s} {e} {n}"
            );
        }
        let tj: serde_json::Value = serde_json::from_slice(
            &srv.get(&format!("/v1/datasets/N46E008/{grid}/tilejson.json"))
                .body,
        )
        .unwrap();
        let max = tj["maxzoom"].as_u64().unwrap();
        let want = tessera_server::web::tile_matrix::TileMatrixSet::parse(tms)
            .unwrap()
            .cell_size(u8::try_from(max).unwrap(), 256);
        assert!(
            (pixel - want).abs() < 1e-9 * want.max(1.0),
            "{tms}: pixel {pixel}, zoom {max} wants {want}"
        );
        eprintln!(
            "{tms}: GDAL opens {}x{} px of {pixel} at zoom {max}",
            j["size"][0], j["size"][1]
        );
    }
}

/// Heights of a raw band-sequential RGBA raster (ENVI), and which are valid (alpha 255).
fn decode(rgba: &[u8], n: usize, mapbox: bool) -> Vec<Option<f64>> {
    assert_eq!(rgba.len(), 4 * n);
    (0..n)
        .map(|i| {
            let [r, g, b, a] = [0, 1, 2, 3].map(|k| f64::from(rgba[k * n + i]));
            (a == 255.0).then(|| {
                if mapbox {
                    -10000.0 + (r * 65536.0 + g * 256.0 + b) * 0.1
                } else {
                    r * 256.0 + g + b / 256.0 - 32768.0
                }
            })
        })
        .collect()
}

/// What one comparison measured.
#[derive(Debug)]
struct Measured {
    max_diff: f64,
    compared: usize,
    ours_valid: f64,
    gdal_valid: f64,
    /// Over pixels whose kernel touches a void sample (not held to the bound).
    max_diff_by_voids: f64,
    /// The largest shift of a pixel centre, in output pixels, that would explain a
    /// difference beyond the encoding step.
    max_shift_px: f64,
    /// The same in the DEM's samples.
    max_shift_samples: f64,
}

/// `gdal_translate` of a window around Andermatt from the WMTS at the TileJSON's max
/// zoom, and `gdalwarp` of the DEM onto exactly that grid; the heights compared.
fn compare(
    step: f64,
    srv: &Server,
    dem: &Path,
    dir: &Path,
    [tms, grid, srs]: [&str; 3],
    enc: &str,
) -> Measured {
    let tj: serde_json::Value = serde_json::from_slice(
        &srv.get(&format!("/v1/datasets/N46E008/{grid}/tilejson.json"))
            .body,
    )
    .unwrap();
    let zoom = tj["maxzoom"].as_u64().unwrap().to_string();
    let url = srv.url("/v1/datasets/N46E008/wmts/1.0.0/WMTSCapabilities.xml");
    let ds = format!("WMTS:{url},layer=N46E008_{enc}");
    let ours = dir.join(format!("{grid}-{enc}.img"));
    let ours_s = ours.to_str().unwrap();
    // Andermatt, the Gotthard and the Oberalp: 8.45–8.75° E, 46.50–46.75° N.
    gdal_run(
        dir,
        "gdal_translate",
        &[
            "-q",
            "-of",
            "ENVI",
            "-co",
            "INTERLEAVE=BSQ",
            "-oo",
            &format!("TILEMATRIXSET={tms}"),
            "-oo",
            &format!("ZOOM_LEVEL={zoom}"),
            "-projwin_srs",
            "EPSG:4326",
            "-projwin",
            "8.45",
            "46.75",
            "8.75",
            "46.50",
            &ds,
            ours_s,
        ],
    );
    let (w, h, gt) = grid_of(dir, ours_s);
    let te = [
        gt[0],
        gt[3] + h as f64 * gt[5],
        gt[0] + w as f64 * gt[1],
        gt[3],
    ]
    .map(|v| format!("{v:.17}"));
    let warp = |respect_nodata: bool| -> Vec<f64> {
        let out = dir.join(format!("{grid}-{enc}-gdal-{respect_nodata}.img"));
        let out_s = out.to_str().unwrap();
        let (w_s, h_s) = (w.to_string(), h.to_string());
        let mut args = vec![
            "-q", "-of", "ENVI", "-ot", "Float64", "-r", "bilinear", "-et", "0", "-t_srs", srs,
            "-te", &te[0], &te[1], &te[2], &te[3], "-ts", &w_s, &h_s,
        ];
        if respect_nodata {
            args.extend(["-dstnodata", "-32767"]);
        } else {
            args.extend(["-srcnodata", "None", "-dstnodata", "None"]);
        }
        args.extend([dem.to_str().unwrap(), out_s]);
        gdal_run(dir, "gdalwarp", &args);
        let (rw, rh, rgt) = grid_of(dir, out_s);
        assert_eq!((rw, rh), (w, h));
        for k in 0..6 {
            assert!(
                (rgt[k] - gt[k]).abs() <= 1e-9 * gt[k].abs().max(1.0),
                "grids differ: {rgt:?} vs {gt:?}"
            );
        }
        std::fs::read(&out)
            .unwrap()
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect()
    };
    let n = w * h;
    let heights = decode(&std::fs::read(&ours).unwrap(), n, enc == "mapbox");
    let gdal: Vec<Option<f64>> = warp(true)
        .into_iter()
        .map(|v| (v != -32767.0 && v.is_finite()).then_some(v))
        .collect();
    // The same kernel blind to no-data: equal to the first exactly where no void
    // sample (-32767) is under the kernel. Next to voids GDAL renormalises its weights
    // over the valid samples, while the pyramid interpolates over its fill (the
    // nearest valid heights, resample.rs): both are fair, and they differ.
    let blind = warp(false);
    assert_eq!(gdal.len(), n);
    let mut m = Measured {
        max_diff: 0.0,
        compared: 0,
        ours_valid: 0.0,
        gdal_valid: 0.0,
        max_diff_by_voids: 0.0,
        max_shift_px: 0.0,
        max_shift_samples: 0.0,
    };
    let mut worst = 0;
    for i in 0..n {
        m.ours_valid += f64::from(u8::from(heights[i].is_some()));
        m.gdal_valid += f64::from(u8::from(gdal[i].is_some()));
        if let (Some(a), Some(b)) = (heights[i], gdal[i]) {
            let d = (a - b).abs();
            if blind[i] != b {
                m.max_diff_by_voids = m.max_diff_by_voids.max(d);
                continue;
            }
            m.compared += 1;
            // Beyond the encoding step, how far off would our pixel centre have to be
            // (in output pixels, along the slope GDAL's heights show) to explain it?
            let (x, y) = (i % w, i / w);
            if d > step && x > 0 && y > 0 && x + 1 < w && y + 1 < h {
                // The steepest one-sided step: bilinear surfaces crease at sample lines.
                let gx = (blind[i + 1] - blind[i])
                    .abs()
                    .max((blind[i] - blind[i - 1]).abs());
                let gy = (blind[i + w] - blind[i])
                    .abs()
                    .max((blind[i] - blind[i - w]).abs());
                let slope = gx.hypot(gy);
                if slope > 0.0 {
                    m.max_shift_px = m.max_shift_px.max((d - step) / slope);
                }
            }
            if d > m.max_diff {
                m.max_diff = d;
                worst = i;
            }
        }
    }
    // Output pixels in N46E008's 3″ samples, east–west (the wider way).
    let degrees_per_unit = if tms == "WebMercatorQuad" {
        180.0 / (6_378_137.0 * std::f64::consts::PI)
    } else {
        1.0
    };
    m.max_shift_samples = m.max_shift_px * gt[1] * degrees_per_unit * 1200.0;
    m.ours_valid /= n as f64;
    m.gdal_valid /= n as f64;
    eprintln!(
        "{tms} {enc} zoom {zoom}: {w}x{h} px, max |ours - GDAL| = {:.6} m over {} pixels (worst at pixel ({}, {}): ours {:?}, GDAL {:?}), {:.3} m beside voids, implied position error {:.2e} px = {:.2e} samples; valid: ours {:.4}, GDAL {:.4}",
        m.max_diff,
        m.compared,
        worst % w,
        worst / w,
        heights[worst],
        gdal[worst],
        m.max_diff_by_voids,
        m.max_shift_px,
        m.max_shift_samples,
        m.ours_valid,
        m.gdal_valid
    );
    assert!(m.compared > n / 2, "{m:?}");
    // Where GDAL has data we have it too, but beside voids; where we have data GDAL
    // does not, it is
    // within reach of GDAL's: half a sample (each sample stands for its pixel) plus
    // the apron web clients' bilinear lookups need (resample.rs `APRON`), plus one
    // pixel for GDAL's own rule at a void's edge.
    let half_sample_px = (0.5 / (gt[1] * degrees_per_unit * 1200.0)).ceil() as usize;
    let reach = half_sample_px + tessera_server::web::resample::APRON as usize + 1;
    let (mut gdal_only, mut far) = (0usize, 0usize);
    for i in 0..n {
        match (heights[i].is_some(), gdal[i].is_some()) {
            (false, true) => {
                // Only beside voids: a valid sample all of whose cells have a void
                // corner is not terrain in the per-cell mask (format v2), while
                // GDAL's kernel renormalises over it.
                assert_ne!(
                    Some(blind[i]),
                    gdal[i],
                    "({}, {}): GDAL has data away from any void and we do not",
                    i % w,
                    i / w
                );
                gdal_only += 1;
            }
            (true, false) => {
                let (x, y) = (i % w, i / w);
                let near = (y.saturating_sub(reach)..=(y + reach).min(h - 1)).any(|yy| {
                    (x.saturating_sub(reach)..=(x + reach).min(w - 1))
                        .any(|xx| gdal[yy * w + xx].is_some())
                });
                far += usize::from(!near);
            }
            _ => {}
        }
    }
    eprintln!(
        "{tms} {enc}: {gdal_only} pixels only GDAL has, {far} of ours beyond {reach} px of GDAL's"
    );
    assert_eq!(far, 0, "{tms} {enc}: {m:?}");
    m
}

#[test]
fn wmts_heights_match_gdal_resampling_the_dem() {
    let Some((pyramid, dem)) = setup() else {
        return;
    };
    let srv = Server::start(&[&pyramid], &[]);
    let dir = tempfile::tempdir().unwrap();
    // 1e-6 m: heights of a few thousand metres in f64, through two bilinear kernels.
    let eps = 1e-6;
    for (enc, step) in [("terrarium", 1.0 / 256.0), ("mapbox", 0.05)] {
        // CRS84 is the DEM's own CRS: pixel centres are exact on both sides.
        let m = compare(
            step,
            &srv,
            &dem,
            dir.path(),
            ["WorldCRS84Quad", "crs84", "EPSG:4326"],
            enc,
        );
        assert!(m.max_diff <= step + eps, "WorldCRS84Quad {enc}: {m:?}");
        // Web Mercator over a longitude/latitude DEM: every column and row is
        // transformed exactly (resample.rs), and proj4rs agrees with PROJ to 1e-10
        // samples here (`our_projections_agree_with_proj` in
        // serve_grid_tiles.rs): the same bound.
        let m = compare(
            step,
            &srv,
            &dem,
            dir.path(),
            ["WebMercatorQuad", "webmercator", "EPSG:3857"],
            enc,
        );
        assert!(m.max_diff <= step + eps, "WebMercatorQuad {enc}: {m:?}");
    }
}

/// OGC API – Tiles: the documents link up, the tileset's limits and template lead
/// to the very tiles the grid route serves (row before column); what GDAL 3.6's
/// OGCAPI driver (which knows only map and vector tilesets) says is reported.
#[test]
fn ogc_api_tiles_lead_to_the_grid_tiles() {
    let Some((pyramid, _)) = setup() else { return };
    let srv = Server::start(&[&pyramid], &[]);
    let json = |path: &str| -> serde_json::Value {
        let r = srv.get(path);
        assert_eq!(
            r.status,
            200,
            "{path}: {}",
            String::from_utf8_lossy(&r.body)
        );
        serde_json::from_slice(&r.body).unwrap()
    };
    let href = |doc: &serde_json::Value, rel: &str| -> String {
        doc["links"]
            .as_array()
            .unwrap()
            .iter()
            .find(|l| l["rel"] == rel)
            .unwrap_or_else(|| panic!("no {rel} link in {doc}"))["href"]
            .as_str()
            .unwrap()
            .to_string()
    };
    let landing = json("/ogcapi");
    let conf = json(&href(&landing, "conformance"));
    assert!(
        conf["conformsTo"]
            .as_array()
            .unwrap()
            .iter()
            .any(|c| c == "http://www.opengis.net/spec/ogcapi-tiles-1/1.0/conf/geodata-tilesets")
    );
    let sets = json(&href(
        &landing,
        "http://www.opengis.net/def/rel/ogc/1.0/tiling-schemes",
    ));
    assert_eq!(sets["tileMatrixSets"].as_array().unwrap().len(), 2);
    let collections = json(&href(&landing, "data"));
    let c = &collections["collections"][0];
    assert_eq!(c["id"], "N46E008");
    let bbox: Vec<f64> = c["extent"]["spatial"]["bbox"][0]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    for (got, want) in bbox.iter().zip([8.0, 46.0, 9.0, 47.0]) {
        assert!((got - want).abs() <= 1.0 / 2400.0 + 1e-9, "{bbox:?}");
    }
    let list = json(&href(
        c,
        "http://www.opengis.net/def/rel/ogc/1.0/tilesets-coverage",
    ));
    assert_eq!(list["tilesets"].as_array().unwrap().len(), 2);
    for ts in list["tilesets"].as_array().unwrap() {
        let tileset = json(&href(ts, "self"));
        assert_eq!(tileset["dataType"], "coverage");
        let tms = json(&href(
            &tileset,
            "http://www.opengis.net/def/rel/ogc/1.0/tiling-scheme",
        ));
        let id = tms["id"].as_str().unwrap().to_string();
        let limits = tileset["tileMatrixSetLimits"].as_array().unwrap();
        let last = limits.last().unwrap();
        let z = last["tileMatrix"].as_str().unwrap();
        assert_eq!(tms["tileMatrices"][z.parse::<usize>().unwrap()]["id"], z);
        // The middle tile of the deepest zoom, by the template and by the grid route.
        let mid =
            |a: &str, b: &str| u64::midpoint(last[a].as_u64().unwrap(), last[b].as_u64().unwrap());
        let (row, col) = (
            mid("minTileRow", "maxTileRow"),
            mid("minTileCol", "maxTileCol"),
        );
        let item = href(&tileset, "item")
            .replace("{tileMatrix}", z)
            .replace("{tileRow}", &row.to_string())
            .replace("{tileCol}", &col.to_string());
        let via_ogc = srv.get(&item);
        // The template asks for alpha-marked no-data (GDAL reads it), as the WMTS does.
        assert!(item.contains("nodata=transparent"), "{item}");
        let direct = srv.get(&format!(
            "/v1/datasets/N46E008/{id}/{z}/{col}/{row}.png?encoding=terrarium&nodata=transparent"
        ));
        assert_eq!((via_ogc.status, direct.status), (200, 200), "{item}");
        assert_eq!(via_ogc.body, direct.body, "{item}");
        eprintln!(
            "{id}: zoom {z} limits {last}; {item}: {} bytes",
            via_ogc.body.len()
        );
    }

    // What GDAL 3.6 makes of it: reported, not asserted (see API.md).
    let cache = tempfile::tempdir().unwrap();
    let o = Command::new("gdalinfo")
        .arg(format!("OGCAPI:{}", srv.url("/ogcapi/collections/N46E008")))
        .env("GDAL_DEFAULT_WMS_CACHE_PATH", cache.path())
        .env("NO_PROXY", "127.0.0.1")
        .output()
        .unwrap();
    eprintln!(
        "gdalinfo OGCAPI: {}: {}{}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// GDAL opens the hillshade layer from the capabilities' template and reads, at
/// Andermatt, the grey the server's own tile has at that pixel (R = G = B, opaque).
#[test]
fn gdal_reads_the_hillshade_layer_as_the_server_draws_it() {
    let Some((pyramid, _)) = setup() else { return };
    let srv = Server::start(&[&pyramid], &[]);
    let cache = tempfile::tempdir().unwrap();
    let url = srv.url("/v1/datasets/N46E008/wmts/1.0.0/WMTSCapabilities.xml");
    let ds = format!("WMTS:{url},layer=N46E008_hillshade,tilematrixset=WebMercatorQuad");
    let (lon, lat) = (8.5937, 46.6339);
    let out = gdal_run(
        cache.path(),
        "gdallocationinfo",
        &[
            "-valonly",
            "-wgs84",
            &ds,
            &lon.to_string(),
            &lat.to_string(),
        ],
    );
    let bands: Vec<u8> = out.lines().map(|l| l.trim().parse().unwrap()).collect();
    assert_eq!(bands.len(), 4, "{out}");
    assert_eq!(bands[3], 255, "opaque over terrain");
    assert!(
        bands[0] == bands[1] && bands[1] == bands[2] && bands[0] > 0,
        "{bands:?}"
    );
    // The same pixel of the server's tile at the TileJSON's max zoom.
    let tj: serde_json::Value = serde_json::from_slice(
        &srv.get("/v1/datasets/N46E008/webmercator/hillshade/tilejson.json")
            .body,
    )
    .unwrap();
    let z = tj["maxzoom"].as_u64().unwrap() as i32;
    let n = f64::from(1u32 << z) * 256.0;
    let l = f64::to_radians(lat);
    let px = (lon + 180.0) / 360.0 * n;
    let py = (1.0 - (l.tan() + 1.0 / l.cos()).ln() / std::f64::consts::PI) / 2.0 * n;
    let (x, y) = ((px / 256.0) as u32, (py / 256.0) as u32);
    let tile = srv
        .get(&format!(
            "/v1/datasets/N46E008/webmercator/hillshade/{z}/{x}/{y}.png"
        ))
        .expect(200);
    let (_, buf) = serve_support::png_rgba(&tile.body);
    let (i, j) = ((px as usize) % 256, (py as usize) % 256);
    let k = (j * 256 + i) * 4;
    assert_eq!(
        &buf[k..k + 4],
        &bands[..],
        "GDAL's pixel and the server's tile at ({i}, {j})"
    );
}
