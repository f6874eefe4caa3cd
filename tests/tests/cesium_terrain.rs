//! Cesium terrain on real DEMs (DECISIONS.md "Cesium terrain"): every tile checked by
//! brute force against every finest sample it covers, and neighbouring tiles' shared
//! edges.
//!
//! - **Error.** Each tile is meshed, encoded and decoded with our own decoder
//!   (`tessera_e2e::quantized_mesh`, written from the spec); the decoded surface
//!   (linear in longitude and latitude within each triangle, as the format defines
//!   it) must be within CesiumJS's geometric error for the zoom of every stored
//!   finest sample in the tile — filled voids included, heights on the ellipsoid
//!   (EGM96 added for SRTM through the PROJ-checked geoid grid). The tile must also
//!   cover every sample: no holes.
//! - **Edges.** Two tiles side by side at one zoom have the same edge points: the
//!   same latitudes (longitudes) and bit-identical heights before quantization.
//! - **Aprons.** Beyond the data a tile is flat: each vertex there repeats a side
//!   point's height straight across.
//!
//! N46E008 (3″ SRTM, 1201², EGM96) is built with 128-cell tiles so that coarse zooms
//! mesh coarse levels (measured against their north-west triangulation plus the error
//! tables); the moon 4096² is georeferenced on its 1737.4 km sphere with
//! `--crs/--bounds`. Zooms with more tiles than [`PER_ZOOM`] are checked on a seeded
//! sample of that many.

#![allow(clippy::unwrap_used)]

use std::collections::HashMap;
use tessera_e2e::Rng;
use tessera_e2e::quantized_mesh::decode;
use tessera_e2e::terrain_check::{SampleGrid, edge_points, egm96_or_skip};
use tessera_server::builder::{BuildOptions, build};
use tessera_server::cesium::quantized_mesh::{Extensions, TerrainMesh, encode};
use tessera_server::cesium::terrain::{PyramidLevels, Terrain};
use tessera_server::cesium::tiling::CesiumTile;
use tessera_server::geoid::Geoid;
use tessera_shared::{FileSource, Pyramid, VerticalDatum, testdata};

/// Tiles checked per zoom at most.
const PER_ZOOM: usize = 48;

struct Case {
    name: &'static str,
    pyramid: Pyramid<FileSource>,
    terrain: Terrain,
    geoid: Option<std::sync::Arc<Geoid>>,
    _dir: tempfile::TempDir,
}

fn built(
    name: &'static str,
    file: &str,
    opts: &BuildOptions,
    geoid: Option<std::sync::Arc<Geoid>>,
) -> Option<Case> {
    let path = testdata::dem_or_skip(file)?;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("dem.tess");
    build(path.to_str().unwrap(), &out, opts).unwrap();
    let pyramid = Pyramid::open_file(&out).unwrap();
    let terrain = Terrain::new(pyramid.metadata(), geoid.clone()).unwrap();
    Some(Case {
        name,
        pyramid,
        terrain,
        geoid,
        _dir: dir,
    })
}

fn srtm() -> Option<Case> {
    let geoid = egm96_or_skip()?;
    let opts = BuildOptions {
        tile_size: 128,
        vertical_datum: Some(VerticalDatum::Egm96),
        ..BuildOptions::default()
    };
    built("N46E008", "N46E008.tif", &opts, Some(geoid))
}

fn moon() -> Option<Case> {
    let opts = BuildOptions {
        tile_size: 256,
        offset: -10000.0,
        vertical_datum: Some(VerticalDatum::Ellipsoid),
        crs: Some("+proj=longlat +R=1737400 +no_defs".into()),
        bounds: Some(
            tessera_server::ingest::assign::Bounds::new(51.0, 8.992_187_5, 67.0, 24.992_187_5)
                .unwrap(),
        ),
        ..BuildOptions::default()
    };
    built("moon 4096²", "moon_crisium_gld100_4096.png", &opts, None)
}

/// The tiles of zoom `z` to check: all, or a seeded sample of [`PER_ZOOM`].
fn tiles(case: &Case, z: u8, rng: &mut Rng) -> Vec<CesiumTile> {
    let Some([x0, y0, x1, y1]) = case.terrain.available(z) else {
        return Vec::new();
    };
    let all: Vec<CesiumTile> = (y0..=y1)
        .flat_map(|y| (x0..=x1).map(move |x| CesiumTile::new(z, x, y).unwrap()))
        .collect();
    if all.len() <= PER_ZOOM {
        return all;
    }
    (0..PER_ZOOM)
        .map(|_| all[(rng.uniform() * all.len() as f64) as usize])
        .collect()
}

