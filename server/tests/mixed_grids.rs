//! Collections on different grids built as one pyramid (DECISIONS.md "Mixed-grid
//! collections"), with default flags, against GDAL: a 30″ "global" base (N46E008 warped
//! by `gdalwarp -r average`), the real 3″ N46E008 over a sub-window (cut with
//! `gdal_translate -srcwin`) and aletsch.tif (EPSG:2056, 200 m). The pyramid is on the
//! finest input's grid (EPSG:4326, 3″, N46E008's lattice), and its heights equal
//! `gdalwarp` of the inputs in priority order (coarsest first: GDAL draws the last on
//! top) onto the same grid with the same resampling, within the quantization error plus
//! what our interpolated source positions (≤ `MAX_ERROR_PX` off) can change, at 2 000
//! random samples away from the inputs' edges (where which input wins can flip with a
//! position 1e-9 off).

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

mod gdal;
#[allow(dead_code)] // each test binary uses some of the shared helpers
mod grid_support;
mod raster_support;
#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use gdal::fusion::Collection;
use gdal::{path_str, run};
use raster_support::{finest_samples, read_raster, steepest};
use std::path::Path;
use std::process::{Command, Output};
use tessera_server::crs::Crs;
use tessera_server::ingest::reproject::MAX_ERROR_PX;
use tessera_shared::Pyramid;

