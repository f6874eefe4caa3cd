//! Contour tiles against GDAL (API.md "Contour tiles"), at the datasets' finest zoom
//! (where the server's heights are the DEM's bilinear heights):
//! - every vertex of every line the server sends lies on its elevation: on the cell
//!   edge it lies on, the DEM's heights at the edge's two samples (the DEM read
//!   bilinearly on its own samples, at points carried to the DEM's CRS by
//!   `gdaltransform`, PROJ), interpolated linearly to the vertex, equal the line's
//!   `ele` within the vertex's rounding to the tile's integer coordinates (1/16 of a
//!   sample along the edge, times the edge's height change) plus [`HEIGHTS_M`]. The
//!   DEM's bilinear height at the vertex itself departs further where the DEM's
//!   surface bends between the two samples (lines are straight between samples, as
//!   `gdal_contour`'s): that departure is printed, 99th percentile and worst;
//! - `gdal_contour` on the same grid of heights (the server's 512-pixel Terrarium
//!   tiles of the tile and its eight neighbours, cut to the contour tile's 2-sample
//!   border) at the same interval draws as many lines within 5 %.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

mod gdal;
#[allow(dead_code)] // each test binary uses some of the shared helpers
mod grid_support;
#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use gdal::dem::Dem;
use gdal::{gdal_or_skip, path_str, run};
use geo_types::Geometry;
use grid_support::{decode_rgba, terrarium};
use serve_support::{Server, dem_pyramid};
use std::path::Path;
use tessera_server::web::tile_matrix::{TileMatrixSet, WebTile};
use tessera_shared::testdata;

/// Samples across a contour tile and beyond each edge (routes/contours.rs).
const GRID: u32 = 512;
const BORDER: u32 = 2;
/// Tile units per grid sample (4096 / 512).
const UNITS: f64 = 8.0;
/// How far the server's heights may lie from the DEM's bilinear heights at the same
/// point, in metres: 0.1 mm (tests/serve_grid_tiles.rs measures the same tiles'
/// heights so) and the pyramid's 16-bit storage (half a step: 0.035 m for N46E008's
/// 4 400 m of relief, 0.05 m for aletsch's).
const HEIGHTS_M: f64 = 0.06;

/// One decoded line: elevation and vertices in tile units.
struct Line {
    ele: f64,
    index: bool,
    points: Vec<[f64; 2]>,
}

fn served(srv: &Server, ds: &str, tile: WebTile, query: &str) -> Vec<Line> {
    let url = format!(
        "/v1/datasets/{ds}/{}/contours/{}/{}/{}.mvt?{query}",
        tile.tms.path(),
        tile.z,
        tile.x,
        tile.y
    );
    let r = srv.get(&url).expect(200);
    assert_eq!(r.must("content-type"), "application/vnd.mapbox-vector-tile");
    let reader = mvt_reader::Reader::new(r.body.clone()).unwrap();
    assert_eq!(reader.get_layer_names().unwrap(), ["contours"]);
    let meta = reader.get_layer_metadata().unwrap();
    assert_eq!(meta[0].extent, 4096);
    let mut lines = Vec::new();
    for f in reader.get_features(0).unwrap() {
        let p = f.properties.as_ref().unwrap();
        let ele = match p["ele"] {
            mvt_reader::feature::Value::SInt(v) => v as f64,
            mvt_reader::feature::Value::Double(v) => v,
            ref other => panic!("ele {other:?}"),
        };
        let mvt_reader::feature::Value::Bool(index) = p["index"] else {
            panic!("index {:?}", p["index"])
        };
        let parts = match &f.geometry {
            Geometry::LineString(l) => vec![l.clone()],
            Geometry::MultiLineString(m) => m.0.clone(),
            other => panic!("not a line: {other:?}"),
        };
        for l in parts {
            lines.push(Line {
                ele,
                index,
                points: l
                    .coords()
                    .map(|c| [f64::from(c.x), f64::from(c.y)])
                    .collect(),
            });
        }
    }
    lines
}

