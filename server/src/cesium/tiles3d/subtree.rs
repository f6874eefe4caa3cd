//! A subtree file of 3D Tiles 1.1 implicit tiling (binary: the magic `subt`,
//! version 1, the JSON and binary chunks' lengths as u64, then the chunks, each
//! padded to 8 bytes): which tiles of the subtree exist (`tileAvailability`, levels
//! in turn, each in Morton order, one bit a tile, least significant bit first), that
//! each of them has a GLB (`contentAvailability`, the same bits), which child subtrees
//! exist (`childSubtreeAvailability`: the tiles one level below the subtree, in
//! Morton order), and a property table of the available tiles, in bit order, with
//! what `Cesium3DTilesTerrainProvider` needs before it draws one: its height range,
//! bounding sphere and horizon-occlusion point ([`super::tileset::TILE_PROPERTIES`]).
//! A bitstream all ones or all zeros is written as a constant.

use super::reader::QuantizedTile;
use super::tileset::{TILE_CLASS, TILE_PROPERTIES};
use super::{ImplicitTile, morton};
use serde_json::{Value, json};

/// The subtree file's magic, "subt".
pub const MAGIC: &[u8; 4] = b"subt";

/// The bounds a subtree states for one tile: those of its quantized-mesh header.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TileBounds {
    pub minimum_height: f64,
    pub maximum_height: f64,
    /// Centre (ECEF) and radius.
    pub bounding_sphere: [f64; 4],
    /// Ellipsoid-scaled space.
    pub horizon_occlusion_point: [f64; 3],
}

impl TileBounds {
    /// The header's bounds of a quantized-mesh tile.
    pub fn of(t: &QuantizedTile) -> Self {
        let c = t.sphere_centre;
        Self {
            minimum_height: f64::from(t.minimum_height),
            maximum_height: f64::from(t.maximum_height),
            bounding_sphere: [c.x, c.y, c.z, t.sphere_radius],
            horizon_occlusion_point: t.horizon_occlusion_point.to_array(),
        }
    }
}

/// Which tiles of a subtree exist, and which of its child subtrees.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SubtreeAvailability {
    /// The subtree's root.
    pub root: ImplicitTile,
    pub levels: u8,
    /// One per tile, levels in turn, each in Morton order.
    pub tiles: Vec<bool>,
    /// One per tile `levels` below the root, in Morton order.
    pub children: Vec<bool>,
}

impl SubtreeAvailability {
    /// The availability of the subtree of `levels` levels rooted at `root`.
    pub fn of(root: ImplicitTile, levels: u8, available: impl Fn(ImplicitTile) -> bool) -> Self {
        let mut tiles = vec![false; bits_before(levels)];
        for level in 0..levels {
            let offset = bits_before(level);
            for y in 0..1u32 << level {
                for x in 0..1u32 << level {
                    tiles[offset + morton(x, y) as usize] = available(root.descendant(level, x, y));
                }
            }
        }
        let side = 1u32 << levels;
        let mut children = vec![false; (side * side) as usize];
        for y in 0..side {
            for x in 0..side {
                children[morton(x, y) as usize] = available(root.descendant(levels, x, y));
            }
        }
        Self {
            root,
            levels,
            tiles,
            children,
        }
    }

    /// The available tiles in bit order: the rows of the property table.
    pub fn available_tiles(&self) -> Vec<ImplicitTile> {
        let mut out = Vec::new();
        for level in 0..self.levels {
            let offset = bits_before(level);
            let side = 1u32 << level;
            let mut at: Vec<(u64, ImplicitTile)> = (0..side)
                .flat_map(|y| (0..side).map(move |x| (x, y)))
                .filter(|&(x, y)| self.tiles[offset + morton(x, y) as usize])
                .map(|(x, y)| (morton(x, y), self.root.descendant(level, x, y)))
                .collect();
            at.sort_unstable_by_key(|&(m, _)| m);
            out.extend(at.into_iter().map(|(_, t)| t));
        }
        out
    }

