//! Dataset metadata: stored in the pyramid header (bincode 2) and served as JSON.

use serde::{Deserialize, Serialize};

/// How quantized `u16` heights map to metres: `h = offset + scale · q`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quantization {
    pub offset: f64,
    pub scale: f64,
    /// Largest difference between an input height and its stored value, in metres
    /// (0 for integer inputs, which are stored exactly).
    pub max_error: f64,
}

impl Quantization {
    pub fn height(&self, q: u16) -> f64 {
        self.offset + self.scale * f64::from(q)
    }
}

/// How a georeferenced raster's coordinates refer to its samples (GeoTIFF `GTRasterTypeGeoKey`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RasterType {
    /// A sample stands for the area of its pixel; the tiepoint is a pixel corner.
    PixelIsArea,
    /// A sample is a point; the tiepoint is the first sample's centre.
    PixelIsPoint,
}

/// Georeferencing, normalised to GDAL's convention whatever the source said.
///
/// `geotransform` is GDAL's six coefficients for the *corner* of pixel `(0, 0)`:
/// `X = gt[0] + col·gt[1] + row·gt[2]`, `Y = gt[3] + col·gt[4] + row·gt[5]`, where
/// `(col, row) = (0.5, 0.5)` is the centre of the first sample. For `PixelIsPoint`
/// sources the half-pixel shift has been applied, as GDAL does.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GeoRef {
    /// EPSG code of the horizontal CRS, when the source names one.
    pub epsg: Option<u32>,
    /// Human-readable CRS description (citation keys), when present.
    pub crs_name: Option<String>,
    pub geotransform: [f64; 6],
    /// What the source declared (kept so exports can write the same convention back).
    pub raster_type: RasterType,
}

impl GeoRef {
    /// `[west, south, east, north]` covered by the pixels of a `width × height` raster
    /// (for north-up rasters without rotation).
    pub fn extent(&self, width: u32, height: u32) -> [f64; 4] {
        let gt = &self.geotransform;
        let xs = [gt[0], gt[0] + f64::from(width) * gt[1]];
        let ys = [gt[3], gt[3] + f64::from(height) * gt[5]];
        [
            xs[0].min(xs[1]),
            ys[0].min(ys[1]),
            xs[0].max(xs[1]),
            ys[0].max(ys[1]),
        ]
    }

    /// `"EPSG:nnnn"` when the code is known.
    pub fn crs(&self) -> Option<String> {
        self.epsg.map(|c| format!("EPSG:{c}"))
    }
}

/// Everything a client or tool needs to know about a dataset.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Metadata {
    /// DEM width and height in samples (the padded grid beyond them is never terrain).
    pub width: u32,
    pub height: u32,
    /// Tile size `T` in cells.
    pub tile_size: u32,
    /// Number of levels (`L_max + 1`).
    pub levels: u8,
    pub quantization: Quantization,
    /// Lowest and highest valid height in metres, after quantization.
    pub min_height: f64,
    pub max_height: f64,
    /// Input samples that were no-data and were filled (DESIGN §3).
    pub nodata_count: u64,
    /// How no-data was filled, e.g. "nearest valid sample".
    pub nodata_fill: String,
    pub georef: Option<GeoRef>,
    /// Where the data came from: file name, sample type, compression.
    pub source: String,
    /// The software that wrote the file.
    pub generator: String,
    /// Hash of the metadata and every record's checksum (16 hex digits): the dataset's
    /// identity for ETags and caches. Empty while the file is being written.
    pub content_hash: String,
}

impl Metadata {
    /// Checks that `content_hash` has the form [`crate::format::content_hash`] writes:
    /// exactly 16 lowercase hex digits. The hash goes into ETags and URLs, so anything
    /// else (a control character, a quote, CRLF) must be refused when a file is read,
    /// not discovered when a header is built. Says what is wrong, without echoing the
    /// raw bytes.
    pub fn check_content_hash(&self) -> Result<(), String> {
        let h = &self.content_hash;
        if h.len() == 16 && h.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f')) {
            return Ok(());
        }
        Err(format!(
            "content_hash \"{}\" is not 16 lowercase hex digits ({} bytes)",
            h.escape_default(),
            h.len()
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extent_follows_the_geotransform() {
        let g = GeoRef {
            epsg: Some(4326),
            crs_name: None,
            geotransform: [8.0, 0.5, 0.0, 47.0, 0.0, -0.25],
            raster_type: RasterType::PixelIsArea,
        };
        assert_eq!(g.extent(4, 8), [8.0, 45.0, 10.0, 47.0]);
        assert_eq!(g.crs().as_deref(), Some("EPSG:4326"));
    }

    #[test]
    fn content_hash_must_be_16_lowercase_hex_digits() {
        let mut m = crate::fixtures::metadata(65, 65, 64);
        assert!(m.check_content_hash().is_ok());
        for bad in [
            "",
            "0123456789abcde",
            "0123456789abcdef0",
            "0123456789ABCDEF",
            "0123456789abcd\r\n",
            "0123456789abcde\"",
            "0123456789abcde\u{7}",
            "0123456789abcdeg",
        ] {
            m.content_hash = bad.into();
            let e = m.check_content_hash().unwrap_err();
            assert!(e.contains("16 lowercase hex digits"), "{bad:?}: {e}");
            assert!(!e.contains('\r') && !e.contains('\u{7}'), "{e}");
        }
    }
}
