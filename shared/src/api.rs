//! The HTTP API's paths and JSON documents (API.md), in the contract so that the
//! server's router and responses and the client's requests and parsing cannot drift.
//!
//! ```
//! use tessera_shared::api::{fill, routes};
//!
//! let url = fill(routes::TILES, &[("name", "moon"), ("level", "3")]);
//! assert_eq!(url, "/v1/datasets/moon/levels/3/tiles");
//! ```

use crate::imagery::ImageryMetadata;
use crate::metadata::{GeoRef, GroundSpacing, LevelCounts, Metadata, Quantization, VerticalDatum};
use serde::{Deserialize, Serialize};

/// Route templates in the router's `{param}` syntax (axum's), used by the server as
/// they are and filled in by clients with [`fill`].
pub mod routes {
    pub const DATASETS: &str = "/v1/datasets";
    pub const DATASET: &str = "/v1/datasets/{name}";
    pub const TILEJSON: &str = "/v1/datasets/{name}/tilejson.json";
    pub const PYRAMID: &str = "/v1/datasets/{name}/pyramid";
    /// The pyramid's sources as GeoJSON (footprints, spacing, finest level).
    pub const COVERAGE: &str = "/v1/datasets/{name}/coverage.geojson";
    /// Everything a first frame needs in one response ([`crate::bootstrap`]); query `v=`.
    pub const BOOTSTRAP: &str = "/v1/datasets/{name}/bootstrap";
    /// Morton-range tile stream; query `ranges=` ([`crate::range_query`]).
    pub const TILES: &str = "/v1/datasets/{name}/levels/{level}/tiles";
    /// Morton-range error tables; query `ranges=`.
    pub const ERRORS: &str = "/v1/datasets/{name}/levels/{level}/errors";
    pub const TILE: &str = "/v1/datasets/{name}/tiles/{level}/{x}/{y}";
    /// Morton-range stream of imagery records (same framing as [`TILES`]); query
    /// `ranges=`. Only for datasets whose document has `imagery`.
    pub const IMAGERY_TILES: &str = "/v1/datasets/{name}/imagery/levels/{level}/tiles";
    /// PNG height tiles; the last segment is `{y}.png` (axum captures it whole).
    pub const WEB_TILE: &str = "/v1/datasets/{name}/{z}/{x}/{y}";
    /// TileJSON of a standard grid (`webmercator`, `crs84`); query `encoding=`, `size=`.
    pub const GRID_TILEJSON: &str = "/v1/datasets/{name}/{grid}/tilejson.json";
    /// Cesium terrain: `layer.json` (quantized-mesh-1.0, EPSG:4326 TMS).
    pub const CESIUM_LAYER: &str = "/v1/datasets/{name}/cesium/layer.json";
    /// Cesium terrain tiles; the last segment is `{y}.terrain`.
    pub const CESIUM_TILE: &str = "/v1/datasets/{name}/cesium/{z}/{x}/{y}";
    /// Cesium terrain as 3D Tiles 1.1: `tileset.json` (two implicit quadtrees).
    pub const TILES3D_TILESET: &str = "/v1/datasets/{name}/3dtiles/tileset.json";
    /// Its GLB tiles and subtree files: `{root}` 0 (west) or 1 (east), `{level}/{x}/{y}`
    /// of that root's quadtree; the last segment is `{y}.glb` or `{y}.subtree`.
    pub const TILES3D_TILE: &str = "/v1/datasets/{name}/3dtiles/{root}/{level}/{x}/{y}";
    /// Standard-grid tiles; the last segment is `{y}.png` or `{y}.webp`.
    pub const GRID_TILE: &str = "/v1/datasets/{name}/{grid}/{z}/{x}/{y}";
    /// A rendered terrain tile (`hillshade`, `color-relief`, `slope`) on a standard
    /// grid (API.md "Rendered terrain tiles").
    pub const RENDERED_TILE: &str = "/v1/datasets/{name}/{grid}/{layer}/{z}/{x}/{y}";
    /// TileJSON of a rendered layer on a standard grid.
    pub const RENDERED_TILEJSON: &str = "/v1/datasets/{name}/{grid}/{layer}/tilejson.json";
    /// Contour lines as Mapbox Vector Tiles on a standard grid; the last segment is
    /// `{y}.mvt` (API.md "Contour tiles").
    pub const CONTOUR_TILE: &str = "/v1/datasets/{name}/{grid}/contours/{z}/{x}/{y}";
    /// TileJSON of the contour tiles, with their `vector_layers`.
    pub const CONTOUR_TILEJSON: &str = "/v1/datasets/{name}/{grid}/contours/tilejson.json";
    /// Heights of points and profiles with their error bounds: `GET` with
    /// `locations=` or `path=`, `POST` with a JSON body (API.md "Elevation queries").
    pub const ELEVATION: &str = "/v1/datasets/{name}/elevation";
    /// WMTS 1.0.0 capabilities (RESTful) of every dataset with a place on a map.
    pub const WMTS: &str = "/wmts/1.0.0/WMTSCapabilities.xml";
    /// WMTS 1.0.0 capabilities of one dataset.
    pub const DATASET_WMTS: &str = "/v1/datasets/{name}/wmts/1.0.0/WMTSCapabilities.xml";
    /// OGC API – Tiles (OGC 20-057): landing page.
    pub const OGC_LANDING: &str = "/ogcapi";
    pub const OGC_CONFORMANCE: &str = "/ogcapi/conformance";
    pub const OGC_TILE_MATRIX_SETS: &str = "/ogcapi/tileMatrixSets";
    /// `{tms}`: `WebMercatorQuad` or `WorldCRS84Quad`.
    pub const OGC_TILE_MATRIX_SET: &str = "/ogcapi/tileMatrixSets/{tms}";
    pub const OGC_COLLECTIONS: &str = "/ogcapi/collections";
    pub const OGC_COLLECTION: &str = "/ogcapi/collections/{name}";
    pub const OGC_TILESETS: &str = "/ogcapi/collections/{name}/coverage/tiles";
    pub const OGC_TILESET: &str = "/ogcapi/collections/{name}/coverage/tiles/{tms}";
    /// One tile; OGC API orders the row before the column.
    pub const OGC_TILE: &str =
        "/ogcapi/collections/{name}/coverage/tiles/{tms}/{tile_matrix}/{tile_row}/{tile_col}";
    /// A shaded-relief PNG of the whole dataset (at most 256 px a side); query `v=`.
    pub const PREVIEW: &str = "/v1/datasets/{name}/preview.png";
    /// The built-in viewer's landing page (HTML): every dataset and its interfaces.
    pub const LANDING: &str = "/";
    /// The built-in viewer of one dataset (HTML: MapLibre GL JS, CesiumJS).
    pub const VIEWER: &str = "/viewer/{name}";
    /// The viewer's static files: `{lib}` is `maplibre`, `cesium` (third-party, from
    /// `--viewer-assets`) or `tessera` (the viewer's own, in the binary).
    pub const VIEWER_ASSET: &str = "/viewer/assets/{lib}/{*path}";
}

