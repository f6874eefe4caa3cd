//! Cesium terrain for data across the antimeridian and up to the poles
//! (DECISIONS.md "Cesium terrain"): a real SRTM tile moved by GDAL to 179.5° E –
//! 180.5° E, and a global grid in EPSG:4326 whose samples reach ±90° and ±180°. Each
//! tile is checked as tests/cesium_terrain.rs checks them: decoded with our own
//! decoder, within CesiumJS's geometric error of every finest sample it covers, with
//! no holes; and the two tiles that meet at the antimeridian share their edge.

#![allow(clippy::unwrap_used)]

use std::path::Path;
use std::process::Command;
use tessera_e2e::Rng;
use tessera_e2e::quantized_mesh::decode;
use tessera_e2e::terrain_check::{SampleGrid, edge_points, egm96_or_skip};
use tessera_server::builder::{BuildOptions, build};
use tessera_server::cesium::quantized_mesh::{Extensions, TerrainMesh, encode};
use tessera_server::cesium::terrain::{PyramidLevels, Terrain};
use tessera_server::cesium::tiling::CesiumTile;
use tessera_server::geoid::Geoid;
use tessera_shared::{FileSource, Pyramid, VerticalDatum, testdata};

/// Whether GDAL's command-line tools run (required in CI).
fn gdal() -> bool {
    let ok = Command::new("gdal_translate")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        ok || std::env::var_os("CI").is_none(),
        "no gdal_translate (apt-get install gdal-bin)"
    );
    if !ok {
        eprintln!("SKIPPED: no gdal_translate (apt-get install gdal-bin)");
    }
    ok
}

