//! How many metres of ground one pixel of a standard-grid tile spans, row by row:
//! what the slope of rendered terrain is measured against.
//!
//! Both standard grids stretch the ground: a WebMercatorQuad pixel spans
//! `c·cos φ` metres on a sphere (more exactly `c·N(φ)·cos φ / R` east–west and
//! `c·M(φ)·cos φ / R` north–south on the ellipsoid, where `R` is the grid's sphere,
//! 6 378 137 m), and a WorldCRS84Quad pixel spans `c·N(φ)·cos φ` by `c·M(φ)` metres
//! for `c` in radians. `gdaldem` takes one spacing for a whole raster from its
//! geotransform, which is why it asks users to reproject geographic grids first (or
//! guess `-s 111120`); a tile here takes each row's own, at the latitude of the row's
//! pixel centres. `N` and `M` are the prime-vertical and meridian radii of curvature.

use crate::web::tile_matrix::{TileMatrixSet, WebTile};

/// WebMercatorQuad's sphere radius (OGC 17-083r4 D.1), metres.
const MERCATOR_RADIUS: f64 = 6_378_137.0;

/// The semi-axes of the body the grid's latitudes are on, metres (`a ≥ b > 0`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Radii {
    pub a: f64,
    pub b: f64,
}

impl Radii {
    /// WGS 84, the standard grids' own datum.
    pub const WGS84: Self = Self {
        a: 6_378_137.0,
        b: 6_356_752.314_245_18,
    };

    /// `(N, M)` at latitude `phi` (radians).
    fn curvature(self, phi: f64) -> (f64, f64) {
        let e2 = 1.0 - (self.b / self.a).powi(2);
        let w2 = 1.0 - e2 * phi.sin().powi(2);
        let n = self.a / w2.sqrt();
        (n, n * (1.0 - e2) / w2)
    }
}

/// `[east–west, north–south]` metres of one pixel, for the `rows` pixel rows
/// starting at row `first` (which may be −1, the border above the tile) of `tile`
/// at `px` pixels.
pub fn row_spacing(tile: WebTile, px: u32, radii: Radii, first: i64, rows: usize) -> Vec<[f64; 2]> {
    let c = tile.tms.cell_size(tile.z, px);
    (0..rows)
        .map(|k| {
            let j = (first + k as i64) as f64;
            let [_, y] = tile.pixel_centre(px, 0.0, j);
            let (phi, ew_rad, ns_rad) = match tile.tms {
                TileMatrixSet::WebMercatorQuad => {
                    let phi = (y / MERCATOR_RADIUS).sinh().atan();
                    // x = R·λ and dy/dφ = R / cos φ.
                    (phi, c / MERCATOR_RADIUS, c * phi.cos() / MERCATOR_RADIUS)
                }
                TileMatrixSet::WorldCrs84Quad => {
                    let phi = y.to_radians();
                    (phi, c.to_radians(), c.to_radians())
                }
            };
            let (n, m) = radii.curvature(phi);
            [ew_rad * n * phi.cos(), ns_rad * m]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mercator_pixel_at_the_equator_is_its_nominal_size() {
        // Tile 0/0/0 at 256 px: rows 127 and 128 straddle the equator.
        let t = WebTile::new(TileMatrixSet::WebMercatorQuad, 0, 0, 0).unwrap();
        let c = TileMatrixSet::WebMercatorQuad.cell_size(0, 256);
        let s = row_spacing(t, 256, Radii::WGS84, 127, 2);
        // Within half a pixel of the equator cos φ ≈ 1 − 3e-5: N = a there.
        for [ew, ns] in s {
            assert!((ew / c - 1.0).abs() < 1e-4, "{ew} vs {c}");
            // M(0) = a(1 − e²) = b²/a.
            let m0 = Radii::WGS84.b.powi(2) / Radii::WGS84.a / Radii::WGS84.a;
            assert!((ns / c - m0).abs() < 1e-4, "{ns}");
        }
    }

    #[test]
    fn spacings_follow_the_latitude_and_match_geodesic_lengths() {
        use geographiclib_rs::InverseGeodesic;
        // CRS84 zoom 12, a tile at about 46.5° N: compare with the geodesic length of
        // one pixel east and one north (geographiclib), which the radii of curvature
        // give to first order.
        let tms = TileMatrixSet::WorldCrs84Quad;
        let t = WebTile::new(tms, 12, 4200, 1000).unwrap();
        let s = row_spacing(t, 256, Radii::WGS84, -1, 258);
        let g = geographiclib_rs::Geodesic::wgs84();
        let c = tms.cell_size(12, 256);
        for (k, [ew, ns]) in s.iter().enumerate() {
            let [lon, lat] = t.pixel_centre(256, 0.0, k as f64 - 1.0);
            let east: f64 = g.inverse(lat, lon - c / 2.0, lat, lon + c / 2.0);
            let north: f64 = g.inverse(lat - c / 2.0, lon, lat + c / 2.0, lon);
            assert!((ew / east - 1.0).abs() < 1e-7, "row {k}: {ew} vs {east}");
            assert!((ns / north - 1.0).abs() < 1e-7, "row {k}: {ns} vs {north}");
        }
        // Rows further south are wider east–west (northern hemisphere).
        assert!(s[257][0] > s[0][0]);
    }
}
