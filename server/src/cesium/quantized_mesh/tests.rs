//! Tests of the quantized-mesh encoder: tiles encoded and read back.

use super::input::f32_at_most;
use super::*;

const RECT: [f64; 4] = [7.5, 45.0, 7.75, 45.25];

fn vertex(u: u16, v: u16, height: f64) -> MeshVertex {
    MeshVertex { u, v, height }
}

/// A `side`×`side` grid of vertices over the tile, two triangles a cell.
fn grid(side: u32, height: impl Fn(u32, u32) -> f64) -> TerrainMesh {
    let q = |i: u32| (u64::from(i) * u64::from(QUANTIZED_MAX) / u64::from(side - 1)) as u16;
    let mut vertices = Vec::new();
    for j in 0..side {
        for i in 0..side {
            vertices.push(vertex(q(i), q(j), height(i, j)));
        }
    }
    let mut triangles = Vec::new();
    for j in 0..side - 1 {
        for i in 0..side - 1 {
            let k = j * side + i;
            triangles.push([k, k + 1, k + side + 1]);
            triangles.push([k, k + side + 1, k + side]);
        }
    }
    TerrainMesh {
        vertices,
        triangles,
    }
}

/// The parts of a tile these tests read back: header numbers and decoded vertices.
struct Read {
    min: f32,
    max: f32,
    sphere: ([f64; 3], f64),
    u: Vec<u16>,
    v: Vec<u16>,
    h: Vec<u16>,
    /// Where the vertex data ends.
    end: usize,
}

fn read(bytes: &[u8]) -> Read {
    let f64_at = |o: usize| f64::from_le_bytes(bytes[o..o + 8].try_into().unwrap());
    let f32_at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    let n = u32::from_le_bytes(bytes[88..92].try_into().unwrap()) as usize;
    let array = |a: usize| {
        let mut value = 0i32;
        (0..n)
            .map(|i| {
                let o = 92 + 2 * (a * n + i);
                let z = i32::from(u16::from_le_bytes([bytes[o], bytes[o + 1]]));
                value += (z >> 1) ^ -(z & 1);
                value as u16
            })
            .collect::<Vec<u16>>()
    };
    Read {
        min: f32_at(24),
        max: f32_at(28),
        sphere: ([f64_at(32), f64_at(40), f64_at(48)], f64_at(56)),
        u: array(0),
        v: array(1),
        h: array(2),
        end: 92 + 6 * n,
    }
}

#[test]
fn header_bounds_contain_every_decoded_vertex() {
    let mesh = grid(5, |i, j| {
        -12.3 + f64::from(i * 37 % 11) * 101.7 + f64::from(j) * 0.01
    });
    let e = Ellipsoid::WGS84;
    let bytes = encode(&mesh, RECT, &e, &Extensions::default()).unwrap();
    let r = read(&bytes);
    let order = vertex_order(&mesh);
    let (lo, hi) = (f64::from(r.min), f64::from(r.max));
    let step = (hi - lo) / f64::from(QUANTIZED_MAX);
    let rect = Rect::new(RECT).unwrap();
    for (k, &old) in order.iter().enumerate() {
        let want = mesh.vertices[old as usize];
        assert_eq!((r.u[k], r.v[k]), (want.u, want.v));
        assert!(lo <= want.height && want.height <= hi);
        let h = lo + f64::from(r.h[k]) * step;
        assert!(
            (h - want.height).abs() <= step / 2.0 * (1.0 + 1e-9),
            "vertex {k}"
        );
        let (lon, lat) = rect.lon_lat(r.u[k], r.v[k]);
        let p = e.to_ecef(lon.to_radians(), lat.to_radians(), h);
        let c = r.sphere.0;
        let d = ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt();
        assert!(
            d <= r.sphere.1 * (1.0 + 1e-12),
            "vertex {k} outside the sphere"
        );
    }
    // The f32 bounds are the tightest that contain the heights.
    assert_eq!(r.min, f32_at_most(-12.3));
    assert!(f64::from(r.min) <= -12.3 && f64::from(r.min.next_up()) > -12.3);
    let top = mesh
        .vertices
        .iter()
        .map(|v| v.height)
        .fold(f64::MIN, f64::max);
    assert!(f64::from(r.max) >= top && f64::from(r.max.next_down()) < top);
}

