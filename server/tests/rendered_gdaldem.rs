//! Rendered terrain tiles against `gdaldem` (API.md "Rendered terrain tiles"): GDAL
//! warps the real DEM onto the tile's grid with a one-pixel border (bilinear, exact
//! transforms), `gdaldem` renders it, and every pixel both call terrain must agree
//! within one level per channel on at least 99 % of them.
//!
//! `gdaldem` takes one pixel size for a whole raster from its geotransform, in the
//! raster's units; the standard grids' pixels are degrees or stretched Mercator
//! metres whose ground size changes with latitude. So each band of 32 rows is
//! rendered on its own with a geotransform of that band's ground size in metres,
//! measured here with geodesics (geographiclib), not with the server's formula.
//! With `-s 111120` on the degrees, as GDAL's manual suggests near the equator, the
//! crs84 hillshade would be another picture: the test would fail.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

mod gdal;
#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use gdal::{gdal_or_skip, path_str, run, warp_tile};
use geographiclib_rs::{Geodesic, InverseGeodesic};
use serve_support::{Server, dem_pyramid};
use std::path::Path;
use tessera_server::web::render::ramp::BUILT_IN;
use tessera_server::web::tile_matrix::{TileMatrixSet, WebTile};
use tessera_shared::testdata;

const PX: u32 = 256;
/// Rows per `gdaldem` run (each with its own ground size).
const BAND: u32 = 32;
const MERCATOR_R: f64 = 6_378_137.0;

/// One product: the server's layer and query, and `gdaldem`'s arguments.
struct Product {
    name: &'static str,
    layer: &'static str,
    query: &'static str,
    gdaldem: &'static [&'static str],
    /// A colour ramp `gdaldem color-relief` applies after the first step (slope).
    ramp: Option<&'static str>,
}

const PRODUCTS: [Product; 5] = [
    Product {
        name: "hillshade",
        layer: "hillshade",
        query: "",
        gdaldem: &["hillshade"],
        ramp: None,
    },
    Product {
        name: "hillshade multidirectional, altitude 30",
        layer: "hillshade",
        query: "method=multidirectional&altitude=30",
        gdaldem: &["hillshade", "-multidirectional", "-alt", "30"],
        ramp: None,
    },
    Product {
        name: "hillshade combined, azimuth 200, z 2",
        layer: "hillshade",
        query: "method=combined&azimuth=200&z_factor=2",
        gdaldem: &["hillshade", "-combined", "-az", "200", "-z", "2"],
        ramp: None,
    },
    Product {
        name: "slope (degrees, ramp slope)",
        layer: "slope",
        query: "",
        gdaldem: &["slope"],
        ramp: Some("slope"),
    },
    Product {
        name: "color-relief (ramp hypsometric)",
        layer: "color-relief",
        query: "",
        gdaldem: &["color-relief"],
        ramp: Some("hypsometric"),
    },
];

fn ramp_text(name: &str) -> &'static str {
    BUILT_IN.iter().find(|(n, _, _)| *n == name).unwrap().2
}

/// Latitude of grid `y` (metres or degrees).
fn latitude(tms: TileMatrixSet, y: f64) -> f64 {
    match tms {
        TileMatrixSet::WebMercatorQuad => (y / MERCATOR_R).sinh().atan().to_degrees(),
        TileMatrixSet::WorldCrs84Quad => y,
    }
}

/// Ground metres (east–west, north–south) of a pixel of `tile` in row `j`, by
/// geodesics on WGS 84.
fn ground(tile: WebTile, j: f64) -> [f64; 2] {
    let c = tile.tms.cell_size(tile.z, PX);
    let [x, y] = tile.pixel_centre(PX, 0.0, j);
    let lon = match tile.tms {
        TileMatrixSet::WebMercatorQuad => (x / MERCATOR_R).to_degrees(),
        TileMatrixSet::WorldCrs84Quad => x,
    };
    let dlon = match tile.tms {
        TileMatrixSet::WebMercatorQuad => (c / MERCATOR_R).to_degrees(),
        TileMatrixSet::WorldCrs84Quad => c,
    };
    let lat = latitude(tile.tms, y);
    let (north, south) = (
        latitude(tile.tms, y + c / 2.0),
        latitude(tile.tms, y - c / 2.0),
    );
    let g = Geodesic::wgs84();
    let ew: f64 = g.inverse(lat, lon - dlon / 2.0, lat, lon + dlon / 2.0);
    let ns: f64 = g.inverse(south, lon, north, lon);
    [ew, ns]
}

fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap()
}

fn f32s(bytes: &[u8]) -> Vec<f32> {
    bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect()
}