/// The decoded tile's worst error over the samples it covers; it must cover them all.
fn worst_error(
    case: &Case,
    grid: &SampleGrid,
    tile: CesiumTile,
    mesh: &TerrainMesh,
) -> (f64, usize) {
    let rect = tile.rect();
    let ext = Extensions {
        normals: true,
        water_mask: None,
        metadata: None,
    };
    let bytes = encode(mesh, rect, &case.terrain.ellipsoid, &ext).unwrap();
    let d = decode(&bytes).unwrap();
    let check = grid.worst_error(rect, &d.positions(rect), &d.triangles);
    assert_eq!(
        check.holes, 0,
        "{}: {tile}: {} of {} samples not covered",
        case.name, check.holes, check.samples
    );
    (check.worst, check.samples)
}

fn brute_force(case: &Case) {
    let grid = SampleGrid::of(&case.pyramid, case.geoid.as_deref());
    let levels = PyramidLevels::new(&case.pyramid);
    let mut rng = Rng(15);
    for z in 0..=case.terrain.max_zoom {
        let plan = case.terrain.plan(z, &levels).unwrap();
        let (mut worst, mut samples, mut tris, mut n) = (0.0_f64, 0, 0, 0);
        for tile in tiles(case, z, &mut rng) {
            let mesh = case.terrain.mesh(tile, &levels).unwrap();
            let (e, s) = worst_error(case, &grid, tile, &mesh);
            assert!(
                e <= plan.geometric_error,
                "{}: {tile}: error {e:.3} m > geometric error {:.3} m (level {}, tau {:.3})",
                case.name,
                plan.geometric_error,
                plan.level.get(),
                plan.tau
            );
            worst = worst.max(e / plan.geometric_error);
            samples += s;
            tris += mesh.triangles.len();
            n += 1;
        }
        eprintln!(
            "{} zoom {z:2}: {n:3} tiles, level {}, square {:3}, worst error {:.3} of ε = {:.2} m, {} samples, {:.0} triangles/tile",
            case.name,
            plan.level.get(),
            plan.square,
            worst,
            plan.geometric_error,
            samples,
            tris as f64 / f64::from(n.max(1))
        );
    }
}

fn shared_edges(case: &Case) {
    let levels = PyramidLevels::new(&case.pyramid);
    let mut rng = Rng(150);
    let mut pairs = 0;
    for z in 0..=case.terrain.max_zoom {
        let mut meshes: HashMap<CesiumTile, TerrainMesh> = HashMap::new();
        let mut get = |t: CesiumTile| -> TerrainMesh {
            meshes
                .entry(t)
                .or_insert_with(|| case.terrain.mesh(t, &levels).unwrap())
                .clone()
        };
        for a in tiles(case, z, &mut rng) {
            for (dx, dy) in [(1, 0), (0, 1)] {
                let Some(b) = CesiumTile::new(z, a.x + dx, a.y + dy) else {
                    continue;
                };
                if !case.terrain.is_available(b) {
                    continue;
                }
                let (ma, mb) = (get(a), get(b));
                let (ea, eb) = if dx == 1 {
                    (
                        edge_points(&ma, Some(32767), None),
                        edge_points(&mb, Some(0), None),
                    )
                } else {
                    (
                        edge_points(&ma, None, Some(32767)),
                        edge_points(&mb, None, Some(0)),
                    )
                };
                assert!(!ea.is_empty(), "{}: {a} has no edge vertices", case.name);
                assert_eq!(
                    ea, eb,
                    "{}: {a} and {b} differ on their shared edge",
                    case.name
                );
                pairs += 1;
            }
        }
    }
    eprintln!(
        "{}: {pairs} neighbour pairs share their edges exactly",
        case.name
    );
    assert!(pairs > 50, "too few pairs checked: {pairs}");
}

/// The mesh's height at `(u, v)` (its triangles, linear in `u` and `v`), if a
/// triangle holds the point.
fn mesh_at(mesh: &TerrainMesh, u: f64, v: f64) -> Option<f64> {
    mesh.triangles.iter().find_map(|t| {
        let [a, b, c] = t.map(|i| &mesh.vertices[i as usize]);
        let (ax, ay, bx, by, cx, cy) = (
            f64::from(a.u),
            f64::from(a.v),
            f64::from(b.u),
            f64::from(b.v),
            f64::from(c.u),
            f64::from(c.v),
        );
        let det = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay);
        let l1 = ((u - ax) * (cy - ay) - (cx - ax) * (v - ay)) / det;
        let l2 = ((bx - ax) * (v - ay) - (u - ax) * (by - ay)) / det;
        let l0 = 1.0 - l1 - l2;
        (l0 >= -1e-9 && l1 >= -1e-9 && l2 >= -1e-9)
            .then_some(l0 * a.height + l1 * b.height + l2 * c.height)
    })
}

