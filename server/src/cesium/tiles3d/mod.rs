//! Cesium terrain as 3D Tiles 1.1 (DECISIONS.md "3D Tiles terrain"), as CesiumJS's
//! `Cesium3DTilesTerrainProvider` reads it: a `tileset.json` whose root has two
//! children, the western and eastern halves of the EPSG:4326 grid ([`super::tiling`]),
//! each an implicit quadtree ([`tileset`]); subtree files saying which tiles exist and
//! each tile's height range, bounding sphere and horizon-occlusion point
//! ([`subtree`]); and one GLB per tile ([`glb`]).
//!
//! The tiles are the quantized-mesh tiles read back ([`reader`]): the same vertices,
//! triangles, edges, normals and bounds, so the two formats draw the same surface.
//!
//! Implicit tile `(level, x, y)` of root `r` is quantized-mesh tile
//! `(level, r·2^level + x, y)`: both count `y` from the south.

pub mod glb;
pub mod reader;
pub mod subtree;
pub mod tileset;

use crate::cesium::tiling::{CesiumTile, MAX_ZOOM};

/// Levels per subtree: a subtree is a tile and its four children, what a client that
/// refines the tile asks for next, so the meshes a subtree's bounds need are the
/// ones about to be drawn.
pub const SUBTREE_LEVELS: u8 = 2;

/// A tile of one of the two implicit quadtrees.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ImplicitTile {
    /// 0: west of the prime meridian, 1: east.
    pub root: u8,
    pub level: u8,
    pub x: u32,
    pub y: u32,
}

impl ImplicitTile {
    /// A checked tile: `root < 2`, `level ≤ MAX_ZOOM`, `x, y < 2^level`.
    pub fn new(root: u8, level: u8, x: u32, y: u32) -> Option<Self> {
        (root < 2 && level <= MAX_ZOOM && x < (1 << level) && y < (1 << level)).then_some(Self {
            root,
            level,
            x,
            y,
        })
    }

    /// The quantized-mesh tile it is.
    pub fn cesium(self) -> CesiumTile {
        CesiumTile {
            z: self.level,
            x: (u32::from(self.root) << self.level) | self.x,
            y: self.y,
        }
    }

    /// The implicit tile a quantized-mesh tile is.
    pub fn of(t: CesiumTile) -> Self {
        Self {
            root: (t.x >> t.z) as u8,
            level: t.z,
            x: t.x & ((1 << t.z) - 1),
            y: t.y,
        }
    }

    /// Whether it roots a subtree (its level is a multiple of [`SUBTREE_LEVELS`]).
    pub fn roots_subtree(self) -> bool {
        self.level.is_multiple_of(SUBTREE_LEVELS)
    }

    /// Its descendant `levels` below at local `(x, y)`.
    pub fn descendant(self, levels: u8, x: u32, y: u32) -> Self {
        Self {
            root: self.root,
            level: self.level + levels,
            x: (self.x << levels) | x,
            y: (self.y << levels) | y,
        }
    }
}

impl std::fmt::Display for ImplicitTile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "3D Tiles tile {}/{}/{}/{}",
            self.root, self.level, self.x, self.y
        )
    }
}

/// The Morton index of `(x, y)` (3D Tiles implicit tiling): bits interleaved, `x`'s
/// in the even places.
pub fn morton(x: u32, y: u32) -> u64 {
    let spread = |v: u32| {
        let mut v = u64::from(v);
        v = (v | (v << 16)) & 0x0000_FFFF_0000_FFFF;
        v = (v | (v << 8)) & 0x00FF_00FF_00FF_00FF;
        v = (v | (v << 4)) & 0x0F0F_0F0F_0F0F_0F0F;
        v = (v | (v << 2)) & 0x3333_3333_3333_3333;
        (v | (v << 1)) & 0x5555_5555_5555_5555
    };
    spread(x) | (spread(y) << 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn morton_interleaves_x_low() {
        assert_eq!(morton(0, 0), 0);
        assert_eq!(morton(1, 0), 1);
        assert_eq!(morton(0, 1), 2);
        assert_eq!(morton(1, 1), 3);
        assert_eq!(morton(2, 0), 4);
        // Brute force: bit 2k of the index is bit k of x, bit 2k+1 bit k of y.
        for (x, y) in [(5u32, 9u32), (0xFFFF, 0), (123_456, 654_321), (u32::MAX, 1)] {
            let mut want = 0u64;
            for k in 0..32 {
                want |= u64::from((x >> k) & 1) << (2 * k);
                want |= u64::from((y >> k) & 1) << (2 * k + 1);
            }
            assert_eq!(morton(x, y), want, "{x} {y}");
        }
    }

    #[test]
    fn implicit_tiles_are_the_grids_halves() {
        // N46E008 at zoom 8 is in the eastern root.
        let t = CesiumTile::new(8, 267, 193).unwrap();
        let i = ImplicitTile::of(t);
        assert_eq!((i.root, i.level, i.x, i.y), (1, 8, 267 - 256, 193));
        assert_eq!(i.cesium(), t);
        let w = ImplicitTile::of(CesiumTile::new(0, 0, 0).unwrap());
        assert_eq!((w.root, w.x), (0, 0));
        assert_eq!(ImplicitTile::of(CesiumTile::new(0, 1, 0).unwrap()).root, 1);
        for z in [0u8, 3, 13] {
            for (x, y) in [(0, 0), ((2 << z) - 1, (1 << z) - 1), (1 << z, 0)] {
                let t = CesiumTile::new(z, x, y).unwrap();
                let i = ImplicitTile::of(t);
                assert!(ImplicitTile::new(i.root, i.level, i.x, i.y).is_some());
                assert_eq!(i.cesium(), t);
                // The same rectangle: the root's half plus the implicit offsets.
                let s = CesiumTile::span(z);
                let west = -180.0 + 180.0 * f64::from(i.root) + f64::from(i.x) * s;
                assert_eq!(t.rect()[0], west);
            }
        }
        assert!(ImplicitTile::new(2, 0, 0, 0).is_none());
        assert!(ImplicitTile::new(0, 3, 8, 0).is_none());
        assert!(ImplicitTile::new(0, 3, 0, 8).is_none());
    }
}