#[test]
fn a_flat_tile_stores_zero_heights() {
    let mesh = grid(3, |_, _| 250.0);
    let bytes = encode(&mesh, RECT, &Ellipsoid::WGS84, &Extensions::default()).unwrap();
    let r = read(&bytes);
    assert_eq!((r.min, r.max), (250.0, 250.0));
    assert!(r.h.iter().all(|&h| h == 0));
}

#[test]
fn high_water_mark_codes_a_hand_made_list() {
    let indices = [0, 1, 2, 2, 1, 3, 0, 2, 4];
    let codes = high_water_mark(indices.into_iter());
    assert_eq!(codes, [0, 0, 0, 1, 2, 0, 4, 2, 0]);
    // The spec's decoder gives the list back.
    let mut highest = 0;
    let decoded: Vec<u32> = codes
        .iter()
        .map(|&c| {
            let i = highest - c;
            if c == 0 {
                highest += 1;
            }
            i
        })
        .collect();
    assert_eq!(decoded, indices);

    // Vertices the triangles meet out of order are renumbered into first-use order,
    // and a vertex no triangle uses goes last; the tile holds those codes.
    let mesh = TerrainMesh {
        vertices: (0..6)
            .map(|i| vertex(i * 100, i * 50, f64::from(i)))
            .collect(),
        triangles: vec![[3, 0, 5], [5, 0, 1], [3, 5, 2]],
    };
    assert_eq!(vertex_order(&mesh), [3, 0, 5, 1, 2, 4]);
    let bytes = encode(&mesh, RECT, &Ellipsoid::WGS84, &Extensions::default()).unwrap();
    let at = read(&bytes).end; // 16-bit data, already 2-aligned
    assert_eq!(at % 2, 0);
    assert_eq!(u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()), 3);
    let stored: Vec<u16> = (0..9)
        .map(|i| u16::from_le_bytes([bytes[at + 4 + 2 * i], bytes[at + 5 + 2 * i]]))
        .collect();
    // Renumbered: [0, 1, 2], [2, 1, 3], [0, 2, 4].
    assert_eq!(stored, [0, 0, 0, 1, 2, 0, 4, 2, 0]);
}

/// Bytes of a tile without extensions for `n` vertices, `t` triangles and `e` edge
/// vertices with `w`-byte indices.
fn tile_len(n: usize, t: usize, e: usize, w: usize) -> usize {
    let vertex_end = HEADER_BYTES + 4 + 6 * n;
    vertex_end.next_multiple_of(w) + 4 + 3 * t * w + 16 + e * w
}

#[test]
fn indices_go_32_bit_past_65536_vertices() {
    // 257² = 66049 vertices: 32-bit, and an odd count, so 2 bytes of padding.
    let mesh = grid(257, |i, j| f64::from(i + j));
    let n = mesh.vertices.len();
    let bytes = encode(&mesh, RECT, &Ellipsoid::WGS84, &Extensions::default()).unwrap();
    let edge = 4 * 257; // corners are on two edges each
    assert_eq!(bytes.len(), tile_len(n, mesh.triangles.len(), edge, 4));
    let r = read(&bytes);
    assert_eq!(r.end % 4, 2);
    assert_eq!(bytes[r.end..r.end + 2], [0, 0]);
    let at = r.end + 2;
    let t = u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    assert_eq!(t as usize, mesh.triangles.len());
    // The first triangle's three new vertices: codes 0, 0, 0 as 32-bit words.
    assert_eq!(bytes[at + 4..at + 16], [0; 12]);

    // 256² = 65536 vertices is still 16-bit.
    let mesh = grid(256, |i, j| f64::from(i * j));
    let bytes = encode(&mesh, RECT, &Ellipsoid::WGS84, &Extensions::default()).unwrap();
    assert_eq!(
        bytes.len(),
        tile_len(65_536, mesh.triangles.len(), 4 * 256, 2)
    );
}

