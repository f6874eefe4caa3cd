//! The `tileset.json` of 3D Tiles terrain: a root without content whose two children
//! are the implicit quadtrees of the western and eastern halves (the two root tiles of
//! the EPSG:4326 grid), as `Cesium3DTilesTerrainProvider` reads them
//! (`root.children[0]` and `[1]`), and the metadata schema of the subtrees' tile
//! properties.

use super::SUBTREE_LEVELS;
use serde_json::{Value, json};
use std::f64::consts::{FRAC_PI_2, PI};

/// The class of the subtrees' tile metadata.
pub const TILE_CLASS: &str = "tile";

/// The tile properties, their types, array lengths and semantics, in the order the
/// subtrees store them: `(name, type, count, semantic)`, all FLOAT64. The bounding
/// sphere is a fixed-length array of 4 SCALARs, as the 3D Tiles metadata semantics
/// define `TILE_BOUNDING_SPHERE` (CesiumJS unpacks it as an array: a VEC4 reads as
/// nothing); the horizon-occlusion point is a VEC3.
pub const TILE_PROPERTIES: [(&str, &str, Option<u8>, &str); 4] = [
    ("minimumHeight", "SCALAR", None, "TILE_MINIMUM_HEIGHT"),
    ("maximumHeight", "SCALAR", None, "TILE_MAXIMUM_HEIGHT"),
    ("boundingSphere", "SCALAR", Some(4), "TILE_BOUNDING_SPHERE"),
    (
        "horizonOcclusionPoint",
        "VEC3",
        None,
        "TILE_HORIZON_OCCLUSION_POINT",
    ),
];

/// What the document says of a dataset.
#[derive(Debug, Clone)]
pub struct Tileset<'a> {
    /// Levels with tiles: the deepest zoom plus one.
    pub available_levels: u8,
    /// The geometric error of zoom 0 (metres); each level halves it.
    pub level_zero_error: f64,
    /// Heights every tile keeps within (metres above the ellipsoid).
    pub heights: [f64; 2],
    /// Appended to the content and subtree URIs (e.g. `?v=<content hash>`).
    pub query: &'a str,
    /// Said in `asset.tilesetVersion`.
    pub version: &'a str,
}

impl Tileset<'_> {
    /// The document.
    pub fn json(&self) -> Value {
        let [lo, hi] = self.heights;
        let properties: serde_json::Map<String, Value> = TILE_PROPERTIES
            .iter()
            .map(|&(name, ty, count, semantic)| {
                let mut p = json!({"type": ty, "componentType": "FLOAT64", "semantic": semantic});
                if let Some(n) = count {
                    p["array"] = json!(true);
                    p["count"] = json!(n);
                }
                (name.to_string(), p)
            })
            .collect();
        let half = |r: u8| {
            let west = -PI + PI * f64::from(r);
            json!({
                "boundingVolume": {"region": [west, -FRAC_PI_2, west + PI, FRAC_PI_2, lo, hi]},
                "geometricError": self.level_zero_error,
                "refine": "REPLACE",
                "content": {"uri": format!("{r}/{{level}}/{{x}}/{{y}}.glb{}", self.query)},
                "implicitTiling": {
                    "subdivisionScheme": "QUADTREE",
                    "subtreeLevels": SUBTREE_LEVELS,
                    "availableLevels": self.available_levels,
                    "subtrees": {"uri": format!("{r}/{{level}}/{{x}}/{{y}}.subtree{}", self.query)},
                },
            })
        };
        json!({
            "asset": {"version": "1.1", "tilesetVersion": self.version, "generator": "Tessera"},
            "schema": {
                "id": "tessera_terrain",
                "classes": {TILE_CLASS: {"properties": properties}},
            },
            "geometricError": 2.0 * self.level_zero_error,
            "root": {
                "boundingVolume": {"region": [-PI, -FRAC_PI_2, PI, FRAC_PI_2, lo, hi]},
                "geometricError": 2.0 * self.level_zero_error,
                "refine": "REPLACE",
                "children": [half(0), half(1)],
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_implicit_halves_with_the_tile_schema() {
        let doc = Tileset {
            available_levels: 15,
            level_zero_error: 77_067.0,
            heights: [-100.0, 4_300.0],
            query: "?v=abc",
            version: "abc",
        }
        .json();
        assert_eq!(doc["asset"]["version"], "1.1");
        let kids = doc["root"]["children"].as_array().unwrap();
        assert_eq!(kids.len(), 2);
        for (r, k) in kids.iter().enumerate() {
            let it = &k["implicitTiling"];
            assert_eq!(it["subdivisionScheme"], "QUADTREE");
            assert_eq!(it["availableLevels"], 15);
            assert_eq!(it["subtreeLevels"], SUBTREE_LEVELS);
            assert_eq!(
                it["subtrees"]["uri"],
                format!("{r}/{{level}}/{{x}}/{{y}}.subtree?v=abc")
            );
            assert_eq!(
                k["content"]["uri"],
                format!("{r}/{{level}}/{{x}}/{{y}}.glb?v=abc")
            );
            let region = k["boundingVolume"]["region"].as_array().unwrap();
            assert_eq!(region[0].as_f64().unwrap(), if r == 0 { -PI } else { 0.0 });
            assert_eq!(region[2].as_f64().unwrap(), if r == 0 { 0.0 } else { PI });
            assert_eq!(region[4].as_f64().unwrap(), -100.0);
        }
        let props = &doc["schema"]["classes"][TILE_CLASS]["properties"];
        for (name, ty, _, semantic) in TILE_PROPERTIES {
            assert_eq!(props[name]["type"], ty);
            assert_eq!(props[name]["semantic"], semantic);
        }
        assert_eq!(props["boundingSphere"]["array"], true);
        assert_eq!(props["boundingSphere"]["count"], 4);
    }
}
