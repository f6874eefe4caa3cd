//! Cesium's terrain tiling: the geographic TMS of `layer.json` with
//! `"projection": "EPSG:4326"` (quantized-mesh-1.0 spec; CesiumJS
//! `GeographicTilingScheme`): two root tiles of 180° × 180°, `2^(z+1) × 2^z` tiles at
//! zoom `z`, `x` from the antimeridian eastwards and `y` from the south pole
//! northwards.
//!
//! ```
//! use tessera_server::cesium::tiling::CesiumTile;
//!
//! let t = CesiumTile::new(1, 2, 1).unwrap();
//! assert_eq!(t.rect(), [0.0, 0.0, 90.0, 90.0]);
//! assert!(CesiumTile::new(0, 2, 0).is_none());
//! ```

/// Deepest zoom addressed (tiles of 180/2²² ° ≈ 4.8 m on Earth).
pub const MAX_ZOOM: u8 = 22;

/// One terrain tile.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CesiumTile {
    pub z: u8,
    pub x: u32,
    pub y: u32,
}

impl CesiumTile {
    /// A checked tile: `z ≤ MAX_ZOOM`, `x < 2^(z+1)`, `y < 2^z`.
    pub fn new(z: u8, x: u32, y: u32) -> Option<Self> {
        (z <= MAX_ZOOM && x < (2 << z) && y < (1 << z)).then_some(Self { z, x, y })
    }

    /// Degrees per tile side at zoom `z`: `180 / 2^z`, exact in binary.
    pub fn span(z: u8) -> f64 {
        180.0 / f64::from(1u32 << z)
    }

    /// `[west, south, east, north]` in degrees. Each edge is computed from the tile
    /// index alone (`−180 + x·span`), so neighbours get bit-identical shared edges.
    pub fn rect(self) -> [f64; 4] {
        let s = Self::span(self.z);
        [
            -180.0 + f64::from(self.x) * s,
            -90.0 + f64::from(self.y) * s,
            -180.0 + f64::from(self.x + 1) * s,
            -90.0 + f64::from(self.y + 1) * s,
        ]
    }

    /// The tiles of zoom `z` meeting the open box `[w, s, e, n]` (degrees):
    /// `[x0, y0, x1, y1]` inclusive, or `None` when none does.
    pub fn covering(z: u8, [w, s, e, n]: [f64; 4]) -> Option<[u32; 4]> {
        let span = Self::span(z);
        let (cols, rows) = (2u32 << z, 1u32 << z);
        let (w, e) = (w.max(-180.0), e.min(180.0));
        let (s, n) = (s.max(-90.0), n.min(90.0));
        if !(w < e && s < n) {
            return None;
        }
        // A tile meets the open box when its open interior overlaps it: the last
        // tile is the one whose west edge is strictly below `e`.
        let first = |v: f64, origin: f64, count: u32| {
            (((v - origin) / span).floor().max(0.0) as u32).min(count - 1)
        };
        let last = |v: f64, origin: f64, count: u32| {
            let k = ((v - origin) / span).ceil() as i64 - 1;
            (k.max(0) as u32).min(count - 1)
        };
        Some([
            first(w, -180.0, cols),
            first(s, -90.0, rows),
            last(e, -180.0, cols),
            last(n, -90.0, rows),
        ])
    }
}

impl std::fmt::Display for CesiumTile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "terrain tile {}/{}/{}", self.z, self.x, self.y)
    }
}

/// The geometric error CesiumJS assumes for zoom 0 of a quantized-mesh layer on a
/// body of the given largest radius: `TerrainProvider.
/// getEstimatedLevelZeroGeometricErrorForAHeightmap(ellipsoid, 65, 2)` =
/// `r · 2π · 0.25 / (65 · 2)` (heightmapTerrainQuality 0.25, a 65-sample tile, two
/// root tiles). Zoom `z` has this over `2^z`; CesiumJS refines with these values, so
/// every tile's true error must be within them.
pub fn level_zero_error(max_radius: f64) -> f64 {
    max_radius * std::f64::consts::TAU * 0.25 / (65.0 * 2.0)
}

/// The error CesiumJS assumes at zoom `z`.
pub fn geometric_error(level_zero: f64, z: u8) -> f64 {
    level_zero / f64::from(1u32 << z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cesiums_level_zero_error_for_wgs84() {
        // CesiumJS: 6378137 · 2π · 0.25 / 130 ≈ 77 067.34 m.
        let e = level_zero_error(6_378_137.0);
        assert!((e - 77_067.34).abs() < 0.01, "{e}");
        assert_eq!(geometric_error(e, 3), e / 8.0);
    }

    #[test]
    fn tiles_tile_the_globe_and_neighbours_share_edges_exactly() {
        for z in [0, 5, 13] {
            let a = CesiumTile::new(z, 7 % (2 << z), 0).unwrap();
            let b = CesiumTile::new(z, a.x + 1, 0);
            if let Some(b) = b {
                assert_eq!(a.rect()[2], b.rect()[0]);
            }
            let last = CesiumTile::new(z, (2 << z) - 1, (1 << z) - 1).unwrap();
            assert_eq!(last.rect()[2], 180.0);
            assert_eq!(last.rect()[3], 90.0);
        }
        assert!(CesiumTile::new(MAX_ZOOM + 1, 0, 0).is_none());
        assert!(CesiumTile::new(3, 16, 0).is_none());
        assert!(CesiumTile::new(3, 15, 8).is_none());
    }

    #[test]
    fn covering_finds_the_tiles_a_box_meets() {
        // N46E008 (8–9° E, 46–47° N) at zoom 0 is in the eastern root tile.
        assert_eq!(
            CesiumTile::covering(0, [8.0, 46.0, 9.0, 47.0]),
            Some([1, 0, 1, 0])
        );
        // At zoom 8 (0.703125° tiles): columns 267–268, rows 193–194.
        let [x0, y0, x1, y1] = CesiumTile::covering(8, [8.0, 46.0, 9.0, 47.0]).unwrap();
        for x in x0..=x1 {
            for y in y0..=y1 {
                let [w, s, e, n] = CesiumTile::new(8, x, y).unwrap().rect();
                assert!(w < 9.0 && e > 8.0 && s < 47.0 && n > 46.0);
            }
        }
        let [w, _, _, _] = CesiumTile::new(8, x0 - 1, y0).unwrap().rect();
        assert!(w + CesiumTile::span(8) <= 8.0);
        // A box ending exactly on a tile edge does not reach the next tile.
        assert_eq!(
            CesiumTile::covering(1, [0.0, 0.0, 90.0, 45.0]),
            Some([2, 1, 2, 1])
        );
        assert_eq!(CesiumTile::covering(1, [5.0, 5.0, 5.0, 6.0]), None);
    }
}