#[test]
fn a_16_bit_code_that_does_not_fit_is_an_error() {
    // 65536 vertices in a strip, then a triangle back at the first.
    let vertices: Vec<MeshVertex> = (0..65_536u32)
        .map(|i| vertex((i % 32_768) as u16, (i / 32_768) as u16, 0.0))
        .collect();
    let mut triangles: Vec<[u32; 3]> = (0..65_534).map(|i| [i, i + 1, i + 2]).collect();
    triangles.push([65_535, 0, 1]);
    let mesh = TerrainMesh {
        vertices,
        triangles,
    };
    let err = encode(&mesh, RECT, &Ellipsoid::WGS84, &Extensions::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("past 16 bits"), "{err}");
}

#[test]
fn bad_input_is_an_error() {
    let e = Ellipsoid::WGS84;
    let none = Extensions::default();
    let mesh = grid(2, |_, _| 0.0);
    let empty = TerrainMesh::default();
    assert!(
        encode(&empty, RECT, &e, &none)
            .unwrap_err()
            .to_string()
            .contains("at least one vertex")
    );
    let mut out_of_range = mesh.clone();
    out_of_range.triangles.push([0, 1, 4]);
    assert!(
        encode(&out_of_range, RECT, &e, &none)
            .unwrap_err()
            .to_string()
            .contains("vertex 4 of 4")
    );
    for rect in [
        [7.0, 45.0, 7.0, 46.0],
        [8.0, 45.0, 7.0, 46.0],
        [7.0, 46.0, 8.0, 46.0],
        [f64::NAN, 45.0, 8.0, 46.0],
        [7.0, 45.0, f64::INFINITY, 46.0],
        [-180.0, -91.0, 0.0, 0.0],
        [-180.0, 0.0, 181.0, 10.0],
    ] {
        assert!(
            encode(&mesh, rect, &e, &none)
                .unwrap_err()
                .to_string()
                .contains("degenerate"),
            "{rect:?}"
        );
    }
    let mut past = mesh.clone();
    past.vertices[1].u = 32_768;
    assert!(encode(&past, RECT, &e, &none).is_err());
    let mut nan = mesh.clone();
    nan.vertices[2].height = f64::NAN;
    assert!(encode(&nan, RECT, &e, &none).is_err());
    let mut huge = mesh.clone();
    huge.vertices[2].height = 1e300;
    assert!(encode(&huge, RECT, &e, &none).is_err());
    for json in ["[1, 2]", "{\"a\":", "\"x\""] {
        let ext = Extensions {
            metadata: Some(json.into()),
            ..Extensions::default()
        };
        assert!(
            encode(&mesh, RECT, &e, &ext)
                .unwrap_err()
                .to_string()
                .contains("metadata"),
            "{json}"
        );
    }
}

#[test]
fn extensions_follow_the_edges() {
    let mesh = grid(3, |i, j| f64::from(i * 10 + j));
    let e = Ellipsoid::WGS84;
    let plain = encode(&mesh, RECT, &e, &Extensions::default()).unwrap();
    let json = r#"{"available":[[{"startX":0,"startY":0,"endX":1,"endY":1}]]}"#;
    let ext = Extensions {
        normals: true,
        water_mask: None,
        metadata: Some(json.into()),
    };
    let full = encode(&mesh, RECT, &e, &ext).unwrap();
    assert_eq!(full[..plain.len()], plain[..]);
    let rest = &full[plain.len()..];
    assert_eq!(rest[0], EXTENSION_OCT_NORMALS);
    assert_eq!(u32::from_le_bytes(rest[1..5].try_into().unwrap()), 18);
    // A flat-ish tile's normals point up, near the ellipsoid's normal.
    let up = e.geodetic_surface_normal(7.625f64.to_radians(), 45.125f64.to_radians());
    for k in 0..9 {
        let n = header_geometry::oct_decode([rest[5 + 2 * k], rest[6 + 2 * k]]);
        let cos = n[0] * up[0] + n[1] * up[1] + n[2] * up[2];
        assert!(cos > 0.99, "vertex {k}: {n:?}");
    }
    let m = &rest[23..];
    assert_eq!(m[0], EXTENSION_METADATA);
    assert_eq!(
        u32::from_le_bytes(m[1..5].try_into().unwrap()) as usize,
        4 + json.len()
    );
    assert_eq!(
        u32::from_le_bytes(m[5..9].try_into().unwrap()) as usize,
        json.len()
    );
    assert_eq!(&m[9..], json.as_bytes());
}

