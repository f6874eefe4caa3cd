//! The two standard tile grids web maps and GIS desktops ask for, as OGC's "Two
//! Dimensional Tile Matrix Set" standard (OGC 17-083r4, annex D) defines them:
//!
//! - `WebMercatorQuad`: EPSG:3857, one root tile, `2^z × 2^z` tiles at zoom `z`;
//!   the XYZ scheme of MapLibre, Leaflet, OpenLayers and QGIS (row 0 at the north).
//! - `WorldCRS84Quad`: longitude/latitude (OGC CRS84, EPSG:4326 with east-north
//!   axes), two root tiles, `2^(z+1) × 2^z` tiles at zoom `z`.
//!
//! Tiles are square in the grid's own units; the numbers below are the standard's
//! definitions (extent, scale denominators), not projection formulas: coordinates
//! go between grids and datasets only through the projection library (crs.rs).
//!
//! ```
//! use tessera_server::web::tile_matrix::{TileMatrixSet, WebTile};
//!
//! let t = WebTile::new(TileMatrixSet::WebMercatorQuad, 1, 1, 0).unwrap();
//! let [x0, y0, x1, y1] = t.bounds();
//! assert!(x0 == 0.0 && y0 == 0.0 && x1 > 2.0e7 && y1 > 2.0e7);
//! assert!(WebTile::new(TileMatrixSet::WorldCrs84Quad, 0, 1, 0).is_some());
//! assert!(WebTile::new(TileMatrixSet::WorldCrs84Quad, 0, 0, 1).is_none());
//! ```

/// Deepest zoom served: at 256 px a WebMercatorQuad pixel is then 9 mm at the equator.
pub const MAX_ZOOM: u8 = 24;

/// WebMercatorQuad's half-width in metres: π × 6 378 137 (OGC 17-083r4 D.1).
const MERCATOR_HALF: f64 = 20_037_508.342_789_244;

/// The standard rendering pixel of OGC scale denominators: 0.28 mm.
pub const STANDARD_PIXEL_M: f64 = 0.000_28;

/// A standard tile matrix set.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TileMatrixSet {
    WebMercatorQuad,
    WorldCrs84Quad,
}

impl TileMatrixSet {
    pub const ALL: [Self; 2] = [Self::WebMercatorQuad, Self::WorldCrs84Quad];

    /// The standard's identifier (WMTS, OGC API – Tiles).
    pub const fn id(self) -> &'static str {
        match self {
            Self::WebMercatorQuad => "WebMercatorQuad",
            Self::WorldCrs84Quad => "WorldCRS84Quad",
        }
    }

    /// The path segment of our URLs (`/v1/datasets/{name}/{grid}/…`).
    pub const fn path(self) -> &'static str {
        match self {
            Self::WebMercatorQuad => "webmercator",
            Self::WorldCrs84Quad => "crs84",
        }
    }

    /// The grid named by a path segment or a standard identifier.
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL
            .into_iter()
            .find(|t| s == t.path() || s.eq_ignore_ascii_case(t.id()))
    }

    /// The EPSG code of the grid's CRS.
    pub const fn epsg(self) -> u32 {
        match self {
            Self::WebMercatorQuad => 3857,
            Self::WorldCrs84Quad => 4326,
        }
    }

    /// The CRS as the standard's documents write it.
    pub const fn crs_uri(self) -> &'static str {
        match self {
            Self::WebMercatorQuad => "http://www.opengis.net/def/crs/EPSG/0/3857",
            Self::WorldCrs84Quad => "http://www.opengis.net/def/crs/OGC/1.3/CRS84",
        }
    }

    /// `[min x, min y, max x, max y]` of the whole grid, in its CRS's units
    /// (metres; degrees east and north).
    pub const fn extent(self) -> [f64; 4] {
        match self {
            Self::WebMercatorQuad => [-MERCATOR_HALF, -MERCATOR_HALF, MERCATOR_HALF, MERCATOR_HALF],
            Self::WorldCrs84Quad => [-180.0, -90.0, 180.0, 90.0],
        }
    }

    /// Tiles across and down at zoom `z`.
    pub const fn matrix_size(self, z: u8) -> (u32, u32) {
        match self {
            Self::WebMercatorQuad => (1 << z, 1 << z),
            Self::WorldCrs84Quad => (2 << z, 1 << z),
        }
    }

    /// One tile's side at zoom `z`, in the CRS's units.
    pub fn tile_span(self, z: u8) -> f64 {
        let [x0, y0, x1, y1] = self.extent();
        let (_, rows) = self.matrix_size(z);
        debug_assert_eq!(x1 - x0, (y1 - y0) * f64::from(self.matrix_size(0).0));
        (y1 - y0) / f64::from(rows)
    }

    /// One pixel's side at zoom `z` for tiles of `px` pixels, in the CRS's units.
    pub fn cell_size(self, z: u8, px: u32) -> f64 {
        self.tile_span(z) / f64::from(px)
    }

    /// Metres per CRS unit, as the standard counts them for scale denominators: 1
    /// for metres, and for degrees the equatorial circumference of WGS 84 over 360.
    pub fn metres_per_unit(self) -> f64 {
        match self {
            Self::WebMercatorQuad => 1.0,
            Self::WorldCrs84Quad => MERCATOR_HALF * 2.0 / 360.0,
        }
    }

    /// The OGC scale denominator of zoom `z` at `px`-pixel tiles.
    pub fn scale_denominator(self, z: u8, px: u32) -> f64 {
        self.cell_size(z, px) * self.metres_per_unit() / STANDARD_PIXEL_M
    }
}

