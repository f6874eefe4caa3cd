//! Cesium terrain tiles (DECISIONS.md "Cesium terrain";
//! docs/ARCHITECTURE.md#derived-outputs): meshes encoded by the server's
//! quantized-mesh-1.0 writer and read back by the tests crate's own decoder, written from
//! the spec. Every field must come back: vertices, triangles, edge lists, normals,
//! metadata, and a header whose bounds hold for what a client decodes.

#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed test

use glam::DVec3;
use tessera_e2e::Rng;
use tessera_e2e::quantized_mesh::{Decoded, decode};
use tessera_server::cesium::header_geometry::{self, possibly_shrunk};
use tessera_server::cesium::quantized_mesh::{
    Extensions, MeshVertex, QUANTIZED_MAX, TerrainMesh, UNBOUNDED_HORIZON_DISTANCE, encode,
    vertex_order,
};
use tessera_shared::ellipsoid::Ellipsoid;

/// A tile over the western Alps, 0.25° a side.
const ALPS: [f64; 4] = [7.5, 45.0, 7.75, 45.25];

/// The largest angle between a normal and its 8-bit oct code's (header_geometry.rs measures
/// ≈ 0.0165 rad over random directions).
const OCT_TOLERANCE_RAD: f64 = 0.017;

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

fn angle(a: [f64; 3], b: [f64; 3]) -> f64 {
    norm(cross(a, b)).atan2(dot(a, b))
}

/// Whether the segment from `camera` to `point` passes through the open unit ball:
/// plain geometry in the scaled frame, independent of CesiumJS's formulation of the
/// same test.
fn hidden(camera: [f64; 3], point: [f64; 3]) -> bool {
    let d = sub(point, camera);
    let t = (-dot(camera, d) / dot(d, d)).clamp(0.0, 1.0);
    let nearest = [0, 1, 2].map(|i| camera[i] + t * d[i]);
    dot(nearest, nearest) < 1.0
}

/// Encodes, decodes and checks every field against the mesh; returns the decoded tile.
fn round_trip(mesh: &TerrainMesh, rect: [f64; 4], e: &Ellipsoid, ext: &Extensions) -> Decoded {
    let bytes = encode(mesh, rect, e, ext).unwrap();
    let d = decode(&bytes).unwrap();
    let n = mesh.vertices.len();

    // The tile stores the vertices in first-use order: a permutation under which the
    // triangles meet new vertices exactly in turn.
    let order = vertex_order(mesh);
    let mut renumber = vec![u32::MAX; n];
    for (k, &old) in order.iter().enumerate() {
        assert_eq!(
            renumber[old as usize],
            u32::MAX,
            "vertex {old} placed twice"
        );
        renumber[old as usize] = k as u32;
    }
    assert!(renumber.iter().all(|&k| k != u32::MAX));
    let triangles: Vec<[u32; 3]> = mesh
        .triangles
        .iter()
        .map(|t| t.map(|i| renumber[i as usize]))
        .collect();
    let mut seen = 0;
    for &i in triangles.iter().flatten() {
        assert!(i <= seen);
        seen += u32::from(i == seen);
    }

    // Vertices, heights within half a quantization step.
    assert_eq!(d.u.len(), n);
    let positions = d.positions(rect);
    let (lo, hi) = (
        f64::from(d.header.minimum_height),
        f64::from(d.header.maximum_height),
    );
    let half_step = (hi - lo) / f64::from(QUANTIZED_MAX) / 2.0;
    for (k, &old) in order.iter().enumerate() {
        let want = mesh.vertices[old as usize];
        assert_eq!((d.u[k], d.v[k]), (want.u, want.v), "vertex {k}");
        let h = positions[k][2];
        assert!(
            (h - want.height).abs() <= half_step * (1.0 + 1e-9) + 1e-9,
            "vertex {k}: {h} for {}",
            want.height
        );
    }

    // Header heights: f32 bounds, as tight as f32 allows.
    let low = mesh
        .vertices
        .iter()
        .map(|v| v.height)
        .fold(f64::MAX, f64::min);
    let high = mesh
        .vertices
        .iter()
        .map(|v| v.height)
        .fold(f64::MIN, f64::max);
    assert!(lo <= low && f64::from(d.header.minimum_height.next_up()) > low);
    assert!(hi >= high && f64::from(d.header.maximum_height.next_down()) < high);
    if low == high {
        assert!(d.height.iter().all(|&q| q == 0));
    }

    // Triangles and index width.
    assert_eq!(d.triangles, triangles);
    assert_eq!(d.index_bytes, if n > 65_536 { 4 } else { 2 });

    // Edge lists: exactly the vertices on each edge, along it.
    let edge = |on: &dyn Fn(usize) -> bool, along: &dyn Fn(usize) -> u16| {
        let mut list: Vec<u32> = (0..n).filter(|&k| on(k)).map(|k| k as u32).collect();
        list.sort_by_key(|&k| (along(k as usize), k));
        list
    };
    assert_eq!(d.west, edge(&|k| d.u[k] == 0, &|k| d.v[k]));
    assert_eq!(d.south, edge(&|k| d.v[k] == 0, &|k| d.u[k]));
    assert_eq!(d.east, edge(&|k| d.u[k] == QUANTIZED_MAX, &|k| d.v[k]));
    assert_eq!(d.north, edge(&|k| d.v[k] == QUANTIZED_MAX, &|k| d.u[k]));

    // The centre: the rectangle's, at mid height.
    let ecef: Vec<[f64; 3]> = positions
        .iter()
        .map(|p| {
            e.to_ecef(p[0].to_radians(), p[1].to_radians(), p[2])
                .to_array()
        })
        .collect();
    let centre = e
        .to_ecef(
            f64::midpoint(rect[0], rect[2]).to_radians(),
            f64::midpoint(rect[1], rect[3]).to_radians(),
            f64::midpoint(lo, hi),
        )
        .to_array();
    assert!(norm(sub(d.header.center, centre)) < 1e-6);

    // The bounding sphere holds every decoded vertex.
    let (c, r) = (
        d.header.bounding_sphere_center,
        d.header.bounding_sphere_radius,
    );
    for (k, p) in ecef.iter().enumerate() {
        assert!(
            norm(sub(*p, c)) <= r + 1e-6,
            "vertex {k} outside the sphere"
        );
    }

    check_horizon(&d, e, centre, &ecef);
    check_extensions(&d, ext, e, &ecef, &positions);
    d
}