fn build(inputs: &[&Path], out: &Path, extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_tessera-server"))
        .arg("build")
        .args(inputs)
        .args(["--tile-size", "256", "--quiet", "-o"])
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

/// An input's samples and grid, to tell where a comparison is meaningful.
struct Grid {
    crs: Crs,
    gt: [f64; 6],
    w: u32,
    h: u32,
    v: Vec<f32>,
}

impl Grid {
    fn read(file: &Path, crs: &str) -> Self {
        let (w, h, v) = read_raster(file);
        let Ok(tessera_server::ingest::Input::Rows(rows)) =
            tessera_server::ingest::open(path_str(file))
        else {
            panic!()
        };
        let gt = rows.info().georef.as_ref().unwrap().geotransform;
        Self {
            crs: Crs::parse(crs).unwrap(),
            gt,
            w,
            h,
            v,
        }
    }

    /// `(x, y)` of `crs` in this grid's pixels (0 at the first pixel's outer edge).
    fn pixel(&self, crs: &Crs, x: f64, y: f64) -> (f64, f64) {
        let [sx, sy] = crs.transform_to(&self.crs, x, y).unwrap();
        (
            (sx - self.gt[0]) / self.gt[1],
            (sy - self.gt[3]) / self.gt[5],
        )
    }

    /// Within `margin` pixels of the grid's edge, or of one of its no-data samples:
    /// where which input wins, or how weights are renormalised, can differ.
    fn near_edge_or_void(&self, crs: &Crs, x: f64, y: f64, margin: f64) -> bool {
        let (c, r) = self.pixel(crs, x, y);
        let inside = |v: f64, n: u32| v > -margin && v < f64::from(n) + margin;
        if !(inside(c, self.w) && inside(r, self.h)) {
            return false;
        }
        let deep = |v: f64, n: u32| v > margin && v < f64::from(n) - margin;
        if !(deep(c, self.w) && deep(r, self.h)) {
            return true;
        }
        let m = margin.ceil() as i64;
        let (ci, ri) = (c.floor() as i64, r.floor() as i64);
        (ri - m..=ri + m).any(|rr| {
            (ci - m..=ci + m).any(|cc| {
                cc >= 0
                    && rr >= 0
                    && cc < i64::from(self.w)
                    && rr < i64::from(self.h)
                    && self.v[(rr * i64::from(self.w) + cc) as usize].is_nan()
            })
        })
    }

    fn covers(&self, crs: &Crs, x: f64, y: f64) -> bool {
        let (c, r) = self.pixel(crs, x, y);
        c > 0.0 && r > 0.0 && c < f64::from(self.w) && r < f64::from(self.h)
    }
}

fn fuse_and_compare(c: &Collection, resampling: &str) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("fused.tess");
    let mut extra = vec![];
    if resampling != "bilinear" {
        extra = vec!["--resampling", resampling];
    }
    let o = build(&[&c.base, &c.fine, &c.aletsch], &out, &extra);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let p = Pyramid::open_file(&out).unwrap();
    let m = p.metadata();
    let g = m.georef.as_ref().unwrap();
    // The finest input's grid: EPSG:4326 at 3″, on N46E008's lattice.
    assert_eq!(g.epsg, Some(4326));
    let gt = g.geotransform;
    assert!((gt[1] - 1.0 / 1200.0).abs() < 1e-15 && (gt[5] + 1.0 / 1200.0).abs() < 1e-15);
    let lattice = (gt[0] - 7.999_583_333_333_334) * 1200.0;
    assert!((lattice - lattice.round()).abs() < 1e-6, "{lattice}");

    // GDAL: the same grid, inputs coarsest first (base 30″, aletsch 200 m, fine 3″).
    let (w, h) = (m.width, m.height);
    let te = [
        gt[0],
        gt[3] + f64::from(h) * gt[5],
        gt[0] + f64::from(w) * gt[1],
        gt[3],
    ]
    .map(|v| format!("{v:.12}"));
    let reference = dir.path().join("gdalwarp.tif");
    let (ws, hs) = (w.to_string(), h.to_string());
    run(
        "gdalwarp",
        &[
            "-q",
            "-t_srs",
            "EPSG:4326",
            "-te",
            &te[0],
            &te[1],
            &te[2],
            &te[3],
            "-ts",
            &ws,
            &hs,
            "-r",
            resampling,
            "-et",
            "0",
            "-ot",
            "Float32",
            "-dstnodata",
            "-99999",
            path_str(&c.base),
            path_str(&c.aletsch),
            path_str(&c.fine),
            path_str(&reference),
        ],
    );
    let (_, _, want) = read_raster(&reference);
    let got = finest_samples(&p);
    let wgs84 = Crs::from_epsg(4326).unwrap();
    let grids = [
        Grid::read(&c.fine, "EPSG:4326"),
        Grid::read(&c.aletsch, "EPSG:2056"),
        Grid::read(&c.base, "EPSG:4326"),
    ];
    // 2 000 random samples valid in both, away from the inputs' edges and voids.
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let (mut compared, mut worst, mut fine_hits, mut aletsch_hits) = (0, f64::NEG_INFINITY, 0, 0);
    let mut tries = 0;
    while compared < 2000 {
        tries += 1;
        assert!(tries < 200_000, "too few comparable samples ({compared})");
        let i = (next() % u64::from(w * h)) as usize;
        let (t, o) = (want[i], got[i]);
        let (col, row) = (i % w as usize, i / w as usize);
        if t.is_nan()
            || o.is_nan()
            || col < 2
            || row < 2
            || col + 2 >= w as usize
            || row + 2 >= h as usize
        {
            continue;
        }
        let x = gt[0] + (col as f64 + 0.5) * gt[1];
        let y = gt[3] + (row as f64 + 0.5) * gt[5];
        if grids.iter().any(|g| g.near_edge_or_void(&wgs84, x, y, 2.5)) {
            continue;
        }
        let bound = m.quantization.max_error + 1e-3 + 2.0 * MAX_ERROR_PX * steepest(&want, w, h, i);
        worst = worst.max(f64::from(o - t).abs() - bound);
        compared += 1;
        if grids[0].covers(&wgs84, x, y) {
            fine_hits += 1;
        } else if grids[1].covers(&wgs84, x, y) {
            aletsch_hits += 1;
        }
    }
    eprintln!(
        "{resampling}: {compared} samples ({fine_hits} from the 3″ window, {aletsch_hits} from \
         aletsch), worst excess over the bound {worst:.2e} m"
    );
    assert!(
        fine_hits > 50 && aletsch_hits > 50,
        "{fine_hits} {aletsch_hits}"
    );
    assert!(
        worst <= 0.0,
        "{resampling}: a height differs by {worst} m more than its bound"
    );
}