    /// The subtree file, with `bounds` for [`Self::available_tiles`], in that order.
    pub fn encode(&self, bounds: &[TileBounds]) -> Vec<u8> {
        assert_eq!(
            bounds.len(),
            self.tiles.iter().filter(|&&b| b).count(),
            "one bounds per available tile"
        );
        let mut bin: Vec<u8> = Vec::new();
        let mut views: Vec<Value> = Vec::new();
        // Buffer views start 8-aligned (FLOAT64 values).
        let mut view = |bin: &mut Vec<u8>, bytes: &[u8]| {
            bin.resize(bin.len().next_multiple_of(8), 0);
            views.push(json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len()}));
            bin.extend_from_slice(bytes);
            views.len() - 1
        };
        let mut availability = |bin: &mut Vec<u8>, bits: &[bool]| {
            let count = bits.iter().filter(|&&b| b).count();
            if count == 0 || count == bits.len() {
                return json!({"constant": u8::from(count > 0), "availableCount": count});
            }
            let v = view(bin, &bitstream(bits));
            json!({"bitstream": v, "availableCount": count})
        };
        let tiles = availability(&mut bin, &self.tiles);
        let children = availability(&mut bin, &self.children);
        let f64s = |vs: &mut dyn Iterator<Item = f64>| -> Vec<u8> {
            vs.flat_map(f64::to_le_bytes).collect()
        };
        let columns: [Vec<u8>; 4] = [
            f64s(&mut bounds.iter().map(|b| b.minimum_height)),
            f64s(&mut bounds.iter().map(|b| b.maximum_height)),
            f64s(&mut bounds.iter().flat_map(|b| b.bounding_sphere)),
            f64s(&mut bounds.iter().flat_map(|b| b.horizon_occlusion_point)),
        ];
        let mut properties = serde_json::Map::new();
        for ((name, _, _, _), column) in TILE_PROPERTIES.iter().zip(&columns) {
            let v = view(&mut bin, column);
            properties.insert((*name).to_string(), json!({"values": v}));
        }
        bin.resize(bin.len().next_multiple_of(8), 0);
        let doc = json!({
            "buffers": [{"byteLength": bin.len()}],
            "bufferViews": views,
            "tileAvailability": tiles,
            "contentAvailability": [tiles],
            "childSubtreeAvailability": children,
            "propertyTables": [{"class": TILE_CLASS, "count": bounds.len(), "properties": properties}],
            "tileMetadata": 0,
        });
        let mut json = serde_json::to_vec(&doc).expect("JSON");
        json.resize(json.len().next_multiple_of(8), b' ');
        let mut out = Vec::with_capacity(24 + json.len() + bin.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&1u32.to_le_bytes());
        out.extend_from_slice(&(json.len() as u64).to_le_bytes());
        out.extend_from_slice(&(bin.len() as u64).to_le_bytes());
        out.extend_from_slice(&json);
        out.extend_from_slice(&bin);
        out
    }
}

/// Tiles in the levels above `level` of a quadtree: `(4^level − 1) / 3`.
pub fn bits_before(level: u8) -> usize {
    ((1usize << (2 * u32::from(level))) - 1) / 3
}