/// The occlusion point is the one the ellipsoid module computes for the decoded
/// vertices; and seen from random viewers, whenever it is hidden so is every vertex.
fn check_horizon(d: &Decoded, e: &Ellipsoid, centre: [f64; 3], ecef: &[[f64; 3]]) {
    let occluder = possibly_shrunk(e, f64::from(d.header.minimum_height));
    let point = d.header.horizon_occlusion_point;
    let vectors: Vec<DVec3> = ecef.iter().map(|&p| p.into()).collect();
    let Some(want) = header_geometry::horizon_occlusion_point(&occluder, centre.into(), &vectors)
        .map(|p| p.to_array())
    else {
        // No finite point bounds the tile: the far point along its direction.
        let axis = occluder.to_scaled_space(centre.into()).to_array();
        assert!(angle(point, axis) < 1e-9, "{point:?}");
        assert!((norm(point) / UNBOUNDED_HORIZON_DISTANCE - 1.0).abs() < 1e-12);
        return;
    };
    assert!(
        norm(sub(point, want)) <= 1e-9 * norm(want),
        "{point:?} {want:?}"
    );
    assert!(norm(point) >= 1.0);

    let scaled: Vec<[f64; 3]> = vectors
        .iter()
        .map(|&p| occluder.to_scaled_space(p).to_array())
        .collect();
    let mut rng = Rng(0x5EED);
    let (mut hidden_views, mut views) = (0, 0);
    while views < 300 {
        let dir = [0; 3].map(|_| rng.uniform() * 2.0 - 1.0);
        if !(1e-3..=1.0).contains(&norm(dir)) {
            continue;
        }
        let dist = 1.0 + 10f64.powf(rng.uniform() * 6.0 - 5.0);
        let camera = dir.map(|c| c / norm(dir) * dist);
        views += 1;
        if hidden(camera, point) {
            hidden_views += 1;
            for (k, q) in scaled.iter().enumerate() {
                assert!(hidden(camera, *q), "vertex {k} visible from {camera:?}");
            }
        }
    }
    assert!(
        hidden_views > 0 && hidden_views < views,
        "{hidden_views} of {views}"
    );
}

/// Normals: what the decoded mesh's triangles make them (area-weighted, ECEF); the
/// metadata: the string given.
fn check_extensions(
    d: &Decoded,
    ext: &Extensions,
    e: &Ellipsoid,
    ecef: &[[f64; 3]],
    positions: &[[f64; 3]],
) {
    let mut ids = Vec::new();
    if ext.normals {
        ids.push(1);
    }
    if ext.metadata.is_some() {
        ids.push(4);
    }
    assert_eq!(d.extensions.iter().map(|x| x.id).collect::<Vec<_>>(), ids);
    assert_eq!(d.metadata, ext.metadata);
    let Some(normals) = &d.normals else {
        assert!(!ext.normals);
        return;
    };
    let mut sums = vec![[0.0; 3]; ecef.len()];
    for t in &d.triangles {
        let [a, b, c] = t.map(|i| ecef[i as usize]);
        let n = cross(sub(b, a), sub(c, a));
        for &i in t {
            sums[i as usize] = [0, 1, 2].map(|k| sums[i as usize][k] + n[k]);
        }
    }
    for (k, (got, sum)) in normals.iter().zip(&sums).enumerate() {
        let want = if norm(*sum) > 0.0 {
            *sum
        } else {
            e.geodetic_surface_normal(positions[k][0].to_radians(), positions[k][1].to_radians())
                .to_array()
        };
        assert!(
            angle(*got, want) <= OCT_TOLERANCE_RAD,
            "vertex {k}: {got:?} for {want:?}"
        );
    }
}