/// `template` with each `{key}` of `params` replaced by its value. Placeholders not
/// named stay as they are (the links in [`DatasetInfo`] keep `{level}` etc. for
/// clients to fill).
pub fn fill(template: &str, params: &[(&str, &str)]) -> String {
    params.iter().fold(template.to_string(), |s, (k, v)| {
        s.replace(&format!("{{{k}}}"), v)
    })
}

/// `GET /v1/datasets/{name}`: one dataset's description.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DatasetInfo {
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub tile_size: u32,
    pub levels: u8,
    pub finest_level: u8,
    /// The pyramid file's format version: how its tile records are laid out
    /// ([`crate::codec::RecordLayout`]), since the server sends them as stored.
    pub format_version: u32,
    pub min_height: f64,
    pub max_height: f64,
    pub quantization: Quantization,
    pub nodata_count: u64,
    pub nodata_fill: String,
    /// `"EPSG:nnnn"` when the code is known.
    pub crs: Option<String>,
    /// `[west, south, east, north]` of the pixel areas, when georeferenced.
    pub extent: Option<[f64; 4]>,
    pub georef: Option<GeoRef>,
    /// Metres between samples east–west (`x`) and north–south (`y`) at the DEM's
    /// centre; `null` without a known CRS (clients then use a stated spacing).
    pub ground_spacing: Option<GroundSpacing>,
    pub vertical_datum: VerticalDatum,
    /// Valid and filled samples per level, level 0 first (empty for v1 files).
    pub level_counts: Vec<LevelCounts>,
    pub source: String,
    pub content_hash: String,
    /// Size of the pyramid file in bytes.
    pub bytes: u64,
    pub links: DatasetLinks,
    /// The dataset's imagery pyramid (DECISIONS.md "Imagery pyramids"), absent when it
    /// has none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub imagery: Option<ImageryInfo>,
    /// The body the grid lies on and whether the grid is longitude/latitude
    /// (DECISIONS.md "The globe"), absent when the CRS names no known ellipsoid. The
    /// server fills it from its projection library; [`DatasetInfo::new`] from the
    /// georeferencing alone ([`crate::body::Body::from_georef`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub body: Option<crate::body::Body>,
}