#[test]
fn the_water_mask_sits_between_the_normals_and_the_metadata() {
    let mesh = grid(3, |i, j| f64::from(i * 10 + j));
    let e = Ellipsoid::WGS84;
    let with_normals = Extensions {
        normals: true,
        ..Extensions::default()
    };
    let normals = encode(&mesh, RECT, &e, &with_normals).unwrap();
    // A grid with water in its north-west cell only: 65 536 bytes, north row first.
    let mut cells = vec![0u8; WATER_MASK_SIDE * WATER_MASK_SIDE];
    cells[0] = 255;
    let mask = WaterMask::from_grid(cells.clone()).unwrap();
    assert!(mask.is_water(0, 0) && !mask.is_water(1, 0) && !mask.is_water(0, 1));
    let json = r#"{"level":0}"#;
    let ext = Extensions {
        normals: true,
        water_mask: Some(mask),
        metadata: Some(json.into()),
    };
    let full = encode(&mesh, RECT, &e, &ext).unwrap();
    assert_eq!(full[..normals.len()], normals[..]);
    let rest = &full[normals.len()..];
    assert_eq!(rest[0], EXTENSION_WATER_MASK);
    assert_eq!(u32::from_le_bytes(rest[1..5].try_into().unwrap()), 65_536);
    assert_eq!(&rest[5..5 + 65_536], &cells[..]);
    let m = &rest[5 + 65_536..];
    assert_eq!(m[0], EXTENSION_METADATA);
    assert_eq!(&m[9..], json.as_bytes());
    // Uniform grids take the one-byte form; other sizes are refused.
    for (v, one) in [(0u8, WaterMask::land()), (255, WaterMask::water())] {
        let m = WaterMask::from_grid(vec![v; 65_536]).unwrap();
        assert_eq!(m, one);
        assert_eq!(m.bytes(), [v]);
        let ext = Extensions {
            water_mask: Some(m),
            ..Extensions::default()
        };
        let plain = encode(&mesh, RECT, &e, &Extensions::default()).unwrap();
        let t = encode(&mesh, RECT, &e, &ext).unwrap();
        assert_eq!(t[plain.len()..], [EXTENSION_WATER_MASK, 1, 0, 0, 0, v]);
    }
    assert!(WaterMask::from_grid(vec![0; 255 * 256]).is_none());
}

#[test]
fn the_centre_is_the_rectangles_at_mid_height() {
    let mesh = grid(3, |i, _| f64::from(i) * 100.0);
    let e = Ellipsoid::WGS84;
    let bytes = encode(&mesh, RECT, &e, &Extensions::default()).unwrap();
    let c: Vec<f64> = (0..3)
        .map(|i| f64::from_le_bytes(bytes[8 * i..8 * i + 8].try_into().unwrap()))
        .collect();
    assert_eq!(
        c,
        e.to_ecef(7.625f64.to_radians(), 45.125f64.to_radians(), 100.0)
            .to_array()
    );
}

#[test]
fn a_hemisphere_gets_the_far_occlusion_point() {
    let mesh = grid(3, |_, _| 10.0);
    let e = Ellipsoid::WGS84;
    let bytes = encode(
        &mesh,
        [-180.0, -90.0, 0.0, 90.0],
        &e,
        &Extensions::default(),
    )
    .unwrap();
    let p: Vec<f64> = (0..3)
        .map(|i| f64::from_le_bytes(bytes[64 + 8 * i..72 + 8 * i].try_into().unwrap()))
        .collect();
    // Along −y (longitude −90°, the equator), 1e6 out.
    assert!(p[0].abs() < 1e-3 && p[2].abs() < 1e-3, "{p:?}");
    assert!((p[1] + UNBOUNDED_HORIZON_DISTANCE).abs() < 1e-3, "{p:?}");
}