/// Bits packed least significant first.
pub fn bitstream(bits: &[bool]) -> Vec<u8> {
    let mut out = vec![0u8; bits.len().div_ceil(8)];
    for (i, _) in bits.iter().enumerate().filter(|(_, b)| **b) {
        out[i / 8] |= 1 << (i % 8);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    /// A subtree file read back: its JSON and binary chunk.
    fn chunks(bytes: &[u8]) -> (Value, Vec<u8>) {
        assert_eq!(&bytes[..4], MAGIC);
        assert_eq!(u32::from_le_bytes(bytes[4..8].try_into().unwrap()), 1);
        let json_len = u64::from_le_bytes(bytes[8..16].try_into().unwrap()) as usize;
        let bin_len = u64::from_le_bytes(bytes[16..24].try_into().unwrap()) as usize;
        assert_eq!(json_len % 8, 0);
        assert_eq!(bin_len % 8, 0);
        assert_eq!(bytes.len(), 24 + json_len + bin_len);
        let json = serde_json::from_slice(&bytes[24..24 + json_len]).unwrap();
        (json, bytes[24 + json_len..].to_vec())
    }

    /// An availability's bit `i`, as a reader takes it from the JSON and buffer.
    fn bit(json: &Value, doc: &Value, bin: &[u8], i: usize) -> bool {
        if let Some(c) = json.get("constant") {
            return c == 1;
        }
        let v = &doc["bufferViews"][json["bitstream"].as_u64().unwrap() as usize];
        let at = v["byteOffset"].as_u64().unwrap() as usize;
        (bin[at + i / 8] >> (i % 8)) & 1 == 1
    }

    fn f64s(doc: &Value, bin: &[u8], name: &str) -> Vec<f64> {
        let table = &doc["propertyTables"][0];
        let view = table["properties"][name]["values"].as_u64().unwrap() as usize;
        let v = &doc["bufferViews"][view];
        let at = v["byteOffset"].as_u64().unwrap() as usize;
        assert_eq!(at % 8, 0);
        let len = v["byteLength"].as_u64().unwrap() as usize;
        bin[at..at + len]
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect()
    }

    #[test]
    fn bits_follow_levels_then_morton_order_by_brute_force() {
        // Available: a diagonal band of tiles of root 1 below (level 4, x 5, y 9).
        let root = ImplicitTile::new(1, 4, 5, 9).unwrap();
        let yes = |t: ImplicitTile| t.level <= 7 && (t.x + t.y) % 3 != 1;
        let levels = 3;
        let a = SubtreeAvailability::of(root, levels, yes);
        assert_eq!(a.tiles.len(), 1 + 4 + 16);
        assert_eq!(a.children.len(), 64);
        // Every bit, by enumerating the bit index → (level, x, y) by hand: a local
        // Morton index m at level d has x from its even bits and y from its odd ones.
        let unmorton = |m: u64| {
            let (mut x, mut y) = (0u32, 0u32);
            for k in 0..16 {
                x |= (((m >> (2 * k)) & 1) as u32) << k;
                y |= (((m >> (2 * k + 1)) & 1) as u32) << k;
            }
            (x, y)
        };
        let mut i = 0;
        for d in 0..levels {
            for m in 0..(1u64 << (2 * d)) {
                let (x, y) = unmorton(m);
                let t = ImplicitTile::new(1, 4 + d, (5 << d) + x, (9 << d) + y).unwrap();
                assert_eq!(a.tiles[i], yes(t), "bit {i}: {t}");
                i += 1;
            }
        }
        for m in 0..64u64 {
            let (x, y) = unmorton(m);
            let t = ImplicitTile::new(1, 7, (5 << 3) + x, (9 << 3) + y).unwrap();
            assert_eq!(a.children[m as usize], yes(t));
        }
        // The table's rows are the available tiles in bit order.
        let rows = a.available_tiles();
        let want: Vec<ImplicitTile> = (0..a.tiles.len())
            .filter(|&i| a.tiles[i])
            .map(|i| {
                let d = (0..levels).rev().find(|&d| bits_before(d) <= i).unwrap();
                let (x, y) = unmorton((i - bits_before(d)) as u64);
                root.descendant(d, x, y)
            })
            .collect();
        assert_eq!(rows, want);
        assert_eq!(rows.iter().collect::<HashSet<_>>().len(), rows.len());
    }

    #[test]
    fn the_file_reads_back() {
        let root = ImplicitTile::new(0, 2, 1, 3).unwrap();
        let a = SubtreeAvailability::of(root, 2, |t| t.level == 2 || (t.x + t.y) % 2 == 1);
        let rows = a.available_tiles();
        assert_eq!(rows.len(), 3);
        assert_eq!(rows[0], root);
        assert!(a.children.iter().any(|&b| b) && !a.children.iter().all(|&b| b));
        let bounds: Vec<TileBounds> = (0..rows.len())
            .map(|k| TileBounds {
                minimum_height: -(k as f64),
                maximum_height: 100.0 + k as f64,
                bounding_sphere: [1.0, 2.0, 3.0, 4.0 + k as f64],
                horizon_occlusion_point: [0.5, 0.25, k as f64],
            })
            .collect();
        let (doc, bin) = chunks(&a.encode(&bounds));
        assert_eq!(
            doc["buffers"][0]["byteLength"].as_u64().unwrap() as usize,
            bin.len()
        );
        for i in 0..a.tiles.len() {
            assert_eq!(bit(&doc["tileAvailability"], &doc, &bin, i), a.tiles[i]);
            assert_eq!(
                bit(&doc["contentAvailability"][0], &doc, &bin, i),
                a.tiles[i]
            );
        }
        for i in 0..a.children.len() {
            assert_eq!(
                bit(&doc["childSubtreeAvailability"], &doc, &bin, i),
                a.children[i]
            );
        }
        assert_eq!(doc["tileAvailability"]["availableCount"], rows.len());
        assert_eq!(doc["propertyTables"][0]["count"], rows.len());
        assert_eq!(doc["propertyTables"][0]["class"], TILE_CLASS);
        assert_eq!(doc["tileMetadata"], 0);
        let lo = f64s(&doc, &bin, "minimumHeight");
        let sphere = f64s(&doc, &bin, "boundingSphere");
        let hop = f64s(&doc, &bin, "horizonOcclusionPoint");
        assert_eq!(lo.len(), rows.len());
        for (k, b) in bounds.iter().enumerate() {
            assert_eq!(lo[k], b.minimum_height);
            assert_eq!(sphere[4 * k..4 * k + 4], b.bounding_sphere);
            assert_eq!(hop[3 * k..3 * k + 3], b.horizon_occlusion_point);
        }
        assert_eq!(f64s(&doc, &bin, "maximumHeight")[2], 102.0);
    }

    #[test]
    fn all_or_nothing_is_a_constant() {
        let root = ImplicitTile::new(1, 0, 0, 0).unwrap();
        let a = SubtreeAvailability::of(root, 2, |t| t.level < 2);
        let one = TileBounds {
            minimum_height: 0.0,
            maximum_height: 1.0,
            bounding_sphere: [0.0; 4],
            horizon_occlusion_point: [0.0; 3],
        };
        let (doc, _) = chunks(&a.encode(&[one; 5]));
        assert_eq!(
            doc["tileAvailability"],
            json!({"constant": 1, "availableCount": 5})
        );
        assert_eq!(
            doc["childSubtreeAvailability"],
            json!({"constant": 0, "availableCount": 0})
        );
        assert_eq!(
            bitstream(&[true, false, false, true, false, false, false, false, true]),
            [0b1001, 1]
        );
    }
}
