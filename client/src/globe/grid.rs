//! A longitude/latitude grid: the affine map from finest-grid indices to degrees.

use tessera_shared::GeoRef;

/// Sample `(x, y)`'s centre is at longitude `lon0 + x·dlon`, latitude `lat0 + y·dlat`
/// (degrees; `dlat` is negative for north-up rasters).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LonLatGrid {
    pub lon0: f64,
    pub dlon: f64,
    pub lat0: f64,
    pub dlat: f64,
}

impl LonLatGrid {
    /// The grid of a north-up geotransform (no rotation terms) whose steps are
    /// finite and non-zero; `None` otherwise.
    pub fn from_georef(g: &GeoRef) -> Option<Self> {
        let gt = g.geotransform;
        let ok = gt[2] == 0.0
            && gt[4] == 0.0
            && gt.iter().all(|v| v.is_finite())
            && gt[1] != 0.0
            && gt[5] != 0.0;
        let [lon0, lat0] = g.sample_centre(0.0, 0.0);
        ok.then_some(Self {
            lon0,
            dlon: gt[1],
            lat0,
            dlat: gt[5],
        })
    }

    /// Longitude and latitude in radians of finest-grid point `(x, y)` (fractional
    /// allowed; latitude clamped to the poles).
    pub fn lon_lat(&self, x: f64, y: f64) -> (f64, f64) {
        let lon = self.lon0 + x * self.dlon;
        let lat = (self.lat0 + y * self.dlat).clamp(-90.0, 90.0);
        (lon.to_radians(), lat.to_radians())
    }
}