/// Beyond the data a tile is a flat apron: at every point outside the data's
/// rectangle the surface has the height of the data's side straight across from it
/// (the nearest point of the rectangle: same latitude beyond the west or east side,
/// same longitude beyond the north or south, the data's corner beyond a corner). A
/// fill that ramps to sea level or fans out from the tile's corners fails.
fn flat_aprons(case: &Case) {
    let levels = PyramidLevels::new(&case.pyramid);
    let [bw, bs, be, bn] = case.terrain.bounds;
    let (mut edge_tiles, mut points) = (0, 0);
    for z in 3..=case.terrain.max_zoom.min(13) {
        let Some([x0, y0, x1, y1]) = case.terrain.available(z) else {
            continue;
        };
        // Tiles along the data's edge: corners and middles of the available range.
        let ring = [
            (x0, y0),
            (x1, y1),
            (x0, y1),
            (x1, y0),
            (x0.midpoint(x1), y0),
            (x0, y0.midpoint(y1)),
        ];
        for (x, y) in ring {
            let tile = CesiumTile::new(z, x, y).unwrap();
            let [w, s, e, n] = tile.rect();
            let u = |lon: f64| (lon - w) / (e - w) * 32767.0;
            let v = |lat: f64| (lat - s) / (n - s) * 32767.0;
            let (dw, de, ds, dn) = (u(bw), u(be), v(bs), v(bn));
            if !(dw > 2.0 || de < 32765.0 || ds > 2.0 || dn < 32765.0) {
                continue; // the data covers the tile
            }
            edge_tiles += 1;
            let mesh = case.terrain.mesh(tile, &levels).unwrap();
            for j in 0..=64 {
                for i in 0..=64 {
                    let (pu, pv) = (f64::from(i) * 32767.0 / 64.0, f64::from(j) * 32767.0 / 64.0);
                    let beyond = pu < dw - 2.0 || pu > de + 2.0 || pv < ds - 2.0 || pv > dn + 2.0;
                    if !beyond {
                        continue;
                    }
                    // On the data's side, straight across (the side's points are
                    // quantized to the nearest unit, as the apron's are).
                    let (qu, qv) = (
                        pu.clamp(dw.round(), de.round()),
                        pv.clamp(ds.round(), dn.round()),
                    );
                    let (Some(h), Some(want)) = (mesh_at(&mesh, pu, pv), mesh_at(&mesh, qu, qv))
                    else {
                        panic!(
                            "{}: {tile}: no triangle at ({pu}, {pv}) or ({qu}, {qv})",
                            case.name
                        );
                    };
                    assert!(
                        (h - want).abs() <= 1e-3,
                        "{}: {tile}: {h:.3} m at ({pu:.0}, {pv:.0}) beyond the data, {want:.3} m straight across",
                        case.name
                    );
                    points += 1;
                }
            }
        }
    }
    eprintln!(
        "{}: {edge_tiles} tiles along the data's edge, {points} points beyond it, flat",
        case.name
    );
    assert!(
        edge_tiles >= 10 && points > 1000,
        "too few checked: {edge_tiles} tiles, {points} points"
    );
}

#[test]
fn srtm_tiles_beyond_the_data_are_flat_aprons() {
    let Some(c) = srtm() else { return };
    flat_aprons(&c);
}

#[test]
fn moon_tiles_beyond_the_data_are_flat_aprons() {
    let Some(c) = moon() else { return };
    flat_aprons(&c);
}

#[test]
fn srtm_tiles_are_within_cesiums_geometric_error_everywhere() {
    let Some(c) = srtm() else { return };
    brute_force(&c);
}

#[test]
fn moon_tiles_are_within_cesiums_geometric_error_everywhere() {
    let Some(c) = moon() else { return };
    assert_eq!(c.terrain.ellipsoid.radii().to_array(), [1_737_400.0; 3]);
    brute_force(&c);
}

#[test]
fn srtm_neighbours_share_their_edge_vertices() {
    let Some(c) = srtm() else { return };
    shared_edges(&c);
}

#[test]
fn moon_neighbours_share_their_edge_vertices() {
    let Some(c) = moon() else { return };
    shared_edges(&c);
}

#[test]
fn layer_zooms_follow_the_data() {
    // N46E008: 1/1200° samples, so tiles of ≤ 4 samples (180/2^z ≤ 1/300°) at zoom 16.
    let Some(c) = srtm() else { return };
    assert_eq!(c.terrain.max_zoom, 16);
    assert_eq!(c.terrain.available(0), Some([1, 0, 1, 0]));
    // Zoom 8: 0.703125° tiles; the sample centres span 8..9° E, 46..47° N.
    assert_eq!(c.terrain.available(8), Some([267, 193, 268, 194]));
}
