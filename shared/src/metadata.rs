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
    /// Human-readable CRS description (citation keys, or the WKT's name), when present.
    pub crs_name: Option<String>,
    /// The CRS as a PROJ string (`+proj=… +datum=…`), when known: what a projection
    /// library needs, whether or not there is an EPSG code.
    pub proj: Option<String>,
    /// The CRS as OGC WKT 1, when known (GDAL and QGIS read it).
    pub wkt: Option<String>,
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

    /// The CRS coordinates of the *centre* of sample `(col, row)`.
    pub fn sample_centre(&self, col: f64, row: f64) -> [f64; 2] {
        let gt = &self.geotransform;
        let (c, r) = (col + 0.5, row + 0.5);
        [gt[0] + c * gt[1] + r * gt[2], gt[3] + c * gt[4] + r * gt[5]]
    }
}

/// The distance on the ground between neighbouring samples, in metres, measured at
/// the DEM's centre (docs/ARCHITECTURE.md#coordinate-systems). For a geographic CRS
/// the two differ (a degree of longitude shrinks with latitude); for a projected one
/// they are the pixel size in metres. The client lays samples out with these, so its
/// world is in metres.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GroundSpacing {
    /// East–west, between columns.
    pub x: f64,
    /// North–south, between rows.
    pub y: f64,
}

impl GroundSpacing {
    /// Both spacings are finite and positive.
    pub fn is_plausible(&self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.x > 0.0 && self.y > 0.0
    }
}

/// What the heights are measured from (docs/ARCHITECTURE.md#coordinate-systems), so
/// that outputs that want another reference (Cesium wants heights above the WGS84
/// ellipsoid) can convert.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VerticalDatum {
    /// Above the EGM96 geoid (SRTM, most 1″/3″ global DEMs).
    Egm96,
    /// Above the EGM2008 geoid (Copernicus DEM).
    Egm2008,
    /// Above the CRS's ellipsoid.
    Ellipsoid,
    /// Not stated by the input or the user.
    #[default]
    Unknown,
}

impl VerticalDatum {
    pub const fn name(self) -> &'static str {
        match self {
            Self::Egm96 => "egm96",
            Self::Egm2008 => "egm2008",
            Self::Ellipsoid => "ellipsoid",
            Self::Unknown => "unknown",
        }
    }
}

/// Samples of one level's grid (the DEM's samples at that level's stride, inside the
/// DEM) that hold input data, and those that were no-data and filled.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LevelCounts {
    pub valid: u64,
    pub filled: u64,
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
    /// Input samples that were no-data and were filled
    /// (docs/ARCHITECTURE.md#heights-and-no-data).
    pub nodata_count: u64,
    /// How no-data was filled, e.g. "nearest valid sample".
    pub nodata_fill: String,
    pub georef: Option<GeoRef>,
    /// Metres between samples at the DEM's centre; `None` when the input has no
    /// georeferencing (a plain PNG), where clients fall back to a stated spacing.
    pub ground_spacing: Option<GroundSpacing>,
    pub vertical_datum: VerticalDatum,
    /// Valid and filled sample counts, level 0 first (empty in version 1 files).
    pub level_counts: Vec<LevelCounts>,
    /// Where the data came from: file name, sample type, compression.
    pub source: String,
    /// The software that wrote the file.
    pub generator: String,
    /// Hash of the metadata and every record's checksum (16 hex digits): the dataset's
    /// identity for ETags and caches. Empty while the file is being written.
    pub content_hash: String,
    /// The inputs the pyramid was built from, in priority order (empty in files
    /// before version 3, and for synthetic terrain). `default`: a JSON document from a
    /// server that predates it still reads (bincode ignores the attribute).
    #[serde(default)]
    pub sources: Vec<SourceRecord>,
}

/// One input of a pyramid (its provenance): what it is, where it lies and how fine it
/// is, as the build read it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SourceRecord {
    /// The file name (without its folder).
    pub name: String,
    /// Its horizontal CRS as the build named it (`EPSG:2056 (CH1903+ / LV95)`), or
    /// empty when it had none.
    pub crs: String,
    /// Metres between its samples at its centre.
    pub spacing: Option<GroundSpacing>,
    /// What its heights were measured from, as read (before any `--to-vertical`).
    pub vertical_datum: VerticalDatum,
    /// Its outline in WGS 84 longitude/latitude degrees, a closed ring (first point =
    /// last), counter-clockwise; empty when it has no place on Earth.
    pub footprint: Vec<[f64; 2]>,
    /// The pyramid level whose sample spacing is the finest at or below this input's:
    /// the deepest level its data supports.
    pub level: u8,
}

impl Metadata {
    /// Checks that `content_hash` has the form [`crate::format::content_hash`] writes:
    /// exactly 16 lowercase hex digits. The hash goes into ETags and URLs, so anything
    /// else (a control character, a quote, CRLF) must be refused when a file is read,
    /// not discovered when a header is built. Says what is wrong, without echoing the
    /// raw bytes.
    pub fn check_content_hash(&self) -> Result<(), ContentHashError> {
        let h = &self.content_hash;
        if h.len() == 16 && h.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f')) {
            return Ok(());
        }
        Err(ContentHashError {
            escaped: h.escape_default().to_string(),
            len: h.len(),
        })
    }
}

/// A `content_hash` that is not 16 lowercase hex digits ([`Metadata::check_content_hash`]).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("content_hash \"{escaped}\" is not 16 lowercase hex digits ({len} bytes)")]
pub struct ContentHashError {
    /// The hash with anything but printable ASCII escaped (never the raw bytes).
    pub escaped: String,
    /// Its length in bytes.
    pub len: usize,
}