fn vertex(u: u16, v: u16, height: f64) -> MeshVertex {
    MeshVertex { u, v, height }
}

/// Nine boundary and interior vertices fanned around the middle, plus one on the west
/// edge no triangle uses; listed out of first-use order, one below the ellipsoid.
fn hand_made() -> TerrainMesh {
    let vertices = vec![
        vertex(0, 0, 812.25),                         // 0 south-west
        vertex(QUANTIZED_MAX, 0, 1990.0),             // 1 south-east
        vertex(QUANTIZED_MAX, QUANTIZED_MAX, 4478.2), // 2 north-east
        vertex(0, QUANTIZED_MAX, 2001.5),             // 3 north-west
        vertex(16_384, 16_384, 3333.3),               // 4 middle
        vertex(16_384, 0, -35.5),                     // 5 south edge
        vertex(QUANTIZED_MAX, 10_000, 2500.0),        // 6 east edge
        vertex(0, 20_000, 1500.0),                    // 7 west edge
        vertex(10_000, QUANTIZED_MAX, 3900.0),        // 8 north edge
        vertex(0, 5000, 900.0),                       // 9 west edge, unused
    ];
    // Around the boundary counter-clockwise (east along the south edge, north along
    // the east…), each step a triangle with the middle; starting in the north-east.
    let ring = [0, 5, 1, 6, 2, 8, 3, 7];
    let triangles = (0..8)
        .map(|i| [ring[(i + 4) % 8], ring[(i + 5) % 8], 4])
        .collect();
    TerrainMesh {
        vertices,
        triangles,
    }
}

#[test]
fn a_hand_made_mesh_round_trips() {
    let mesh = hand_made();
    let json = r#"{"available":[[{"startX":0,"startY":0,"endX":1,"endY":1}]]}"#;
    let full = Extensions {
        normals: true,
        water_mask: None,
        metadata: Some(json.to_string()),
    };
    let d = round_trip(&mesh, ALPS, &Ellipsoid::WGS84, &full);
    assert_eq!(d.u.len(), 10);
    assert_eq!(d.triangles.len(), 8);
    // The unused vertex goes last and still counts on the west edge.
    assert_eq!((d.u[9], d.v[9]), (0, 5000));
    assert_eq!(d.west.len(), 4);
    assert_eq!(d.metadata.as_deref(), Some(json));
    // Below the ellipsoid, so the occlusion point is against the shrunk one.
    assert!(d.header.minimum_height < 0.0);
    // Counter-clockwise from above makes normals point up, out of the ground.
    let positions = d.positions(ALPS);
    for (k, n) in d.normals.as_ref().unwrap().iter().enumerate() {
        let up = Ellipsoid::WGS84
            .geodetic_surface_normal(positions[k][0].to_radians(), positions[k][1].to_radians())
            .to_array();
        assert!(dot(*n, up) > 0.5, "vertex {k}: {n:?}");
    }

    round_trip(&mesh, ALPS, &Ellipsoid::WGS84, &Extensions::default());
    let normals_only = Extensions {
        normals: true,
        water_mask: None,
        metadata: None,
    };
    let moon = Ellipsoid::sphere(1_737_400.0).unwrap();
    round_trip(&mesh, [57.0, 12.0, 60.0, 15.0], &moon, &normals_only);
}

/// Shuffles in place (Fisher–Yates).
fn shuffle<T>(items: &mut [T], rng: &mut Rng) {
    for i in (1..items.len()).rev() {
        let j = (rng.uniform() * (i + 1) as f64) as usize;
        items.swap(i, j.min(i));
    }
}

/// A `side`×`side` grid of vertices with random heights, its vertices and triangles
/// shuffled and each triangle's corners rotated (keeping its winding).
fn random_grid(side: u32, rng: &mut Rng) -> TerrainMesh {
    let q = |i: u32| (u64::from(i) * u64::from(QUANTIZED_MAX) / u64::from(side - 1)) as u16;
    let mut vertices = Vec::new();
    for j in 0..side {
        for i in 0..side {
            vertices.push(vertex(q(i), q(j), -200.0 + 5000.0 * rng.uniform()));
        }
    }
    let mut slot: Vec<u32> = (0..side * side).collect();
    shuffle(&mut slot, rng);
    let mut shuffled = vertices.clone();
    for (old, &new) in slot.iter().enumerate() {
        shuffled[new as usize] = vertices[old];
    }
    let mut triangles = Vec::new();
    for j in 0..side - 1 {
        for i in 0..side - 1 {
            let k = j * side + i;
            for t in [[k, k + 1, k + side + 1], [k, k + side + 1, k + side]] {
                let r = (rng.uniform() * 3.0) as usize % 3;
                triangles.push([0, 1, 2].map(|c| slot[t[(c + r) % 3] as usize]));
            }
        }
    }
    shuffle(&mut triangles, rng);
    TerrainMesh {
        vertices: shuffled,
        triangles,
    }
}

