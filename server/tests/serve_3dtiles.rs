//! Cesium terrain as 3D Tiles 1.1 over HTTP (DECISIONS.md "3D Tiles terrain"): a real
//! `tessera-server serve` of N46E008 (SRTM, EGM96). `tileset.json` as
//! `Cesium3DTilesTerrainProvider` reads it; subtree files whose availability is the
//! quantized-mesh availability, bit for bit, and whose tile bounds are the
//! quantized-mesh headers'; GLBs drawing the quantized-mesh tiles' vertices and
//! triangles; 404s with JSON reasons outside. CesiumJS itself draws it in
//! tests/browser/cesium3dtiles.test.mjs.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod cesium_support;

use cesium_support::{built, tile_at};
use glam::DVec3;
use serde_json::Value;
use serve_support::Server;
use std::path::Path;
use tessera_server::cesium::terrain::availability::{Availability, Stored};
use tessera_server::cesium::terrain::{PyramidLevels, Terrain};
use tessera_server::cesium::tiles3d::reader::QuantizedTile;
use tessera_server::cesium::tiles3d::{ImplicitTile, SUBTREE_LEVELS, morton};
use tessera_server::cesium::tiling::CesiumTile;
use tessera_shared::Pyramid;
use tessera_shared::ellipsoid::Ellipsoid;
use tessera_shared::format::FLAG_PARTIAL;

const BASE: &str = "/v1/datasets/N46E008";
/// The Finsteraarhorn.
const PEAK: (f64, f64) = (8.126_11, 46.537_22);

/// The availability made in-process, from the pyramid's index and masks.
fn availability_of(path: &Path) -> Availability {
    let p = Pyramid::open_file(path).unwrap();
    let terrain = Terrain::new(p.metadata(), None).unwrap();
    let levels = PyramidLevels::new(&p);
    let stored = |t| match p.entry(t) {
        Some(e) if e.flags & FLAG_PARTIAL != 0 => Stored::Partial,
        Some(_) => Stored::Full,
        None => Stored::Absent,
    };
    terrain.availability(stored, &levels).unwrap()
}

/// The quantized-mesh tile with normals, as the quantized-mesh route serves it.
fn quantized(s: &Server, t: CesiumTile) -> QuantizedTile {
    let r = s
        .get_with(
            &format!("{BASE}/cesium/{}/{}/{}.terrain", t.z, t.x, t.y),
            &[(
                "Accept",
                "application/vnd.quantized-mesh;extensions=octvertexnormals",
            )],
        )
        .expect(200);
    QuantizedTile::decode(&r.body).unwrap()
}

/// A subtree file's JSON and binary chunk.
fn subtree_chunks(b: &[u8]) -> (Value, Vec<u8>) {
    assert_eq!(&b[..4], b"subt");
    assert_eq!(u32::from_le_bytes(b[4..8].try_into().unwrap()), 1);
    let j = u64::from_le_bytes(b[8..16].try_into().unwrap()) as usize;
    let n = u64::from_le_bytes(b[16..24].try_into().unwrap()) as usize;
    assert_eq!(b.len(), 24 + j + n);
    (
        serde_json::from_slice(&b[24..24 + j]).unwrap(),
        b[24 + j..].to_vec(),
    )
}

fn bit(avail: &Value, doc: &Value, bin: &[u8], i: usize) -> bool {
    if let Some(c) = avail.get("constant") {
        return c == 1;
    }
    let v = &doc["bufferViews"][avail["bitstream"].as_u64().unwrap() as usize];
    let at = v["byteOffset"].as_u64().unwrap() as usize;
    (bin[at + i / 8] >> (i % 8)) & 1 == 1
}