#[test]
fn three_grids_in_two_crss_fuse_as_gdalwarp_draws_them() {
    let Some(c) = Collection::new() else { return };
    fuse_and_compare(&c, "bilinear");
    fuse_and_compare(&c, "cubic");
}

/// The fused pyramid says where its data came from: `info` lists the three sources
/// in priority order with their CRS, spacing and deepest level, and the server (default
/// flags, asked from another origin as a web map would) serves their outlines as GeoJSON,
/// each where GDAL puts the input's corners.
#[test]
fn the_pyramid_records_and_serves_its_sources() {
    let Some(c) = Collection::new() else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("fused.tess");
    let o = build(&[&c.base, &c.fine, &c.aletsch], &out, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let info = Command::new(env!("CARGO_BIN_EXE_tessera-server"))
        .arg("info")
        .arg(&out)
        .output()
        .unwrap();
    let text = String::from_utf8(info.stdout).unwrap();
    let lines: Vec<&str> = text
        .lines()
        .filter(|l| l.starts_with("  ") && l.contains(".tif:"))
        .collect();
    assert_eq!(lines.len(), 3, "{text}");
    assert!(
        lines[0].starts_with("  fine_3s.tif: EPSG:4326 (WGS 84)"),
        "{text}"
    );
    assert!(
        lines[1].starts_with("  aletsch.tif: EPSG:2056 (CH1903+ / LV95), 199.99"),
        "{text}"
    );
    assert!(lines[2].starts_with("  base_30s.tif: EPSG:4326"), "{text}");

    let server = serve_support::Server::start(&[&out], &[]);
    let r = server.get_with(
        "/v1/datasets/fused/coverage.geojson",
        &[("Origin", "https://maps.example.org")],
    );
    assert_eq!(r.status, 200);
    assert_eq!(r.header("content-type"), Some("application/geo+json"));
    assert!(r.header("access-control-allow-origin").is_some());
    assert!(r.header("etag").is_some());
    let fc = r.json();
    assert_eq!(fc["type"], "FeatureCollection");
    let f = fc["features"].as_array().unwrap();
    let names: Vec<&str> = f
        .iter()
        .map(|x| x["properties"]["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["fine_3s.tif", "aletsch.tif", "base_30s.tif"]);
    let levels: Vec<u64> = f
        .iter()
        .map(|x| x["properties"]["level"].as_u64().unwrap())
        .collect();
    let finest = fc["levels"].as_u64().unwrap() - 1;
    // The 3″ window at the finest level, aletsch (200 m ≈ 2.5× coarser) one above,
    // the 30″ base three above (10× coarser: 8× is the last level that keeps it).
    assert_eq!(levels, [finest, finest - 1, finest.saturating_sub(3)]);
    // Aletsch's outline passes through its corners as GDAL carries them to WGS 84.
    let ring: Vec<[f64; 2]> = f[1]["geometry"]["coordinates"][0]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| [p[0].as_f64().unwrap(), p[1].as_f64().unwrap()])
        .collect();
    let corners = gdal::transform(
        "EPSG:2056",
        "EPSG:4326",
        &[[2_601_100.0, 1_184_500.0], [2_672_700.0, 1_122_500.0]],
    );
    for c in corners {
        let (lon, lat) = (c[0], c[1]);
        let nearest = ring
            .iter()
            .map(|p| (p[0] - lon).hypot(p[1] - lat))
            .fold(f64::INFINITY, f64::min);
        assert!(
            nearest < 1e-6,
            "no outline point at {lon}, {lat}: {nearest}"
        );
    }
}

/// `--feather 3000`: along a row through the middle of the 3″ window, each sample
/// within 3 km of the window's east edge is the window's height blended with what lies
/// below it (the base and aletsch, fused with the same feather) by the share
/// distance-to-edge / 3 km, and deeper in it is the window's height alone. A hard seam
/// (no feathering) or a blend the other way round fails the first check.
#[test]
fn feathering_blends_linearly_into_what_lies_below() {
    let Some(c) = Collection::new() else { return };
    let dir = tempfile::tempdir().unwrap();
    let built = |inputs: &[&Path], name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let o = build(inputs, &out, extra);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let p = Pyramid::open_file(&out).unwrap();
        (finest_samples(&p), p.metadata().clone())
    };
    let feather = ["--feather", "3000"];
    let (hard, m) = built(&[&c.base, &c.fine, &c.aletsch], "hard.tess", &[]);
    let (soft, ms) = built(&[&c.base, &c.fine, &c.aletsch], "soft.tess", &feather);
    // What lies below the window: the same inputs with the window all no-data (so the
    // grid, which the window decides, is the same).
    let void = dir.path().join("fine_void.tif");
    run(
        "gdal_translate",
        &[
            "-q",
            "-scale",
            "0",
            "5000",
            "-32767",
            "-32767",
            path_str(&c.fine),
            path_str(&void),
        ],
    );
    let (below, mb) = built(&[&c.base, &void, &c.aletsch], "below.tess", &feather);
    let g = m.georef.as_ref().unwrap().geotransform;
    assert_eq!(g, ms.georef.as_ref().unwrap().geotransform);
    assert_eq!(g, mb.georef.as_ref().unwrap().geotransform);
    let w = m.width as usize;
    let cell_x = m.ground_spacing.unwrap().x;
    // The fine window's east edge, on a row through its middle.
    let [_, y0, x1, _] = Collection::fine_window_on(&g);
    let (x1, row) = (x1 as usize, y0 as usize + 200);
    let q = m.quantization.max_error + ms.quantization.max_error + mb.quantization.max_error;
    let (mut blended, mut alone) = (0, 0);
    for col in x1 - 80..x1 {
        let i = row * w + col;
        let (a, s, b) = (f64::from(hard[i]), f64::from(soft[i]), f64::from(below[i]));
        if a.is_nan() || s.is_nan() || b.is_nan() {
            continue;
        }
        // Distance from the sample's centre to the window's east edge.
        let d = (x1 as f64 - (col as f64 + 0.5)) * cell_x;
        let share = (d / 3000.0).min(1.0);
        let want = b + share * (a - b);
        assert!(
            (s - want).abs() <= q + 1e-3,
            "col {col}, {d:.0} m from the edge: {s} vs {want} (window {a}, below {b})"
        );
        if share < 1.0 && (a - b).abs() > 5.0 {
            blended += 1;
        } else if share >= 1.0 {
            alone += 1;
        }
    }
    assert!(
        blended > 20 && alone > 10,
        "{blended} blended, {alone} deep inside"
    );
}

/// A spacing meant as metres for a grid in degrees (1e-5° ≈ 1 m over the 1.5° × 1°
/// union: 1.5e10 samples) is refused before anything is read, naming the size, with
/// nothing written (by `--max-samples`; the default, 2^40, leaves it to the free-disk
/// check, which depends on the machine). So is a feather that is not a distance.
#[test]
fn a_target_grid_too_large_is_refused_before_work_starts() {
    let Some(c) = Collection::new() else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.tess");
    let inputs = [c.base.as_path(), c.fine.as_path(), c.aletsch.as_path()];
    let o = build(
        &inputs,
        &out,
        &["--spacing", "0.00001", "--max-samples", "1000000000"],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("more than --max-samples") && err.contains("154668 × 100000"),
        "{err}"
    );
    assert!(!out.exists());
    let o = build(&[&c.base, &c.fine], &out, &["--feather", "0"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("--feather 0: want a positive"),
        "{err}"
    );
    assert!(!out.exists());
}

/// Multi-resolution: the fused pyramid stores levels below a place's coarsest only
/// where finer data lies. Every tile it stores is the `--full-pyramid` build's, byte
/// for byte (same heights and error tables: nodes below are still built); every stored
/// tile's parent is stored; the finest level exists only around the 3″ window. A web
/// tile over a place only the 30″ base covers is still terrain (the server upsamples
/// the stored ancestor), within what the stored level says it can be off: the largest
/// difference there between the full pyramid's finest samples and the bilinear
/// surface of the ancestor's, plus quantization and Terrarium's 1/256 m.
#[test]
fn deep_tiles_are_stored_only_where_fine_data_lies() {
    use tessera_shared::{Level, TileId};
    let Some(c) = Collection::new() else { return };
    let dir = tempfile::tempdir().unwrap();
    let (multi, full) = (dir.path().join("multi.tess"), dir.path().join("full.tess"));
    let inputs = [c.base.as_path(), c.fine.as_path(), c.aletsch.as_path()];
    for (out, extra) in [(&multi, &[][..]), (&full, &["--full-pyramid"][..])] {
        let o = build(&inputs, out, extra);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let (pm, pf) = (
        Pyramid::open_file(&multi).unwrap(),
        Pyramid::open_file(&full).unwrap(),
    );
    let g = *pm.geometry();
    assert_eq!(&g, pf.geometry());
    let finest = g.finest();
    let (mut stored, mut dropped) = (0, 0);
    for level in g.levels() {
        for tile in g.present_tiles(level) {
            let (m, f) = (pm.entry(tile), pf.entry(tile));
            match (m.filter(|e| e.is_present()), f.filter(|e| e.is_present())) {
                (Some(m), Some(f)) => {
                    assert_eq!(
                        m.checksum, f.checksum,
                        "{tile}: not the full pyramid's record"
                    );
                    if let Some(p) = tile.parent() {
                        assert!(
                            pm.entry(p)
                                .is_some_and(tessera_shared::format::IndexEntry::is_present),
                            "{tile}: parent absent"
                        );
                    }
                    stored += 1;
                }
                (Some(_), None) => panic!("{tile} stored only in the multi-resolution pyramid"),
                (None, Some(_)) => dropped += 1,
                (None, None) => {}
            }
        }
    }
    assert!(
        stored > 0 && dropped > 0,
        "{stored} stored, {dropped} dropped"
    );
    // The 3″ window on the mosaic's grid (aletsch's west edge is the mosaic's).
    let m = pm.metadata();
    let gt = m.georef.as_ref().unwrap().geotransform;
    let [wx0, wy0, wx1, wy1] = Collection::fine_window_on(&gt);
    let t = u64::from(g.tile_size());
    for tile in g.present_tiles(finest).filter(|t| {
        pm.entry(*t)
            .is_some_and(tessera_shared::format::IndexEntry::is_present)
    }) {
        // Its parent's samples meet the window.
        let (px, py) = (
            u64::from(tile.x() / 2) * 2 * t,
            u64::from(tile.y() / 2) * 2 * t,
        );
        assert!(
            px <= wx1 && px + 2 * t >= wx0 && py <= wy1 && py + 2 * t >= wy0,
            "{tile}: finest tile far from the 3″ window"
        );
    }
    let size = |p: &Path| std::fs::metadata(p).unwrap().len();
    eprintln!(
        "multi-resolution {} bytes, full pyramid {} bytes; {stored} tiles stored, {dropped} not",
        size(&multi),
        size(&full)
    );
    assert!(size(&multi) < size(&full));

    // A zoom-13 Web Mercator tile where only the base lies (8.85° E, 46.15° N).
    let server = serve_support::Server::start(&[&multi, &full], &[]);
    let (x, y) = grid_support::xyz_tile(8.85, 46.15, 13);
    let heights = |name: &str| {
        let r = server.get(&format!(
            "/v1/datasets/{name}/webmercator/13/{x}/{y}.png?encoding=terrarium"
        ));
        assert_eq!(r.status, 200);
        let (_, rgba) = grid_support::decode_rgba(&r.body);
        rgba.chunks_exact(4)
            .map(grid_support::terrarium)
            .collect::<Vec<f64>>()
    };
    let (hm, hf) = (heights("multi"), heights("full"));
    let relief = hm.iter().copied().fold(f64::NEG_INFINITY, f64::max)
        - hm.iter().copied().fold(f64::INFINITY, f64::min);
    assert!(
        relief > 10.0,
        "a flat tile ({relief} m of relief): no terrain drawn there"
    );
    // What the stored level can be off there: the full pyramid's finest samples
    // against the bilinear surface of the level the base supports, over the web
    // tile's place (it spans 52 × 37 finest samples here; ± 64 around its point).
    let base_level = m
        .sources
        .iter()
        .find(|s| s.name == "base_30s.tif")
        .unwrap()
        .level;
    let step = 1u64 << (finest.get() - base_level);
    let samples = finest_samples(&pf);
    let w = u64::from(m.width);
    let (cx, cy) = (
        ((8.85 - gt[0]) / gt[1]) as u64,
        ((gt[3] - 46.15) / -gt[5]) as u64,
    );
    let anc_level = Level::new(base_level).unwrap();
    let q = pf.metadata().quantization;
    let records = std::cell::RefCell::new(std::collections::HashMap::new());
    let coarse = |sx: u64, sy: u64| -> f64 {
        // The level's sample grid: every `step`-th finest sample.
        let (gx, gy) = (sx as f64 / step as f64, sy as f64 / step as f64);
        let tile = TileId::new(anc_level, (gx as u64 / t) as u32, (gy as u64 / t) as u32).unwrap();
        let mut cache = records.borrow_mut();
        let rec = cache
            .entry(tile)
            .or_insert_with(|| pf.read_tile(tile).unwrap().unwrap());
        let (ox, oy) = (
            gx - f64::from(tile.x()) * t as f64,
            gy - f64::from(tile.y()) * t as f64,
        );
        let (x0, y0) = ((ox as u64).min(t - 1), (oy as u64).min(t - 1));
        let (fx, fy) = (ox - x0 as f64, oy - y0 as f64);
        let at = |i: u64, j: u64| q.height(rec.heights[(j * (t + 1) + i) as usize]);
        at(x0, y0) * (1.0 - fx) * (1.0 - fy)
            + at(x0 + 1, y0) * fx * (1.0 - fy)
            + at(x0, y0 + 1) * (1.0 - fx) * fy
            + at(x0 + 1, y0 + 1) * fx * fy
    };
    let mut off = 0f64;
    for sy in cy.saturating_sub(64)..(cy + 64).min(u64::from(m.height)) {
        for sx in cx.saturating_sub(64)..(cx + 64).min(w) {
            let v = f64::from(samples[(sy * w + sx) as usize]);
            if v.is_finite() {
                off = off.max((v - coarse(sx, sy)).abs());
            }
        }
    }
    let bound = off + 2.0 * q.max_error + pm.metadata().quantization.max_error + 1.0 / 256.0;
    let worst = hm
        .iter()
        .zip(&hf)
        .map(|(a, b)| (a - b).abs())
        .fold(0f64, f64::max);
    eprintln!("zoom 13 over the base: worst {worst:.3} m against a bound of {bound:.3} m");
    assert!(worst <= bound, "{worst} m apart, more than {bound} m");
    assert!(
        worst > 0.0,
        "the same heights: was the finest level stored there after all?"
    );
}