#[test]
fn a_random_mesh_past_65536_vertices_round_trips_with_32_bit_indices() {
    let mut rng = Rng(15);
    // 257² = 66049 vertices: 32-bit indices after 2 bytes of padding.
    let mesh = random_grid(257, &mut rng);
    let ext = Extensions {
        normals: true,
        water_mask: None,
        metadata: Some(r#"{"tile":"random"}"#.to_string()),
    };
    let d = round_trip(&mesh, [-120.0, 35.0, -119.0, 36.0], &Ellipsoid::WGS84, &ext);
    assert_eq!(d.index_bytes, 4);
    assert_eq!(d.west.len(), 257);

    // 256² = 65536 is the most that keeps 16-bit indices.
    let mesh = random_grid(256, &mut rng);
    let d = round_trip(&mesh, [140.0, -40.0, 141.0, -39.0], &Ellipsoid::WGS84, &ext);
    assert_eq!(d.index_bytes, 2);
}

#[test]
fn flat_and_whole_hemisphere_tiles_round_trip() {
    let mut mesh = hand_made();
    for v in &mut mesh.vertices {
        v.height = 120.0;
    }
    let d = round_trip(&mesh, ALPS, &Ellipsoid::WGS84, &Extensions::default());
    assert_eq!(d.header.minimum_height, d.header.maximum_height);

    // Level 0 of the grid: no finite occlusion point bounds a hemisphere.
    let mesh = random_grid(9, &mut Rng(2));
    let ext = Extensions {
        normals: true,
        water_mask: None,
        metadata: None,
    };
    round_trip(&mesh, [-180.0, -90.0, 0.0, 90.0], &Ellipsoid::WGS84, &ext);
}

/// Every strict prefix of a tile fails to decode, except those ending exactly where
/// an extension does (extensions are optional, so those are whole tiles with fewer).
#[test]
fn truncated_tiles_are_errors() {
    let mesh = hand_made();
    for ext in [
        Extensions::default(),
        Extensions {
            normals: true,
            water_mask: None,
            metadata: Some("{}".to_string()),
        },
    ] {
        let bytes = encode(&mesh, ALPS, &Ellipsoid::WGS84, &ext).unwrap();
        let full = decode(&bytes).unwrap();
        let mut ends = vec![bytes.len()];
        for x in full.extensions.iter().rev() {
            let last = *ends.last().unwrap();
            ends.push(last - 5 - x.data.len());
        }
        for len in 0..bytes.len() {
            match decode(&bytes[..len]) {
                Err(_) => assert!(!ends.contains(&len), "a whole tile at {len} rejected"),
                Ok(d) => {
                    let kept = ends.iter().position(|&e| e == len);
                    assert!(
                        kept.is_some(),
                        "a tile cut at {len} of {} decoded",
                        bytes.len()
                    );
                    let kept = full.extensions.len() - kept.unwrap();
                    assert_eq!(d.extensions, full.extensions[..kept]);
                    assert_eq!(d.triangles, full.triangles);
                }
            }
        }
    }
}

/// Damaged or random bytes decode to something or to an error, never a panic.
#[test]
fn damaged_tiles_never_panic() {
    let ext = Extensions {
        normals: true,
        water_mask: None,
        metadata: Some("{\"a\":1}".to_string()),
    };
    let bytes = encode(&hand_made(), ALPS, &Ellipsoid::WGS84, &ext).unwrap();
    let mut rng = Rng(99);
    for _ in 0..5000 {
        let mut bad = bytes.clone();
        let flips = 1 + (rng.uniform() * 4.0) as usize;
        for _ in 0..flips {
            let at = (rng.uniform() * bad.len() as f64) as usize % bad.len();
            bad[at] = (rng.uniform() * 256.0) as u8;
        }
        let _ = decode(&bad);
    }
    for len in [0, 1, 88, 92, 100, 300] {
        let noise: Vec<u8> = (0..len).map(|_| (rng.uniform() * 256.0) as u8).collect();
        let _ = decode(&noise);
    }
    // Counts that would overflow a length computation.
    let mut huge = bytes.clone();
    huge[88..92].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(decode(&huge).is_err());
}
