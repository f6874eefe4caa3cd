//! One terrain tile as a binary glTF 2.0 (GLB), as CesiumJS's
//! `Cesium3DTilesTerrainProvider` reads it: one mesh, one triangle primitive with
//! `POSITION` and `NORMAL` (32-bit floats: the provider reads uncompressed attributes
//! as `Float32Array`s whatever the accessor says), 16- or 32-bit indices, and the
//! extension `CESIUM_tile_edges` naming the accessors of the west (`left`), south
//! (`bottom`), east (`right`) and north (`top`) edge vertices, from which the client
//! builds skirts. Node 0 carries a `matrix` (the provider reads nothing else): a
//! translation to the tile's centre, in glTF's y-up frame (the client turns it z-up).
//!
//! The vertices, triangles, edges and normals are those of the quantized-mesh tile
//! ([`super::reader::QuantizedTile`]), positions decoded exactly as a quantized-mesh
//! client decodes them, so both formats draw the same surface.

use super::reader::QuantizedTile;
use glam::DVec3;
use serde_json::json;
use tessera_shared::ellipsoid::Ellipsoid;

/// The GLB header's magic, "glTF".
pub const GLB_MAGIC: u32 = 0x4654_6C67;
/// Chunk types: JSON and BIN.
pub const CHUNK_JSON: u32 = 0x4E4F_534A;
pub const CHUNK_BIN: u32 = 0x004E_4942;
/// glTF's `componentType`s and buffer view targets.
const FLOAT: u32 = 5126;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
/// The extension naming the edge vertices.
pub const TILE_EDGES: &str = "CESIUM_tile_edges";

/// z-up (ECEF) to glTF's y-up: `(x, y, z) → (x, z, −y)`; the client undoes it.
fn y_up(p: DVec3) -> DVec3 {
    DVec3::new(p.x, p.z, -p.y)
}