/// Where a dataset's resources are, relative to the server; `{level}`, `{ranges}`,
/// `{x}`, `{y}` and `{z}` are left for the client to fill.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct DatasetLinks {
    #[serde(rename = "self")]
    pub self_: String,
    pub tilejson: String,
    pub pyramid: String,
    pub tiles: String,
    pub errors: String,
    pub tile: String,
    pub png: String,
    /// The interfaces a server offers beyond the pyramid itself (DECISIONS.md "Real
    /// clients"), each only where it applies to the dataset; absent in documents made
    /// from the file alone ([`DatasetInfo::new`]) and from servers that predate them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bootstrap: Option<String>,
    /// A shaded-relief PNG of the whole dataset.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub preview: Option<String>,
    /// The sources' footprints, spacing and finest level as GeoJSON (files that record
    /// their sources: format version 3).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coverage: Option<String>,
    /// TileJSON of the standard grids (datasets with a place on a map).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub standard_grids: Option<StandardGridLinks>,
    /// WMTS 1.0.0 capabilities of this dataset.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wmts: Option<String>,
    /// OGC API – Tiles: the dataset's collection.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ogcapi_collection: Option<String>,
    /// OGC API – Tiles: the collection's coverage tilesets.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ogcapi_tilesets: Option<String>,
    /// Cesium terrain (quantized-mesh-1.0) `layer.json`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cesium: Option<String>,
    /// The server's built-in viewer of the dataset (HTML), unless `--no-viewer`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub viewer: Option<String>,
}

/// TileJSON documents of one standard grid, per height encoding.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct EncodingLinks {
    pub terrarium: String,
    pub mapbox: String,
}

/// TileJSON documents of the two standard grids (OGC tile matrix set identifiers).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct StandardGridLinks {
    #[serde(rename = "WebMercatorQuad")]
    pub web_mercator_quad: EncodingLinks,
    #[serde(rename = "WorldCRS84Quad")]
    pub world_crs84_quad: EncodingLinks,
}

/// `GET /v1/datasets`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DatasetList {
    pub datasets: Vec<DatasetInfo>,
}