/// The server's heights on the contour tile's grid: its 512-pixel Terrarium tiles of
/// `tile` and its neighbours (no data where a neighbour is beyond the dataset or
/// transparent), cut to the tile and [`BORDER`] samples around it.
fn server_grid(srv: &Server, ds: &str, tile: WebTile) -> Vec<f32> {
    let side = (GRID + 2 * BORDER) as usize;
    let mut grid = vec![NODATA; side * side];
    for dy in -1i64..=1 {
        for dx in -1i64..=1 {
            let (x, y) = (i64::from(tile.x) + dx, i64::from(tile.y) + dy);
            let url = format!(
                "/v1/datasets/{ds}/{}/{}/{x}/{y}.png?encoding=terrarium&size={GRID}&nodata=transparent",
                tile.tms.path(),
                tile.z
            );
            let r = srv.get(&url);
            if r.status != 200 {
                continue;
            }
            let (w, px) = decode_rgba(&r.body);
            assert_eq!(w, GRID);
            for j in 0..GRID as i64 {
                for i in 0..GRID as i64 {
                    // Where this pixel lies on the bordered grid.
                    let gx = dx * i64::from(GRID) + i + i64::from(BORDER);
                    let gy = dy * i64::from(GRID) + j + i64::from(BORDER);
                    if !(0..side as i64).contains(&gx) || !(0..side as i64).contains(&gy) {
                        continue;
                    }
                    let p = &px[((j * i64::from(GRID) + i) * 4) as usize..][..4];
                    if p[3] == 255 {
                        grid[gy as usize * side + gx as usize] = terrarium(p) as f32;
                    }
                }
            }
        }
    }
    grid
}

const NODATA: f32 = -99_999.0;

/// `gdal_contour`'s lines at `interval` on `grid` (a square of float32 heights).
fn gdal_lines(grid: &[f32], interval: f64, dir: &Path) -> usize {
    let side = (grid.len() as f64).sqrt() as usize;
    let raw = dir.join("grid.img");
    let bytes: Vec<u8> = grid.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(&raw, bytes).unwrap();
    std::fs::write(
        dir.join("grid.hdr"),
        format!(
            "ENVI\nsamples = {side}\nlines = {side}\nbands = 1\nheader offset = 0\nfile type = ENVI Standard\ndata type = 4\ninterleave = bsq\nbyte order = 0\ndata ignore value = {NODATA}\n"
        ),
    )
    .unwrap();
    let out = dir.join("contours.geojson");
    let _ = std::fs::remove_file(&out);
    let i = interval.to_string();
    let nodata = NODATA.to_string();
    run(
        "gdal_contour",
        &[
            "-q",
            "-i",
            &i,
            "-a",
            "ele",
            "-snodata",
            &nodata,
            "-f",
            "GeoJSON",
            path_str(&raw),
            path_str(&out),
        ],
    );
    let doc: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    doc["features"].as_array().unwrap().len()
}

/// The cell edges a vertex at grid point `(x, y)` may lie on — vertices are where a
/// level crosses an edge, moved at most 1/16 of a sample each way by rounding, so
/// near a sample several edges qualify — as their two samples and how far along.
fn edges_of(x: f64, y: f64, side: usize) -> Vec<([usize; 2], [usize; 2], f64)> {
    const SLACK: f64 = 0.5 / UNITS + 1e-9;
    let last = side as f64 - 1.0;
    let mut out = Vec::new();
    for vertical in [true, false] {
        let (fixed, free) = if vertical { (x, y) } else { (y, x) };
        if (fixed - fixed.round()).abs() > SLACK || !(0.0..=last).contains(&fixed.round()) {
            continue;
        }
        let start = (free - SLACK).floor().max(0.0);
        let mut lo = start;
        while lo + 1.0 <= last && lo <= free + SLACK {
            let t = (free - lo).clamp(0.0, 1.0);
            let (f, l) = (fixed.round() as usize, lo as usize);
            out.push(if vertical {
                ([f, l], [f, l + 1], t)
            } else {
                ([l, f], [l + 1, f], t)
            });
            lo += 1.0;
        }
    }
    out
}