/// GDAL's rendering of `tile`: `PX × PX` `[r, g, b]`, whether each pixel is data,
/// and whether its window is clear of voids (see [`compare`]).
struct Reference {
    rgb: Vec<[u8; 3]>,
    data: Vec<bool>,
    clear: Vec<bool>,
}

fn reference(dem: &Path, tile: WebTile, p: &Product, dir: &Path) -> Reference {
    let side = PX + 2;
    let warped = dir.join("warped.img");
    let heights = warp_tile(dem, tile, PX, 1, &warped, false);
    // Pixels whose bilinear stencil touches a void: GDAL's warp renormalizes over
    // the valid samples there, the server interpolates the build's fill (the
    // nearest valid heights); reading the voids' values as heights tells them apart.
    let raw = warp_tile(dem, tile, PX, 1, &dir.join("raw.img"), true);
    let touched: Vec<bool> = heights
        .iter()
        .zip(&raw)
        .map(|(a, b)| *a == -99999.0 || (a - b).abs() > 1e-3)
        .collect();
    let s = side as usize;
    let window = usize::from(p.layer != "color-relief");
    let clear = (0..(PX * PX) as usize)
        .map(|o| {
            let (j, i) = (o / PX as usize + 1, o % PX as usize + 1);
            (j - window..=j + window)
                .all(|y| (i - window..=i + window).all(|x| !touched[y * s + x]))
        })
        .collect();
    let n = (PX * PX) as usize;
    let mut rgb = vec![[0u8; 3]; n];
    let mut data = vec![false; n];
    if p.layer == "color-relief" {
        let ramp = dir.join("ramp.txt");
        std::fs::write(&ramp, ramp_text(p.ramp.unwrap())).unwrap();
        let out = dir.join("relief.img");
        run(
            "gdaldem",
            &[
                "color-relief",
                "-q",
                "-of",
                "ENVI",
                path_str(&warped),
                path_str(&ramp),
                path_str(&out),
            ],
        );
        let bytes = read(&out);
        let plane = (side * side) as usize;
        for j in 0..PX as usize {
            for i in 0..PX as usize {
                let k = (j + 1) * side as usize + i + 1;
                let o = j * PX as usize + i;
                rgb[o] = [bytes[k], bytes[plane + k], bytes[2 * plane + k]];
                data[o] = heights[k] != -99999.0;
            }
        }
        return Reference { rgb, data, clear };
    }
    for b in 0..PX / BAND {
        let j0 = b * BAND;
        let [ew, ns] = ground(tile, f64::from(j0) + f64::from(BAND) / 2.0 - 0.5);
        let band = dir.join("band.vrt");
        let rows = BAND + 2;
        run(
            "gdal_translate",
            &[
                "-q",
                "-of",
                "VRT",
                "-srcwin",
                "0",
                &j0.to_string(),
                &side.to_string(),
                &rows.to_string(),
                "-a_ullr",
                "0",
                "0",
                &(f64::from(side) * ew).to_string(),
                &(-f64::from(rows) * ns).to_string(),
                path_str(&warped),
                path_str(&band),
            ],
        );
        let out = dir.join("out.img");
        let mut args: Vec<&str> = p.gdaldem.to_vec();
        args.extend(["-q", "-of", "ENVI", path_str(&band), path_str(&out)]);
        run("gdaldem", &args);
        let (values, mask): (Vec<[u8; 3]>, Vec<bool>) = if let Some(r) = p.ramp {
            // Slope (float, −9999 for no data), then coloured by the ramp.
            let slopes = f32s(&read(&out));
            let ramp = dir.join("ramp.txt");
            std::fs::write(&ramp, ramp_text(r)).unwrap();
            let coloured = dir.join("coloured.img");
            run(
                "gdaldem",
                &[
                    "color-relief",
                    "-q",
                    "-of",
                    "ENVI",
                    path_str(&out),
                    path_str(&ramp),
                    path_str(&coloured),
                ],
            );
            let bytes = read(&coloured);
            let plane = slopes.len();
            (
                (0..plane)
                    .map(|k| [bytes[k], bytes[plane + k], bytes[2 * plane + k]])
                    .collect(),
                slopes.iter().map(|&s| s != -9999.0).collect(),
            )
        } else {
            read(&out).iter().map(|&g| ([g; 3], g != 0)).unzip()
        };
        for jj in 0..BAND as usize {
            for i in 0..PX as usize {
                let k = (jj + 1) * side as usize + i + 1;
                let o = (j0 as usize + jj) * PX as usize + i;
                rgb[o] = values[k];
                data[o] = mask[k];
            }
        }
    }
    Reference { rgb, data, clear }
}