impl DatasetInfo {
    /// The description of dataset `name`, whose file of `bytes` bytes holds `meta`.
    pub fn new(name: &str, meta: &Metadata, format_version: u32, bytes: u64) -> Self {
        let at = |template: &str| fill(template, &[("name", name)]);
        Self {
            name: name.to_string(),
            width: meta.width,
            height: meta.height,
            tile_size: meta.tile_size,
            levels: meta.levels,
            finest_level: meta.levels.saturating_sub(1),
            format_version,
            min_height: meta.min_height,
            max_height: meta.max_height,
            quantization: meta.quantization,
            nodata_count: meta.nodata_count,
            nodata_fill: meta.nodata_fill.clone(),
            crs: meta.georef.as_ref().and_then(GeoRef::crs),
            extent: meta
                .georef
                .as_ref()
                .map(|g| g.extent(meta.width, meta.height)),
            georef: meta.georef.clone(),
            ground_spacing: meta.ground_spacing,
            vertical_datum: meta.vertical_datum,
            level_counts: meta.level_counts.clone(),
            source: meta.source.clone(),
            content_hash: meta.content_hash.clone(),
            bytes,
            links: DatasetLinks {
                self_: at(routes::DATASET),
                tilejson: at(routes::TILEJSON),
                pyramid: at(routes::PYRAMID),
                tiles: format!("{}?ranges={{ranges}}", at(routes::TILES)),
                errors: format!("{}?ranges={{ranges}}", at(routes::ERRORS)),
                tile: at(routes::TILE),
                png: format!("{}.png?encoding=terrarium", at(routes::WEB_TILE)),
                bootstrap: None,
                preview: None,
                coverage: (!meta.sources.is_empty()).then(|| at(routes::COVERAGE)),
                standard_grids: None,
                wmts: None,
                ogcapi_collection: None,
                ogcapi_tilesets: None,
                cesium: None,
                viewer: None,
            },
            imagery: None,
            body: meta
                .georef
                .as_ref()
                .and_then(crate::body::Body::from_georef),
        }
    }
}

/// What the dataset document (`GET /v1/datasets/{name}`, [`DatasetInfo`])
/// says of a dataset's imagery.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageryInfo {
    /// Texels per tile side (every level).
    pub texels: u32,
    /// Ground size of a finest-level texel, `[x, y]` in the DEM CRS's units.
    pub texel_size: [f64; 2],
    /// Media type of each record.
    pub media_type: String,
    pub bands: [u16; 3],
    pub source: String,
    /// The imagery pyramid's own content hash (ETags of imagery responses).
    pub content_hash: String,
    /// Size of the imagery pyramid file in bytes.
    pub bytes: u64,
    /// Morton-range stream of imagery records; `{level}` and `{ranges}` to fill.
    pub tiles: String,
}

impl ImageryInfo {
    /// The imagery part of dataset `name`'s document: from its imagery pyramid's
    /// metadata and the file's size.
    pub fn new(name: &str, meta: &ImageryMetadata, bytes: u64) -> Self {
        Self {
            texels: meta.texels,
            texel_size: meta.texel_size,
            media_type: meta.encoding.media_type().to_string(),
            bands: meta.bands,
            source: meta.source.clone(),
            content_hash: meta.content_hash.clone(),
            bytes,
            tiles: format!(
                "{}?ranges={{ranges}}",
                fill(routes::IMAGERY_TILES, &[("name", name)])
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fill_replaces_only_the_named_placeholders() {
        assert_eq!(
            fill(routes::TILE, &[("name", "a"), ("x", "3")]),
            "/v1/datasets/a/tiles/{level}/3/{y}"
        );
    }

    #[test]
    fn links_are_the_routes_of_the_dataset() {
        let meta = crate::fixtures::metadata(8193, 8193, 512);
        let info = DatasetInfo::new("moon", &meta, crate::format::VERSION, 42);
        assert_eq!(info.links.self_, "/v1/datasets/moon");
        assert_eq!(
            info.links.tiles,
            "/v1/datasets/moon/levels/{level}/tiles?ranges={ranges}"
        );
        assert_eq!(
            info.links.png,
            "/v1/datasets/moon/{z}/{x}/{y}.png?encoding=terrarium"
        );
        let json = serde_json::to_value(&info).unwrap();
        assert_eq!(json["links"]["self"], "/v1/datasets/moon");
        assert_eq!(json["finest_level"], u64::from(meta.levels) - 1);
        let back: DatasetInfo = serde_json::from_value(json).unwrap();
        assert_eq!(back, info);
        // The document itself, as clients see it (API.md).
        insta::assert_snapshot!(serde_json::to_string_pretty(&info).unwrap());
    }
}