fn gdal_translate(args: &[&str], from: &Path, to: &Path) {
    let out = Command::new("gdal_translate")
        .arg("-q")
        .args(args)
        .arg(from)
        .arg(to)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "gdal_translate: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

struct Case {
    pyramid: Pyramid<FileSource>,
    terrain: Terrain,
    geoid: Option<std::sync::Arc<Geoid>>,
    _dir: tempfile::TempDir,
}

fn built(
    dir: tempfile::TempDir,
    input: &Path,
    opts: &BuildOptions,
    geoid: Option<std::sync::Arc<Geoid>>,
) -> Case {
    let out = dir.path().join("dem.tess");
    build(input.to_str().unwrap(), &out, opts).unwrap();
    let pyramid = Pyramid::open_file(&out).unwrap();
    let terrain = Terrain::new(pyramid.metadata(), geoid.clone()).unwrap();
    Case {
        pyramid,
        terrain,
        geoid,
        _dir: dir,
    }
}

/// N46E008 (3″ SRTM, EGM96) with its corners moved to 179.5° E – 180.5° E.
fn across_the_antimeridian() -> Option<Case> {
    let src = testdata::dem_or_skip("N46E008.tif")?;
    let geoid = egm96_or_skip()?;
    if !gdal() {
        return None;
    }
    let dir = tempfile::tempdir().unwrap();
    let moved = dir.path().join("moved.tif");
    // Half a 3″ pixel beyond 179.5 and 180.5: the samples' centres span them exactly.
    let h = 0.5 / 1200.0;
    let ullr = [179.5 - h, 47.0 + h, 180.5 + h, 46.0 - h].map(|v| v.to_string());
    let args: Vec<&str> = std::iter::once("-a_ullr")
        .chain(ullr.iter().map(String::as_str))
        .collect();
    gdal_translate(&args, &src, &moved);
    let opts = BuildOptions {
        tile_size: 128,
        vertical_datum: Some(VerticalDatum::Egm96),
        ..BuildOptions::default()
    };
    Some(built(dir, &moved, &opts, Some(geoid)))
}

/// The moon 4096² resampled by GDAL to a global 0.25° grid whose sample centres
/// reach both poles and both sides of the antimeridian (1441 × 721).
fn global() -> Option<Case> {
    let src = testdata::dem_or_skip("moon_crisium_gld100_4096.png")?;
    if !gdal() {
        return None;
    }
    let dir = tempfile::tempdir().unwrap();
    let tif = dir.path().join("global.tif");
    let args = [
        "-outsize",
        "1441",
        "721",
        "-r",
        "bilinear",
        "-a_srs",
        "EPSG:4326",
        "-a_ullr",
        "-180.125",
        "90.125",
        "180.125",
        "-90.125",
    ];
    gdal_translate(&args, &src, &tif);
    let opts = BuildOptions {
        tile_size: 128,
        offset: -10000.0,
        vertical_datum: Some(VerticalDatum::Ellipsoid),
        ..BuildOptions::default()
    };
    Some(built(dir, &tif, &opts, None))
}

/// Meshes and checks `tile` against every finest sample it covers (in the data's
/// longitudes: `frame_rect`), returning its mesh.
fn checked(
    case: &Case,
    grid: &SampleGrid,
    tile: CesiumTile,
    levels: &PyramidLevels<'_, FileSource>,
) -> TerrainMesh {
    let mesh = case.terrain.mesh(tile, levels).unwrap();
    let plan = case.terrain.plan(tile.z, levels).unwrap();
    let ext = Extensions::default();
    let bytes = encode(&mesh, tile.rect(), &case.terrain.ellipsoid, &ext).unwrap();
    let d = decode(&bytes).unwrap();
    let rect = case.terrain.frame_rect(tile);
    let check = grid.worst_error(rect, &d.positions(rect), &d.triangles);
    assert_eq!(
        check.holes, 0,
        "{tile}: {} of {} samples not covered",
        check.holes, check.samples
    );
    assert!(
        check.worst <= plan.geometric_error,
        "{tile}: error {:.3} m > ε {:.3} m",
        check.worst,
        plan.geometric_error
    );
    assert!(
        mesh.vertices.iter().all(|v| v.height.is_finite()),
        "{tile}: a height is not finite"
    );
    mesh
}

#[test]
fn srtm_across_the_antimeridian_is_whole_and_seamless() {
    let Some(case) = across_the_antimeridian() else {
        return;
    };
    let [w, _, e, _] = case.terrain.bounds;
    assert!(
        (w - 179.5).abs() < 1e-9 && (e - 180.5).abs() < 1e-9,
        "bounds {:?}",
        case.terrain.bounds
    );
    let grid = SampleGrid::of(&case.pyramid, case.geoid.as_deref());
    let levels = PyramidLevels::new(&case.pyramid);
    let mut rng = Rng(7);
    let (mut checked_tiles, mut seams) = (0, 0);
    for z in [5, 8, 10, 12] {
        let ranges = case.terrain.available_ranges(z);
        assert_eq!(
            ranges.len(),
            2,
            "zoom {z}: tiles on both sides of the antimeridian: {ranges:?}"
        );
        let last = (2u32 << z) - 1;
        assert_eq!(ranges[0][2], last, "zoom {z}: the west part ends at 180°");
        assert_eq!(ranges[1][0], 0, "zoom {z}: the east part starts at −180°");
        for [x0, y0, x1, y1] in ranges {
            for _ in 0..6 {
                let x = x0 + (rng.uniform() * f64::from(x1 - x0 + 1)) as u32;
                let y = y0 + (rng.uniform() * f64::from(y1 - y0 + 1)) as u32;
                checked(&case, &grid, CesiumTile::new(z, x, y).unwrap(), &levels);
                checked_tiles += 1;
            }
        }
        // The two tiles that meet at the antimeridian, in every row of data.
        let [_, y0, _, y1] = case.terrain.available(z).unwrap();
        for y in y0..=y1 {
            let a = checked(&case, &grid, CesiumTile::new(z, last, y).unwrap(), &levels);
            let b = checked(&case, &grid, CesiumTile::new(z, 0, y).unwrap(), &levels);
            let (ea, eb) = (
                edge_points(&a, Some(32767), None),
                edge_points(&b, Some(0), None),
            );
            assert!(ea.len() >= 2, "zoom {z} row {y}: no edge points");
            assert_eq!(
                ea, eb,
                "zoom {z} row {y}: the antimeridian's two sides differ"
            );
            seams += 1;
        }
    }
    eprintln!(
        "across the antimeridian: {checked_tiles} tiles within ε, {seams} seams shared exactly"
    );
}

#[test]
fn a_global_grid_reaches_both_poles() {
    let Some(case) = global() else { return };
    assert_eq!(case.terrain.bounds, [-180.0, -90.0, 180.0, 90.0]);
    let grid = SampleGrid::of(&case.pyramid, None);
    let levels = PyramidLevels::new(&case.pyramid);
    let mut polar = 0;
    for z in 0..=3u8 {
        let ranges = case.terrain.available_ranges(z);
        assert_eq!(
            ranges,
            vec![[0, 0, (2u32 << z) - 1, (1u32 << z) - 1]],
            "zoom {z}: the whole globe"
        );
        for y in [0, (1u32 << z) - 1] {
            for x in 0..(2u32 << z) {
                let mesh = checked(&case, &grid, CesiumTile::new(z, x, y).unwrap(), &levels);
                polar += 1;
                // The data's edge at ±180° is the tile's: its points are on the border
                // from corner to corner (where the skirts hang).
                for u in [0, 32767] {
                    let edge = edge_points(&mesh, Some(u), None);
                    let ends = edge.first().map(|p| p.0) == Some(0)
                        && edge.last().map(|p| p.0) == Some(32767);
                    assert!(ends, "zoom {z} ({x}, {y}): edge u = {u} is {edge:?}");
                }
            }
        }
    }
    eprintln!("global grid: {polar} polar tiles within ε, covering the samples up to ±90°");
}