/// Compares the server's contours of `tile` at `interval` with the DEM and with
/// `gdal_contour`.
fn compare(srv: &Server, ds: &str, dem: &Dem, tile: WebTile, interval: f64) {
    let dir = tempfile::tempdir().unwrap();
    let grid = server_grid(srv, ds, tile);
    let side = (GRID + 2 * BORDER) as usize;
    let on_grid = |c: usize, r: usize| -> Option<f64> {
        let v = grid[r * side + c];
        (v != NODATA).then_some(f64::from(v))
    };
    let lines = served(srv, ds, tile, &format!("interval={interval}"));
    let c = tile.tms.cell_size(tile.z, GRID);
    let [x0, _, _, y1] = tile.bounds();
    let border = f64::from(BORDER);
    let to_crs = |g: [f64; 2]| {
        [
            x0 + (g[0] - border + 0.5) * c,
            y1 - (g[1] - border + 0.5) * c,
        ]
    };
    let from = format!("EPSG:{}", tile.tms.epsg());
    // The DEM at every sample of the grid, and at every vertex.
    let samples: Vec<[f64; 2]> = (0..side * side)
        .map(|i| to_crs([(i % side) as f64, (i / side) as f64]))
        .collect();
    let sample_at = gdal::transform(&from, &dem.epsg, &samples);
    let dem_grid: Vec<Option<f64>> = sample_at.iter().map(|q| dem.bilinear(q[0], q[1])).collect();
    // `gdal_contour` cuts lines where the DEM has no data, as the server does: its
    // grid is the server's heights where the DEM's pixel there holds data.
    let reference: Vec<f32> = grid
        .iter()
        .zip(&sample_at)
        .map(|(h, q)| if dem.has_data(q[0], q[1]) { *h } else { NODATA })
        .collect();
    let mut vertices = Vec::new();
    for line in &lines {
        let k = (line.ele / interval).round();
        assert!(
            (line.ele - k * interval).abs() < 1e-6,
            "ele {} off the interval",
            line.ele
        );
        assert_eq!(
            line.index,
            (k as i64) % 5 == 0,
            "index flag of {}",
            line.ele
        );
        assert!(line.points.len() >= 2);
        for p in &line.points {
            let g = [p[0] / UNITS - 0.5 + border, p[1] / UNITS - 0.5 + border];
            assert!(
                g.iter().all(|v| *v > -0.1 && *v < side as f64 - 0.9),
                "vertex {p:?} beyond the tile's buffer"
            );
            vertices.push(to_crs(g));
        }
    }
    let at_dem = gdal::transform(&from, &dem.epsg, &vertices);
    let mut at = at_dem.iter();
    let mut s = Stats::default();
    for line in &lines {
        for p in &line.points {
            let q = at.next().unwrap();
            let g = [p[0] / UNITS - 0.5 + border, p[1] / UNITS - 0.5 + border];
            // The best of the edges the vertex may lie on: on the DEM's samples and on
            // the server's own, how far beyond the rounding it is.
            let mut best: Option<(f64, f64, f64)> = None;
            let mut beside_void = false;
            for (e0, e1, t) in edges_of(g[0], g[1], side) {
                let (Some(d0), Some(d1), Some(g0), Some(g1)) = (
                    dem_grid[e0[1] * side + e0[0]],
                    dem_grid[e1[1] * side + e1[0]],
                    on_grid(e0[0], e0[1]),
                    on_grid(e1[0], e1[1]),
                ) else {
                    beside_void = true;
                    continue;
                };
                // Rounding to whole tile units moves a vertex up to half a unit
                // along its edge: 1/16 of a sample.
                let rounding = (d1 - d0).abs() * 0.5 / UNITS;
                let on_dem = (d0 + t * (d1 - d0) - line.ele).abs() - rounding;
                let grid_rounding = (g1 - g0).abs() * 0.5 / UNITS;
                let on_tile = (g0 + t * (g1 - g0) - line.ele).abs() - grid_rounding;
                if best.is_none_or(|b| on_dem < b.0) {
                    best = Some((on_dem, on_tile, rounding));
                }
            }
            // Beside a void the DEM's 4-sample bilinear has no height where the
            // server's nearest-sample validity has one (web/resample.rs).
            let (false, Some((on_dem, on_tile, rounding))) = (beside_void, best) else {
                continue;
            };
            assert!(
                on_dem <= HEIGHTS_M,
                "{tile}: vertex {p:?} of the {} m line: its edge's DEM samples reach the level {on_dem:.3} m beyond rounding",
                line.ele
            );
            assert!(
                on_tile <= 1.0 / 256.0 + 1e-4,
                "{tile}: vertex {p:?} of the {} m line: {on_tile:.3} m beyond rounding on the tile's grid",
                line.ele
            );
            s.worst_edge = s.worst_edge.max(on_dem);
            // The DEM's surface itself bends between the samples (reported).
            if let Some(h) = dem.bilinear(q[0], q[1]) {
                let bend = ((h - line.ele).abs() - rounding).max(0.0);
                s.worst_bend = s.worst_bend.max(bend);
                s.bends.push(bend);
            }
            s.vertices += 1;
        }
    }
    let theirs = gdal_lines(&reference, interval, dir.path());
    let ours = lines.len();
    let diff = (ours as f64 - theirs as f64).abs() / theirs.max(1) as f64;
    s.bends.sort_by(f64::total_cmp);
    let p99 = s
        .bends
        .get(s.bends.len() * 99 / 100)
        .copied()
        .unwrap_or_default();
    eprintln!(
        "{ds} {tile} every {interval} m: {ours} lines (gdal_contour {theirs}, {:.2} % apart); {} vertices: on their edge's DEM samples at most {:.4} m beyond rounding; the DEM's bilinear surface at the vertex within {p99:.3} m (99 %), {:.3} m (all) beyond rounding",
        diff * 100.0,
        s.vertices,
        s.worst_edge,
        s.worst_bend
    );
    assert!(
        s.vertices > 1000,
        "{tile}: too few vertices checked ({})",
        s.vertices
    );
    assert!(ours > 10, "{tile}: too few lines to compare ({ours})");
    assert!(
        diff <= 0.05,
        "{tile}: {ours} lines against gdal_contour's {theirs}"
    );
}