/// The server's tile: `[r, g, b]` and whether each pixel is drawn (alpha 255).
fn served(srv: &Server, ds: &str, tile: WebTile, p: &Product) -> (Vec<[u8; 3]>, Vec<bool>) {
    let url = format!(
        "/v1/datasets/{ds}/{}/{}/{}/{}/{}.png?{}",
        tile.tms.path(),
        p.layer,
        tile.z,
        tile.x,
        tile.y,
        p.query
    );
    let r = srv.get(&url).expect(200);
    assert_eq!(r.must("content-type"), "image/png");
    let (side, buf) = serve_support::png_rgba(&r.body);
    assert_eq!(side, PX);
    buf.chunks_exact(4)
        .take((PX * PX) as usize)
        .map(|p| {
            assert!(p[3] == 0 || p[3] == 255, "alpha {}", p[3]);
            ([p[0], p[1], p[2]], p[3] == 255)
        })
        .unzip()
}

/// Compares every product on `tiles` of dataset `ds` (built from `dem`): on the
/// pixels both draw whose windows are clear of voids, at least 99 % within one
/// level; the rest (void edges) reported, and the drawn masks equal away from voids.
fn compare(ds: &str, dem: &Path, pyramid: &Path, tiles: &[WebTile]) {
    let srv = Server::start(&[pyramid], &[]);
    let dir = tempfile::tempdir().unwrap();
    for &tile in tiles {
        for p in &PRODUCTS {
            let r = reference(dem, tile, p, dir.path());
            let (got, ours) = served(&srv, ds, tile, p);
            let diff = |k: usize| {
                (0..3)
                    .map(|c| r.rgb[k][c].abs_diff(got[k][c]))
                    .max()
                    .unwrap()
            };
            let both: Vec<usize> = (0..got.len()).filter(|&k| r.data[k] && ours[k]).collect();
            let (clear, edge): (Vec<usize>, Vec<usize>) = both.iter().partition(|&&k| r.clear[k]);
            let within = clear.iter().filter(|&&k| diff(k) <= 1).count();
            let worst = clear.iter().map(|&k| diff(k)).max().unwrap_or(0);
            let edge_within = edge.iter().filter(|&&k| diff(k) <= 1).count();
            let only_ours = (0..got.len()).filter(|&k| ours[k] && !r.data[k]).count();
            let only_gdal = (0..got.len()).filter(|&k| r.data[k] && !ours[k]).count();
            let share = within as f64 / clear.len() as f64;
            eprintln!(
                "{ds} {tile} {}: {} px compared, {:.3} % within 1 level (worst {worst}); at void edges {} px, {edge_within} within 1 level; drawn only here {only_ours}, only by GDAL {only_gdal}",
                p.name,
                clear.len(),
                100.0 * share,
                edge.len()
            );
            assert!(
                // Most of the tile: SRTM's alpine voids and their edges take the rest.
                clear.len() as f64 >= 0.8 * f64::from(PX * PX),
                "{ds} {tile} {}: only {} pixels compared",
                p.name,
                clear.len()
            );
            assert!(
                share >= 0.99,
                "{ds} {tile} {}: {:.3} % within one level",
                p.name,
                100.0 * share
            );
            // Where one draws and the other does not: the edges of voids, where the
            // server's terrain follows the nearest sample (resample.rs step 4).
            let masks_differ = (0..got.len())
                .filter(|&k| ours[k] != r.data[k] && r.clear[k])
                .count();
            assert_eq!(
                masks_differ, 0,
                "{ds} {tile} {}: drawn masks differ away from voids",
                p.name
            );
        }
    }
}

#[test]
fn srtm_tiles_match_gdaldem_on_both_grids() {
    if !gdal_or_skip() {
        return;
    }
    let (Some(dem), Some(pyramid)) = (
        testdata::dem_or_skip("N46E008.tif"),
        dem_pyramid("N46E008.tif", 256),
    ) else {
        return;
    };
    let tiles = [
        WebTile::new(TileMatrixSet::WebMercatorQuad, 12, 2144, 1448).unwrap(),
        WebTile::new(TileMatrixSet::WorldCrs84Quad, 10, 1072, 247).unwrap(),
    ];
    compare("N46E008", &dem, &pyramid, &tiles);
}

#[test]
fn projected_tiles_match_gdaldem() {
    if !gdal_or_skip() {
        return;
    }
    let (Some(dem), Some(pyramid)) = (
        testdata::dem_or_skip("aletsch.tif"),
        dem_pyramid("aletsch.tif", 64),
    ) else {
        return;
    };
    // The middle of the DEM (46.53° N, 7.92° E), EPSG:2056 at 200 m.
    let tiles = [WebTile::new(TileMatrixSet::WebMercatorQuad, 10, 534, 362).unwrap()];
    compare("aletsch", &dem, &pyramid, &tiles);
}