/// The GLB of `tile` over `rect_deg` = [west, south, east, north] (degrees).
pub fn encode(tile: &QuantizedTile, rect_deg: [f64; 4], ellipsoid: &Ellipsoid) -> Vec<u8> {
    let [west, south, east, north] = rect_deg;
    let n = tile.u.len();
    let centre = tile.centre;
    // Positions relative to the centre, as f32 (a zoom-0 tile is ±6400 km: 0.5 m steps;
    // a zoom-12 tile 5 km: 0.3 mm).
    let positions: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            let lon = west + f64::from(tile.u[i]) / 32767.0 * (east - west);
            let lat = south + f64::from(tile.v[i]) / 32767.0 * (north - south);
            let p = ellipsoid.to_ecef(lon.to_radians(), lat.to_radians(), tile.height(i));
            y_up(p - centre).as_vec3().to_array()
        })
        .collect();
    let normals: Vec<[f32; 3]> = match &tile.normals {
        Some(ns) => ns.iter().map(|&v| y_up(v).as_vec3().to_array()).collect(),
        None => (0..n)
            .map(|i| {
                let lon = west + f64::from(tile.u[i]) / 32767.0 * (east - west);
                let lat = south + f64::from(tile.v[i]) / 32767.0 * (north - south);
                let g = ellipsoid.geodetic_surface_normal(lon.to_radians(), lat.to_radians());
                y_up(g).as_vec3().to_array()
            })
            .collect(),
    };
    // 16-bit indices cannot hold 65535 (primitive restart).
    let wide = n > 65_535;

    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    // Each view starts 4-aligned (the client makes typed arrays on them). A view has
    // at least 4 bytes (glTF wants byteLength ≥ 1; a tile's edges always hold its
    // corners, so only a degenerate tile has an empty list).
    let mut view = |bin: &mut Vec<u8>, bytes: &[u8], target: Option<u32>| {
        bin.resize(bin.len().next_multiple_of(4), 0);
        let length = bytes.len().max(4);
        let mut v = json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": length});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        bin.extend_from_slice(bytes);
        bin.resize(bin.len() + (length - bytes.len()), 0);
        views.push(v);
        views.len() - 1
    };
    let floats = |vs: &[[f32; 3]]| -> Vec<u8> {
        vs.iter().flatten().flat_map(|f| f.to_le_bytes()).collect()
    };
    let index_bytes = |is: &mut dyn Iterator<Item = u32>| -> Vec<u8> {
        if wide {
            is.flat_map(u32::to_le_bytes).collect()
        } else {
            is.flat_map(|i| (i as u16).to_le_bytes()).collect()
        }
    };
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for p in &positions {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let pv = view(&mut bin, &floats(&positions), Some(ARRAY_BUFFER));
    accessors.push(json!({"bufferView": pv, "componentType": FLOAT, "count": n,
        "type": "VEC3", "min": lo, "max": hi}));
    let nv = view(&mut bin, &floats(&normals), Some(ARRAY_BUFFER));
    accessors.push(json!({"bufferView": nv, "componentType": FLOAT, "count": n, "type": "VEC3"}));
    let index_type = if wide { UNSIGNED_INT } else { UNSIGNED_SHORT };
    let iv = view(
        &mut bin,
        &index_bytes(&mut tile.triangles.iter().flatten().copied()),
        Some(ELEMENT_ARRAY_BUFFER),
    );
    accessors.push(json!({"bufferView": iv, "componentType": index_type,
        "count": 3 * tile.triangles.len(), "type": "SCALAR"}));
    let mut edges = serde_json::Map::new();
    for (name, list) in ["left", "bottom", "right", "top"].iter().zip(&tile.edges) {
        let ev = view(&mut bin, &index_bytes(&mut list.iter().copied()), None);
        accessors.push(json!({"bufferView": ev, "componentType": index_type,
            "count": list.len(), "type": "SCALAR"}));
        edges.insert((*name).to_string(), json!(accessors.len() - 1));
    }
    bin.resize(bin.len().next_multiple_of(4), 0);

    // Column-major: identity, then the translation to the centre (y-up).
    let t = y_up(centre);
    let matrix = [
        1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, t.x, t.y, t.z, 1.0,
    ];
    let doc = json!({
        "asset": {"version": "2.0", "generator": "Tessera"},
        "extensionsUsed": [TILE_EDGES],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "matrix": matrix}],
        "meshes": [{"primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1},
            "indices": 2,
            "mode": 4,
            "extensions": {TILE_EDGES: edges},
        }]}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}],
    });
    let mut json = serde_json::to_vec(&doc).expect("JSON");
    json.resize(json.len().next_multiple_of(4), b' ');

    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    for w in [GLB_MAGIC, 2, total as u32, json.len() as u32, CHUNK_JSON] {
        out.extend_from_slice(&w.to_le_bytes());
    }
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(&CHUNK_BIN.to_le_bytes());
    out.extend_from_slice(&bin);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cesium::quantized_mesh::{Extensions, MeshVertex, TerrainMesh, encode as qm};
    use serde_json::Value;

    /// A GLB read back: its JSON and binary chunk.
    pub fn chunks(glb: &[u8]) -> (Value, Vec<u8>) {
        let word = |p: usize| u32::from_le_bytes(glb[p..p + 4].try_into().unwrap());
        assert_eq!(word(0), GLB_MAGIC);
        assert_eq!(word(4), 2);
        assert_eq!(word(8) as usize, glb.len());
        let json_len = word(12) as usize;
        assert_eq!(word(16), CHUNK_JSON);
        assert_eq!(json_len % 4, 0);
        let json: Value = serde_json::from_slice(&glb[20..20 + json_len]).unwrap();
        let at = 20 + json_len;
        assert_eq!(word(at + 4), CHUNK_BIN);
        let bin = glb[at + 8..at + 8 + word(at) as usize].to_vec();
        assert_eq!(at + 8 + bin.len(), glb.len());
        (json, bin)
    }

    /// An accessor's values as f64 (floats or unsigned indices).
    pub fn values(doc: &Value, bin: &[u8], accessor: usize) -> Vec<f64> {
        let a = &doc["accessors"][accessor];
        let v = &doc["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
        let at = v["byteOffset"].as_u64().unwrap() as usize;
        assert_eq!(at % 4, 0);
        let per = match a["type"].as_str().unwrap() {
            "SCALAR" => 1,
            "VEC3" => 3,
            t => panic!("{t}"),
        };
        let n = a["count"].as_u64().unwrap() as usize * per;
        let b = &bin[at..];
        match a["componentType"].as_u64().unwrap() as u32 {
            FLOAT => (0..n)
                .map(|i| f64::from(f32::from_le_bytes(b[4 * i..4 * i + 4].try_into().unwrap())))
                .collect(),
            UNSIGNED_SHORT => (0..n)
                .map(|i| f64::from(u16::from_le_bytes(b[2 * i..2 * i + 2].try_into().unwrap())))
                .collect(),
            UNSIGNED_INT => (0..n)
                .map(|i| f64::from(u32::from_le_bytes(b[4 * i..4 * i + 4].try_into().unwrap())))
                .collect(),
            c => panic!("{c}"),
        }
    }

    #[test]
    fn the_glb_draws_the_quantized_mesh_tiles_vertices() {
        let mut vertices = Vec::new();
        for j in 0..4u16 {
            for i in 0..4u16 {
                vertices.push(MeshVertex {
                    u: (i * 10922).min(32767),
                    v: (j * 10922).min(32767),
                    height: 500.0 + f64::from(i + 3 * j) * 113.0,
                });
            }
        }
        // Edges at exactly 32767.
        for v in &mut vertices {
            if v.u == 32766 {
                v.u = 32767;
            }
            if v.v == 32766 {
                v.v = 32767;
            }
        }
        let mut triangles = Vec::new();
        for j in 0..3u32 {
            for i in 0..3u32 {
                let a = 4 * j + i;
                triangles.extend([[a, a + 1, a + 5], [a, a + 5, a + 4]]);
            }
        }
        let mesh = TerrainMesh {
            vertices,
            triangles,
        };
        let rect = [8.4375, 46.40625, 8.789_062_5, 46.757_812_5];
        let e = Ellipsoid::WGS84;
        let ext = Extensions {
            normals: true,
            ..Extensions::default()
        };
        let tile = QuantizedTile::decode(&qm(&mesh, rect, &e, &ext).unwrap()).unwrap();
        let glb = encode(&tile, rect, &e);
        let (doc, bin) = chunks(&glb);
        assert_eq!(doc["asset"]["version"], "2.0");
        let prim = &doc["meshes"][0]["primitives"][0];
        let m: Vec<f64> = doc["nodes"][0]["matrix"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let pos = values(
            &doc,
            &bin,
            prim["attributes"]["POSITION"].as_u64().unwrap() as usize,
        );
        assert_eq!(pos.len(), 3 * 16);
        for i in 0..16 {
            // Node matrix (column-major), then y-up to z-up: (x, y, z) → (x, −z, y).
            let p = [pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]];
            let q: Vec<f64> = (0..3)
                .map(|r| m[r] * p[0] + m[4 + r] * p[1] + m[8 + r] * p[2] + m[12 + r])
                .collect();
            let ecef = DVec3::new(q[0], -q[2], q[1]);
            let lon = rect[0] + f64::from(tile.u[i]) / 32767.0 * (rect[2] - rect[0]);
            let lat = rect[1] + f64::from(tile.v[i]) / 32767.0 * (rect[3] - rect[1]);
            let want = e.to_ecef(lon.to_radians(), lat.to_radians(), tile.height(i));
            assert!(ecef.distance(want) < 0.01, "vertex {i}: {ecef} vs {want}");
        }
        let idx = values(&doc, &bin, prim["indices"].as_u64().unwrap() as usize);
        let want: Vec<f64> = tile
            .triangles
            .iter()
            .flatten()
            .map(|&i| f64::from(i))
            .collect();
        assert_eq!(idx, want);
        let edges = &prim["extensions"][TILE_EDGES];
        for (name, list) in ["left", "bottom", "right", "top"].iter().zip(&tile.edges) {
            let got = values(&doc, &bin, edges[*name].as_u64().unwrap() as usize);
            let want: Vec<f64> = list.iter().map(|&i| f64::from(i)).collect();
            assert_eq!(got, want, "{name}");
            assert_eq!(got.len(), 4);
        }
        let normals = values(
            &doc,
            &bin,
            prim["attributes"]["NORMAL"].as_u64().unwrap() as usize,
        );
        let n0 = tile.normals.as_ref().unwrap()[0];
        assert!((normals[0] - n0.x).abs() < 1e-6);
        assert!((normals[1] - n0.z).abs() < 1e-6);
        assert!((normals[2] + n0.y).abs() < 1e-6);
        // Every position within the accessor's min and max.
        let a = &doc["accessors"][prim["attributes"]["POSITION"].as_u64().unwrap() as usize];
        for i in 0..16 {
            for k in 0..3 {
                assert!(pos[3 * i + k] >= a["min"][k].as_f64().unwrap());
                assert!(pos[3 * i + k] <= a["max"][k].as_f64().unwrap());
            }
        }
    }
}