/// The metadata of format version 2 files: today's without `sources`.
pub(crate) mod v2 {
    use super::{GeoRef, GroundSpacing, LevelCounts, Quantization, VerticalDatum};
    use serde::{Deserialize, Serialize};

    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    pub struct Metadata {
        pub width: u32,
        pub height: u32,
        pub tile_size: u32,
        pub levels: u8,
        pub quantization: Quantization,
        pub min_height: f64,
        pub max_height: f64,
        pub nodata_count: u64,
        pub nodata_fill: String,
        pub georef: Option<GeoRef>,
        pub ground_spacing: Option<GroundSpacing>,
        pub vertical_datum: VerticalDatum,
        pub level_counts: Vec<LevelCounts>,
        pub source: String,
        pub generator: String,
        pub content_hash: String,
    }

    /// Back to the old shape, for hashing a version 2 file's metadata as it was
    /// written (`sources` is empty by construction).
    impl From<&super::Metadata> for Metadata {
        fn from(m: &super::Metadata) -> Self {
            Self {
                width: m.width,
                height: m.height,
                tile_size: m.tile_size,
                levels: m.levels,
                quantization: m.quantization,
                min_height: m.min_height,
                max_height: m.max_height,
                nodata_count: m.nodata_count,
                nodata_fill: m.nodata_fill.clone(),
                georef: m.georef.clone(),
                ground_spacing: m.ground_spacing,
                vertical_datum: m.vertical_datum,
                level_counts: m.level_counts.clone(),
                source: m.source.clone(),
                generator: m.generator.clone(),
                content_hash: m.content_hash.clone(),
            }
        }
    }

    impl From<Metadata> for super::Metadata {
        fn from(m: Metadata) -> Self {
            Self {
                width: m.width,
                height: m.height,
                tile_size: m.tile_size,
                levels: m.levels,
                quantization: m.quantization,
                min_height: m.min_height,
                max_height: m.max_height,
                nodata_count: m.nodata_count,
                nodata_fill: m.nodata_fill,
                georef: m.georef,
                ground_spacing: m.ground_spacing,
                vertical_datum: m.vertical_datum,
                level_counts: m.level_counts,
                source: m.source,
                generator: m.generator,
                content_hash: m.content_hash,
                sources: Vec::new(),
            }
        }
    }
}

/// The metadata of format version 1 files, field for field as they were written
/// (bincode is not self-describing, so old files need their own shape).
pub(crate) mod v1 {
    use super::{Quantization, RasterType};
    use serde::{Deserialize, Serialize};

    #[derive(Debug, Serialize, Deserialize)]
    pub struct GeoRef {
        pub epsg: Option<u32>,
        pub crs_name: Option<String>,
        pub geotransform: [f64; 6],
        pub raster_type: RasterType,
    }

    #[derive(Debug, Serialize, Deserialize)]
    pub struct Metadata {
        pub width: u32,
        pub height: u32,
        pub tile_size: u32,
        pub levels: u8,
        pub quantization: Quantization,
        pub min_height: f64,
        pub max_height: f64,
        pub nodata_count: u64,
        pub nodata_fill: String,
        pub georef: Option<GeoRef>,
        pub source: String,
        pub generator: String,
        pub content_hash: String,
    }

    /// Back to the old shape, for hashing a version 1 file's metadata as it was
    /// written (its new fields are empty by construction).
    impl From<&super::Metadata> for Metadata {
        fn from(m: &super::Metadata) -> Self {
            Self {
                width: m.width,
                height: m.height,
                tile_size: m.tile_size,
                levels: m.levels,
                quantization: m.quantization,
                min_height: m.min_height,
                max_height: m.max_height,
                nodata_count: m.nodata_count,
                nodata_fill: m.nodata_fill.clone(),
                georef: m.georef.as_ref().map(|g| GeoRef {
                    epsg: g.epsg,
                    crs_name: g.crs_name.clone(),
                    geotransform: g.geotransform,
                    raster_type: g.raster_type,
                }),
                source: m.source.clone(),
                generator: m.generator.clone(),
                content_hash: m.content_hash.clone(),
            }
        }
    }

    impl From<Metadata> for super::Metadata {
        fn from(m: Metadata) -> Self {
            Self {
                width: m.width,
                height: m.height,
                tile_size: m.tile_size,
                levels: m.levels,
                quantization: m.quantization,
                min_height: m.min_height,
                max_height: m.max_height,
                nodata_count: m.nodata_count,
                nodata_fill: m.nodata_fill,
                georef: m.georef.map(|g| super::GeoRef {
                    epsg: g.epsg,
                    crs_name: g.crs_name,
                    proj: None,
                    wkt: None,
                    geotransform: g.geotransform,
                    raster_type: g.raster_type,
                }),
                ground_spacing: None,
                vertical_datum: super::VerticalDatum::Unknown,
                level_counts: Vec::new(),
                source: m.source,
                generator: m.generator,
                content_hash: m.content_hash,
                sources: Vec::new(),
            }
        }
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
            proj: None,
            wkt: None,
            geotransform: [8.0, 0.5, 0.0, 47.0, 0.0, -0.25],
            raster_type: RasterType::PixelIsArea,
        };
        assert_eq!(g.extent(4, 8), [8.0, 45.0, 10.0, 47.0]);
        assert_eq!(g.crs().as_deref(), Some("EPSG:4326"));
        assert_eq!(g.sample_centre(0.0, 0.0), [8.25, 46.875]);
        assert_eq!(g.sample_centre(3.0, 7.0), [9.75, 45.125]);
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
            let e = m.check_content_hash().unwrap_err().to_string();
            assert!(e.contains("16 lowercase hex digits"), "{bad:?}: {e}");
            assert!(!e.contains('\r') && !e.contains('\u{7}'), "{e}");
        }
    }
}
