//! Where the finest samples are on the body: a geographic grid directly, any other
//! CRS through its geotransform and the projection library.

use crate::crs::Crs;

/// Where the finest samples are on the body.
#[derive(Debug)]
pub(super) enum Mapping {
    /// A geographic grid on the body: `lon = lon0 + col·dlon`, `lat = lat0 + row·dlat`.
    Affine {
        lon0: f64,
        dlon: f64,
        lat0: f64,
        dlat: f64,
    },
    /// Any other CRS: the GDAL geotransform, then the projection library.
    Projected {
        crs: Box<Crs>,
        body: Box<Crs>,
        gt: [f64; 6],
        inverse: [f64; 6],
    },
}

impl Mapping {
    /// Longitude and latitude of finest-grid point `(col, row)`.
    pub(super) fn lon_lat(&self, col: f64, row: f64) -> Option<[f64; 2]> {
        match self {
            Self::Affine {
                lon0,
                dlon,
                lat0,
                dlat,
            } => Some([lon0 + col * dlon, lat0 + row * dlat]),
            Self::Projected { crs, body, gt, .. } => {
                let (c, r) = (col + 0.5, row + 0.5);
                let x = gt[0] + c * gt[1] + r * gt[2];
                let y = gt[3] + c * gt[4] + r * gt[5];
                crs.transform_to(body, x, y).ok()
            }
        }
    }

    /// Degrees between finest samples at `(col, row)`: the smaller of the two axes.
    pub(super) fn spacing_at(&self, col: f64, row: f64) -> Option<f64> {
        let c = self.lon_lat(col, row)?;
        let e = self.lon_lat(col + 1.0, row)?;
        let s = self.lon_lat(col, row + 1.0)?;
        Some(
            (e[0] - c[0])
                .hypot(e[1] - c[1])
                .min((s[0] - c[0]).hypot(s[1] - c[1])),
        )
    }

    /// Finest-grid coordinates of a longitude and latitude.
    pub(super) fn to_samples(&self, lon: f64, lat: f64) -> Option<[f64; 2]> {
        match self {
            Self::Affine {
                lon0,
                dlon,
                lat0,
                dlat,
            } => Some([(lon - lon0) / dlon, (lat - lat0) / dlat]),
            Self::Projected {
                crs, body, inverse, ..
            } => {
                let [x, y] = body.transform_to(crs, lon, lat).ok()?;
                let c = inverse[0] + x * inverse[1] + y * inverse[2];
                let r = inverse[3] + x * inverse[4] + y * inverse[5];
                Some([c - 0.5, r - 0.5])
            }
        }
    }
}

/// The inverse of a GDAL geotransform, or `None` when it is singular.
pub(super) fn invert(gt: &[f64; 6]) -> Option<[f64; 6]> {
    let det = gt[1] * gt[5] - gt[2] * gt[4];
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let (a, b, c, d) = (gt[5] / det, -gt[2] / det, -gt[4] / det, gt[1] / det);
    Some([
        -(a * gt[0] + b * gt[3]),
        a,
        b,
        -(c * gt[0] + d * gt[3]),
        c,
        d,
    ])
}