/// What one tile's vertices showed.
#[derive(Default)]
struct Stats {
    vertices: usize,
    worst_edge: f64,
    worst_bend: f64,
    bends: Vec<f64>,
}

#[test]
fn srtm_contours_lie_on_the_dem_and_match_gdal_contour() {
    if !gdal_or_skip() {
        return;
    }
    let (Some(dem), Some(pyramid)) = (
        testdata::dem_or_skip("N46E008.tif"),
        dem_pyramid("N46E008.tif", 256),
    ) else {
        return;
    };
    let srv = Server::start(&[&pyramid], &[]);
    let dem = Dem::read(&dem, "EPSG:4326");
    // Andermatt and the Gotthard at the finest zoom of each grid (11 and 10).
    let mercator = WebTile::new(TileMatrixSet::WebMercatorQuad, 11, 1072, 724).unwrap();
    compare(&srv, "N46E008", &dem, mercator, 50.0);
    compare(&srv, "N46E008", &dem, mercator, 20.0);
    let crs84 = WebTile::new(TileMatrixSet::WorldCrs84Quad, 10, 1072, 247).unwrap();
    compare(&srv, "N46E008", &dem, crs84, 100.0);
}

#[test]
fn projected_contours_lie_on_the_dem_and_match_gdal_contour() {
    if !gdal_or_skip() {
        return;
    }
    let (Some(dem), Some(pyramid)) = (
        testdata::dem_or_skip("aletsch.tif"),
        dem_pyramid("aletsch.tif", 64),
    ) else {
        return;
    };
    let srv = Server::start(&[&pyramid], &[]);
    let dem = Dem::read(&dem, "EPSG:2056");
    // The middle of the LV95 DEM (46.53° N, 7.92° E) at its finest zoom, 10.
    let tile = WebTile::new(TileMatrixSet::WebMercatorQuad, 10, 534, 362).unwrap();
    compare(&srv, "aletsch", &dem, tile, 100.0);
}