fn column(doc: &Value, bin: &[u8], name: &str) -> Vec<f64> {
    let view = doc["propertyTables"][0]["properties"][name]["values"]
        .as_u64()
        .unwrap() as usize;
    let v = &doc["bufferViews"][view];
    let at = v["byteOffset"].as_u64().unwrap() as usize;
    let len = v["byteLength"].as_u64().unwrap() as usize;
    bin[at..at + len]
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

/// A GLB's JSON and binary chunk.
fn glb_chunks(b: &[u8]) -> (Value, Vec<u8>) {
    let w = |p: usize| u32::from_le_bytes(b[p..p + 4].try_into().unwrap()) as usize;
    assert_eq!(&b[..4], b"glTF");
    assert_eq!(w(4), 2);
    assert_eq!(w(8), b.len());
    let j = w(12);
    assert_eq!(&b[16..20], b"JSON");
    let doc = serde_json::from_slice(&b[20..20 + j]).unwrap();
    let at = 20 + j;
    assert_eq!(&b[at + 4..at + 8], b"BIN\0");
    (doc, b[at + 8..at + 8 + w(at)].to_vec())
}

/// An accessor's values (FLOAT, UNSIGNED_SHORT or UNSIGNED_INT).
fn accessor(doc: &Value, bin: &[u8], k: u64) -> Vec<f64> {
    let a = &doc["accessors"][k as usize];
    let v = &doc["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
    let at = v["byteOffset"].as_u64().unwrap() as usize;
    let per = if a["type"] == "VEC3" { 3 } else { 1 };
    let n = a["count"].as_u64().unwrap() as usize * per;
    let b = &bin[at..];
    let word = |i: usize| b[4 * i..4 * i + 4].try_into().unwrap();
    match a["componentType"].as_u64().unwrap() {
        5126 => (0..n)
            .map(|i| f64::from(f32::from_le_bytes(word(i))))
            .collect(),
        5123 => (0..n)
            .map(|i| f64::from(u16::from_le_bytes([b[2 * i], b[2 * i + 1]])))
            .collect(),
        5125 => (0..n)
            .map(|i| f64::from(u32::from_le_bytes(word(i))))
            .collect(),
        c => panic!("componentType {c}"),
    }
}

/// The URI of a template filled for an implicit tile, relative to tileset.json.
fn fill(template: &str, t: ImplicitTile) -> String {
    let uri = template
        .replace("{level}", &t.level.to_string())
        .replace("{x}", &t.x.to_string())
        .replace("{y}", &t.y.to_string());
    format!("{BASE}/3dtiles/{uri}")
}

#[test]
fn tileset_json_is_two_implicit_quadtrees_over_the_terrains_levels() {
    let Some(b) = built() else { return };
    let s = Server::start(&[&b.srtm], &[]);
    let layer = s
        .get(&format!("{BASE}/cesium/layer.json"))
        .expect(200)
        .json();
    let r = s.get(&format!("{BASE}/3dtiles/tileset.json")).expect(200);
    assert!(r.must("content-type").starts_with("application/json"));
    let etag = r.must("etag").to_string();
    let doc = r.json();
    assert_eq!(doc["asset"]["version"], "1.1");
    let kids = doc["root"]["children"].as_array().unwrap();
    assert_eq!(kids.len(), 2);
    let max_zoom = layer["maxzoom"].as_u64().unwrap();
    let lze = layer["metadata"]["levelZeroGeometricError"]
        .as_f64()
        .unwrap();
    for (root, k) in kids.iter().enumerate() {
        let it = &k["implicitTiling"];
        assert_eq!(it["subdivisionScheme"], "QUADTREE");
        assert_eq!(it["availableLevels"].as_u64().unwrap(), max_zoom + 1);
        assert_eq!(
            it["subtreeLevels"].as_u64().unwrap(),
            u64::from(SUBTREE_LEVELS)
        );
        assert_eq!(k["geometricError"].as_f64().unwrap(), lze);
        let hash = layer["metadata"]["contentHash"].as_str().unwrap();
        assert_eq!(
            k["content"]["uri"],
            format!("{root}/{{level}}/{{x}}/{{y}}.glb?v={hash}")
        );
        let region = k["boundingVolume"]["region"].as_array().unwrap();
        let w = region[0].as_f64().unwrap();
        assert_eq!(
            w,
            if root == 0 {
                -std::f64::consts::PI
            } else {
                0.0
            }
        );
        // The root tile's URIs answer (both roots always exist: sea level or data).
        let t = ImplicitTile::new(root as u8, 0, 0, 0).unwrap();
        let glb = s
            .get(&fill(k["content"]["uri"].as_str().unwrap(), t))
            .expect(200);
        assert_eq!(glb.must("content-type"), "model/gltf-binary");
        assert_eq!(&glb.body[..4], b"glTF");
        let sub = s
            .get(&fill(it["subtrees"]["uri"].as_str().unwrap(), t))
            .expect(200);
        assert_eq!(&sub.body[..4], b"subt");
        // Pinned (`?v=` the content hash): cacheable for good.
        assert!(
            glb.must("cache-control").contains("immutable"),
            "{:?}",
            glb.headers
        );
    }
    for (name, semantic) in [
        ("minimumHeight", "TILE_MINIMUM_HEIGHT"),
        ("maximumHeight", "TILE_MAXIMUM_HEIGHT"),
        ("boundingSphere", "TILE_BOUNDING_SPHERE"),
        ("horizonOcclusionPoint", "TILE_HORIZON_OCCLUSION_POINT"),
    ] {
        assert_eq!(
            doc["schema"]["classes"]["tile"]["properties"][name]["semantic"],
            semantic
        );
    }
    s.get_with(
        &format!("{BASE}/3dtiles/tileset.json"),
        &[("If-None-Match", &etag)],
    )
    .expect(304);
}

#[test]
fn subtrees_say_the_quantized_mesh_availability_and_headers() {
    let Some(b) = built() else { return };
    let s = Server::start(&[&b.srtm], &[]);
    let available = availability_of(&b.srtm);
    let max_zoom = available.max_zoom();
    // Subtrees along the way down to the peak, and to the data's south-west corner
    // (where tiles beyond the data do not exist), at every subtree level.
    let mut checked_partial = false;
    for (lon, lat) in [PEAK, (8.0001, 46.0001)] {
        for level in (0..=max_zoom).step_by(usize::from(SUBTREE_LEVELS)) {
            let root = ImplicitTile::of(tile_at(level, lon, lat));
            let r = s.get(&format!(
                "{BASE}/3dtiles/{}/{}/{}/{}.subtree",
                root.root, root.level, root.x, root.y
            ));
            let r = r.expect(200);
            assert_eq!(r.must("content-type"), "application/octet-stream");
            let (doc, bin) = subtree_chunks(&r.body);
            let mut rows = Vec::new();
            let mut i = 0;
            for d in 0..SUBTREE_LEVELS {
                let side = 1u32 << d;
                let mut level_tiles: Vec<(u64, ImplicitTile)> = (0..side)
                    .flat_map(|y| (0..side).map(move |x| (x, y)))
                    .map(|(x, y)| (morton(x, y), root.descendant(d, x, y)))
                    .collect();
                level_tiles.sort_unstable_by_key(|&(m, _)| m);
                for (_, t) in level_tiles {
                    let want = available.contains(t.cesium());
                    assert_eq!(bit(&doc["tileAvailability"], &doc, &bin, i), want, "{t}");
                    assert_eq!(bit(&doc["contentAvailability"][0], &doc, &bin, i), want);
                    if want {
                        rows.push(t);
                    }
                    i += 1;
                }
            }
            if rows.len() < i {
                checked_partial = true;
            }
            let side = 1u32 << SUBTREE_LEVELS;
            for y in 0..side {
                for x in 0..side {
                    let t = root.descendant(SUBTREE_LEVELS, x, y);
                    let want = t.level <= max_zoom && available.contains(t.cesium());
                    let got = bit(
                        &doc["childSubtreeAvailability"],
                        &doc,
                        &bin,
                        morton(x, y) as usize,
                    );
                    assert_eq!(got, want, "child {t}");
                }
            }
            assert_eq!(
                doc["propertyTables"][0]["count"].as_u64().unwrap() as usize,
                rows.len()
            );
            // Each row's bounds are its quantized-mesh tile's header.
            let lo = column(&doc, &bin, "minimumHeight");
            let hi = column(&doc, &bin, "maximumHeight");
            let sphere = column(&doc, &bin, "boundingSphere");
            let hop = column(&doc, &bin, "horizonOcclusionPoint");
            for (k, t) in rows.iter().enumerate() {
                let q = quantized(&s, t.cesium());
                assert_eq!(lo[k], f64::from(q.minimum_height), "{t}");
                assert_eq!(hi[k], f64::from(q.maximum_height), "{t}");
                assert_eq!(sphere[4 * k..4 * k + 3], q.sphere_centre.to_array());
                assert_eq!(sphere[4 * k + 3], q.sphere_radius);
                assert_eq!(hop[3 * k..3 * k + 3], q.horizon_occlusion_point.to_array());
            }
        }
    }
    assert!(
        checked_partial,
        "a subtree with tiles beyond the data was checked"
    );
}

#[test]
fn glbs_draw_the_quantized_mesh_tiles() {
    let Some(b) = built() else { return };
    let s = Server::start(&[&b.srtm], &[]);
    let available = availability_of(&b.srtm);
    let e = Ellipsoid::WGS84;
    let mut sizes = Vec::new();
    for z in [0, 5, 9, 12, available.max_zoom()] {
        let t = tile_at(z, PEAK.0, PEAK.1);
        let i = ImplicitTile::of(t);
        let q = quantized(&s, t);
        let r = s
            .get(&format!(
                "{BASE}/3dtiles/{}/{}/{}/{}.glb",
                i.root, i.level, i.x, i.y
            ))
            .expect(200);
        let (doc, bin) = glb_chunks(&r.body);
        // Compressed for a client that accepts it, as quantized-mesh is.
        let path = format!("{BASE}/3dtiles/{}/{}/{}/{}.glb", i.root, i.level, i.x, i.y);
        let zipped = s
            .get_with(&path, &[("accept-encoding", "gzip")])
            .expect(200);
        if r.body.len() > 1024 {
            assert_eq!(zipped.must("content-encoding"), "gzip", "{t}");
            assert!(
                zipped.body.len() < r.body.len(),
                "{t}: gzip made it no smaller"
            );
        }
        let prim = &doc["meshes"][0]["primitives"][0];
        let pos = accessor(&doc, &bin, prim["attributes"]["POSITION"].as_u64().unwrap());
        assert_eq!(pos.len(), 3 * q.u.len(), "{t}: vertex count");
        let m: Vec<f64> = doc["nodes"][0]["matrix"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let [w, so, ea, n] = t.rect();
        // f32 positions relative to the centre: ~6e6 m at zoom 0 has 0.5 m steps.
        let tolerance = (CesiumTile::span(z) * 111_000.0 * 1e-7).max(0.01);
        for k in 0..q.u.len() {
            let p = [pos[3 * k], pos[3 * k + 1], pos[3 * k + 2]];
            let y_up: Vec<f64> = (0..3)
                .map(|r| m[r] * p[0] + m[4 + r] * p[1] + m[8 + r] * p[2] + m[12 + r])
                .collect();
            let ecef = DVec3::new(y_up[0], -y_up[2], y_up[1]);
            let lon = w + f64::from(q.u[k]) / 32767.0 * (ea - w);
            let lat = so + f64::from(q.v[k]) / 32767.0 * (n - so);
            let want = e.to_ecef(lon.to_radians(), lat.to_radians(), q.height(k));
            assert!(
                ecef.distance(want) <= tolerance,
                "{t} vertex {k}: {ecef} vs {want}"
            );
        }
        let idx = accessor(&doc, &bin, prim["indices"].as_u64().unwrap());
        let want: Vec<f64> = q
            .triangles
            .iter()
            .flatten()
            .map(|&i| f64::from(i))
            .collect();
        assert_eq!(idx, want, "{t}: triangles");
        let edges = &prim["extensions"]["CESIUM_tile_edges"];
        for (name, list) in ["left", "bottom", "right", "top"].iter().zip(&q.edges) {
            let got = accessor(&doc, &bin, edges[*name].as_u64().unwrap());
            assert_eq!(got, list.iter().map(|&i| f64::from(i)).collect::<Vec<_>>());
        }
        sizes.push((t, r.body.len()));
    }
    eprintln!("GLB bytes: {sizes:?}");
}

#[test]
fn tiles_and_subtrees_outside_availability_are_404s_with_reasons() {
    let Some(b) = built() else { return };
    let s = Server::start(&[&b.srtm], &[]);
    let available = availability_of(&b.srtm);
    let deep = available.max_zoom() + 1;
    // West root, zoom 4: the Pacific, no data.
    let msg = s.get(&format!("{BASE}/3dtiles/0/4/0/0.glb")).error(404);
    assert!(msg.contains("holds no data"), "{msg}");
    let msg = s.get(&format!("{BASE}/3dtiles/0/4/0/0.subtree")).error(404);
    assert!(msg.contains("subtree"), "{msg}");
    // Past the deepest level, at the peak.
    let t = ImplicitTile::of(tile_at(deep.next_multiple_of(2), PEAK.0, PEAK.1));
    let msg = s
        .get(&format!("{BASE}/3dtiles/1/{}/{}/{}.glb", t.level, t.x, t.y))
        .error(404);
    assert!(msg.contains("holds no data"), "{msg}");
    s.get(&format!(
        "{BASE}/3dtiles/1/{}/{}/{}.subtree",
        t.level, t.x, t.y
    ))
    .error(404);
    // Subtrees start at even levels only.
    let t = ImplicitTile::of(tile_at(5, PEAK.0, PEAK.1));
    let msg = s
        .get(&format!("{BASE}/3dtiles/1/5/{}/{}.subtree", t.x, t.y))
        .error(404);
    assert!(msg.contains("multiples of 2"), "{msg}");
    // Not in the quadtrees, or not a tile at all.
    for bad in [
        "2/0/0/0.glb",
        "1/3/8/0.glb",
        "1/3/0/8.subtree",
        "1/99/0/0.glb",
        "1/x/0/0.glb",
        "1/0/0/0.png",
    ] {
        let msg = s.get(&format!("{BASE}/3dtiles/{bad}")).error(404);
        assert!(!msg.is_empty(), "{bad}");
    }
    s.get("/v1/datasets/nope/3dtiles/tileset.json").error(404);
}