/// One tile of a standard grid (`x` east, `y` south, both from 0 at the north-west).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct WebTile {
    pub tms: TileMatrixSet,
    pub z: u8,
    pub x: u32,
    pub y: u32,
}

impl WebTile {
    /// A checked tile: `z ≤ MAX_ZOOM` and `(x, y)` inside the matrix.
    pub fn new(tms: TileMatrixSet, z: u8, x: u32, y: u32) -> Option<Self> {
        let (cols, rows) = (z <= MAX_ZOOM).then(|| tms.matrix_size(z))?;
        (x < cols && y < rows).then_some(Self { tms, z, x, y })
    }

    /// `[min x, min y, max x, max y]` in the grid's CRS.
    pub fn bounds(self) -> [f64; 4] {
        let [x0, _, _, y1] = self.tms.extent();
        let s = self.tms.tile_span(self.z);
        [
            x0 + f64::from(self.x) * s,
            y1 - f64::from(self.y + 1) * s,
            x0 + f64::from(self.x + 1) * s,
            y1 - f64::from(self.y) * s,
        ]
    }

    /// The grid-CRS coordinates of the centre of pixel `(i, j)` of a `px`-pixel tile.
    pub fn pixel_centre(self, px: u32, i: f64, j: f64) -> [f64; 2] {
        let [x0, _, _, y1] = self.bounds();
        let c = self.tms.cell_size(self.z, px);
        [x0 + (i + 0.5) * c, y1 - (j + 0.5) * c]
    }
}

impl std::fmt::Display for WebTile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} tile {}/{}/{}", self.tms.id(), self.z, self.x, self.y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_standard_scale_denominators() {
        // OGC 17-083r4 tables D.1 and D.2, zoom 0 at 256 px.
        let m = TileMatrixSet::WebMercatorQuad.scale_denominator(0, 256);
        assert!((m - 559_082_264.028_717_8).abs() < 1e-3, "{m}");
        let g = TileMatrixSet::WorldCrs84Quad.scale_denominator(0, 256);
        assert!((g - 279_541_132.014_358_9).abs() < 1e-3, "{g}");
        assert!((TileMatrixSet::WebMercatorQuad.scale_denominator(3, 512) - m / 16.0).abs() < 1e-6);
    }

    #[test]
    fn tiles_cover_the_grid_without_gaps() {
        for tms in TileMatrixSet::ALL {
            let z = 3;
            let (cols, rows) = tms.matrix_size(z);
            let [ex0, ey0, ex1, ey1] = tms.extent();
            let first = WebTile::new(tms, z, 0, 0).unwrap().bounds();
            let last = WebTile::new(tms, z, cols - 1, rows - 1).unwrap().bounds();
            assert_eq!((first[0], first[3]), (ex0, ey1));
            assert!((last[2] - ex1).abs() < 1e-6 && (last[1] - ey0).abs() < 1e-6);
            let a = WebTile::new(tms, z, 2, 5).unwrap().bounds();
            let b = WebTile::new(tms, z, 3, 5).unwrap().bounds();
            let c = WebTile::new(tms, z, 2, 6).unwrap().bounds();
            assert_eq!(a[2], b[0]);
            assert_eq!(a[1], c[3]);
            assert!(WebTile::new(tms, z, cols, 0).is_none());
            assert!(WebTile::new(tms, z, 0, rows).is_none());
        }
        assert!(WebTile::new(TileMatrixSet::WebMercatorQuad, MAX_ZOOM + 1, 0, 0).is_none());
    }

    #[test]
    fn grids_parse_from_paths_and_identifiers() {
        assert_eq!(
            TileMatrixSet::parse("webmercator"),
            Some(TileMatrixSet::WebMercatorQuad)
        );
        assert_eq!(
            TileMatrixSet::parse("WorldCRS84Quad"),
            Some(TileMatrixSet::WorldCrs84Quad)
        );
        assert_eq!(TileMatrixSet::parse("utm"), None);
    }
}
