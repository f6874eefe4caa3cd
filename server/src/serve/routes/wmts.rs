//! OGC WMTS 1.0.0 capabilities (RESTful binding) for the standard-grid tiles of
//! web_grid.rs, so GIS desktops (QGIS) and GDAL's WMTS driver open the datasets from
//! one URL, with no hand-written XML (DECISIONS.md "WMTS capabilities",
//! docs/ARCHITECTURE.md#derived-outputs).
//!
//! - `GET /wmts/1.0.0/WMTSCapabilities.xml`: every dataset that has a place on a map;
//! - `GET /v1/datasets/{name}/wmts/1.0.0/WMTSCapabilities.xml`: one dataset.
//!
//! One layer per dataset and encoding (`{name}_terrarium`, `{name}_mapbox`), and one
//! per rendered layer with its default options (`{name}_hillshade`,
//! `{name}_color-relief`, `{name}_slope`: routes/rendered.rs), each
//! linked to both standard grids (`WebMercatorQuad`, `WorldCRS84Quad`) with the tile
//! ranges that hold the dataset per zoom, and a `ResourceURL` template pointing at
//! the 256-pixel PNG tiles, pinned to the content hash. WMTS clients need absolute
//! URLs: they come from `--public-url` (or trusted forwarded headers), else from the
//! request's `Host`, and then the document is marked private (see `absolute_base`).

use super::base_url;
use super::web_grid::footprint;
use super::{Params, Segments, dataset, pinned};
use crate::http::cache::{self, LastModified};
use crate::http::error::{ApiError, ApiResult};
use crate::serve::AppState;
use crate::serve::dataset::Dataset;
use crate::web::encoding::Encoding;
use crate::web::footprint::Footprint;
use crate::web::render;
use crate::web::tile_matrix::TileMatrixSet;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, Uri, header};
use axum::response::{IntoResponse, Response};
use quick_xml::Writer;
use quick_xml::events::{BytesDecl, BytesText, Event};
use std::fmt::Write as _;
use std::io;
use std::sync::Arc;
use tessera_shared::api::routes;

/// The tile size the capabilities describe (the standard grids' own).
pub const TILE_PX: u32 = 256;

/// The encodings offered as layers, in layer order.
pub const ENCODINGS: [Encoding; 2] = [Encoding::Terrarium, Encoding::Mapbox];

/// How to turn a pixel back into a height, for abstracts and descriptions.
pub fn decoding(enc: Encoding) -> &'static str {
    match enc {
        Encoding::Terrarium => {
            "Terrarium-encoded heights: h = R*256 + G + B/256 - 32768 metres (1/256 m steps); alpha 0 marks no data."
        }
        Encoding::Mapbox => {
            "Terrain-RGB-encoded heights: h = -10000 + (R*65536 + G*256 + B)*0.1 metres (0.1 m steps); alpha 0 marks no data."
        }
    }
}

/// The CRS URN WMTS 1.0.0 documents use, with the axis order GDAL and QGIS read:
/// EPSG:3857 is east–north, and OGC CRS84 is longitude–latitude (EPSG:4326's URN
/// would be latitude–longitude).
pub const fn crs_urn(tms: TileMatrixSet) -> &'static str {
    match tms {
        TileMatrixSet::WebMercatorQuad => "urn:ogc:def:crs:EPSG::3857",
        TileMatrixSet::WorldCrs84Quad => "urn:ogc:def:crs:OGC:1.3:CRS84",
    }
}

/// The standard's well-known scale set of a grid (WMTS 1.0.0 annex E).
pub const fn well_known_scale_set(tms: TileMatrixSet) -> &'static str {
    match tms {
        TileMatrixSet::WebMercatorQuad => "urn:ogc:def:wkss:OGC:1.0:GoogleMapsCompatible",
        TileMatrixSet::WorldCrs84Quad => "urn:ogc:def:wkss:OGC:1.0:GoogleCRS84Quad",
    }
}

/// Tile ranges of one zoom: the tiles that meet `bounds` (a box in the grid's CRS).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileLimits {
    pub min_col: u32,
    pub max_col: u32,
    pub min_row: u32,
    pub max_row: u32,
}

/// The tiles of `tms` at zoom `z` that meet the box `[x0, y0, x1, y1]`.
pub fn tile_limits(tms: TileMatrixSet, bounds: [f64; 4], z: u8) -> TileLimits {
    let [ex0, _, _, ey1] = tms.extent();
    let span = tms.tile_span(z);
    let (cols, rows) = tms.matrix_size(z);
    let [bx0, by0, bx1, by1] = bounds;
    let index = |v: f64, n: u32| -> u32 {
        if v.is_nan() || v <= 0.0 {
            0
        } else {
            // Saturating float-to-int cast, then clamped into the matrix.
            (v as u32).min(n - 1)
        }
    };
    let min_col = index(((bx0 - ex0) / span).floor(), cols);
    let max_col = index(((bx1 - ex0) / span).ceil() - 1.0, cols).max(min_col);
    let min_row = index(((ey1 - by1) / span).floor(), rows);
    let max_row = index(((ey1 - by0) / span).ceil() - 1.0, rows).max(min_row);
    TileLimits {
        min_col,
        max_col,
        min_row,
        max_row,
    }
}

/// A dataset with a place on the map.
#[derive(Debug)]
pub struct Mapped<'a> {
    pub ds: &'a Dataset,
    pub fp: &'a Footprint,
}

/// The XML writer of the capabilities: indented, into memory.
type Xml = Writer<Vec<u8>>;

/// The capabilities document of `layers` (already in name order), its URLs under
/// `base` (scheme and authority, no trailing slash) and the document's own URL `me`.
/// Written with `quick-xml`, which escapes every text and attribute value.
pub fn capabilities(layers: &[Mapped<'_>], base: &str, me: &str) -> String {
    let mut w = Writer::new_with_indent(Vec::with_capacity(8192 + layers.len() * 16384), b' ', 2);
    document(&mut w, layers, base, me).expect("XML is written to memory");
    let mut x = String::from_utf8(w.into_inner()).expect("the XML writer writes UTF-8");
    x.push('\n');
    x
}

fn document(w: &mut Xml, layers: &[Mapped<'_>], base: &str, me: &str) -> io::Result<()> {
    w.write_event(Event::Decl(BytesDecl::new("1.0", Some("UTF-8"), None)))?;
    w.create_element("Capabilities")
        .with_attributes([
            ("xmlns", "http://www.opengis.net/wmts/1.0"),
            ("xmlns:ows", "http://www.opengis.net/ows/1.1"),
            ("xmlns:xlink", "http://www.w3.org/1999/xlink"),
            ("xmlns:xsi", "http://www.w3.org/2001/XMLSchema-instance"),
            (
                "xsi:schemaLocation",
                "http://www.opengis.net/wmts/1.0 http://schemas.opengis.net/wmts/1.0/wmtsGetCapabilities_response.xsd",
            ),
            ("version", "1.0.0"),
        ])
        .write_inner_content(|w| {
            w.create_element("ows:ServiceIdentification")
                .write_inner_content(|w| {
                    text(w, "ows:Title", "Tessera DEM tiles")?;
                    text(
                        w,
                        "ows:Abstract",
                        "Elevation as Terrarium or Terrain-RGB PNG tiles, and hillshade, colour relief and slope rendered as gdaldem renders them, on the standard WebMercatorQuad and WorldCRS84Quad grids; each layer's abstract says what its pixels are.",
                    )?;
                    text(w, "ows:ServiceType", "OGC WMTS")?;
                    text(w, "ows:ServiceTypeVersion", "1.0.0")
                })?;
            w.create_element("Contents").write_inner_content(|w| {
                // The deepest zoom any layer needs, per grid (the matrix sets list no
                // deeper).
                let mut deepest = [0u8; 2];
                for m in layers {
                    for (i, tms) in TileMatrixSet::ALL.into_iter().enumerate() {
                        deepest[i] = deepest[i].max(m.fp.max_zoom(tms, TILE_PX));
                    }
                }
                for m in layers {
                    for enc in ENCODINGS {
                        layer(w, m, Shows::Heights(enc), base)?;
                    }
                    for kind in render::Kind::ALL {
                        layer(w, m, Shows::Rendered(kind), base)?;
                    }
                }
                for (i, tms) in TileMatrixSet::ALL.into_iter().enumerate() {
                    matrix_set(w, tms, deepest[i])?;
                }
                Ok(())
            })?;
            w.create_element("ServiceMetadataURL")
                .with_attribute(("xlink:href", me))
                .write_empty()?;
            Ok(())
        })?;
    Ok(())
}

/// `<name>value</name>`, the value escaped.
fn text(w: &mut Xml, name: &str, value: &str) -> io::Result<()> {
    w.create_element(name)
        .write_text_content(BytesText::new(value))?;
    Ok(())
}

fn corners(w: &mut Xml, [x0, y0, x1, y1]: [f64; 4]) -> io::Result<()> {
    text(w, "ows:LowerCorner", &format!("{x0} {y0}"))?;
    text(w, "ows:UpperCorner", &format!("{x1} {y1}"))
}

/// What a layer's tiles show.
#[derive(Clone, Copy, Debug)]
enum Shows {
    Heights(Encoding),
    /// A rendered layer with its default options (routes/rendered.rs).
    Rendered(render::Kind),
}

impl Shows {
    /// The layer's identifier suffix, title suffix and abstract.
    fn describe(self) -> (&'static str, &'static str, &'static str) {
        match self {
            Shows::Heights(enc) => (
                enc.name(),
                match enc {
                    Encoding::Terrarium => "Terrarium",
                    Encoding::Mapbox => "Terrain-RGB",
                },
                decoding(enc),
            ),
            Shows::Rendered(render::Kind::Hillshade) => (
                "hillshade",
                "hillshade",
                "Shaded relief as gdaldem hillshade computes it (light from 315 degrees, 45 degrees up): grey levels 1-255; alpha 0 marks no data. Other lights: the tile URL's azimuth, altitude, z_factor and method.",
            ),
            Shows::Rendered(render::Kind::ColorRelief) => (
                "color-relief",
                "colour relief",
                "Heights coloured by the hypsometric ramp, as gdaldem color-relief colours them; alpha 0 marks no data. Other ramps: the tile URL's ramp.",
            ),
            Shows::Rendered(render::Kind::Slope) => (
                "slope",
                "slope",
                "Slope in degrees as gdaldem slope computes it, coloured by the slope ramp (yellow from 25, orange at 30, red at 35, purple at 45 degrees); alpha 0 marks no data.",
            ),
        }
    }
}

fn layer(w: &mut Xml, m: &Mapped<'_>, shows: Shows, base: &str) -> io::Result<()> {
    let name = &m.ds.name;
    let [west, south, east, north] = m.fp.lon_lat;
    let wgs84 = [
        west.clamp(-180.0, 180.0),
        south.clamp(-90.0, 90.0),
        east.clamp(-180.0, 180.0),
        north.clamp(-90.0, 90.0),
    ];
    let (suffix, kind, about) = shows.describe();
    w.create_element("Layer").write_inner_content(|w| {
        text(w, "ows:Title", &format!("{name} ({kind})"))?;
        text(w, "ows:Abstract", about)?;
        w.create_element("ows:WGS84BoundingBox")
            .write_inner_content(|w| corners(w, wgs84))?;
        text(w, "ows:Identifier", &format!("{name}_{suffix}"))?;
        // The box in each grid's own CRS: GDAL takes the layer's extent from the one
        // whose CRS matches the chosen grid's.
        for tms in TileMatrixSet::ALL {
            let b = match tms {
                TileMatrixSet::WorldCrs84Quad => wgs84,
                TileMatrixSet::WebMercatorQuad => m.fp.grid_bounds(tms),
            };
            w.create_element("ows:BoundingBox")
                .with_attribute(("crs", crs_urn(tms)))
                .write_inner_content(|w| corners(w, b))?;
        }
        w.create_element("Style")
            .with_attribute(("isDefault", "true"))
            .write_inner_content(|w| text(w, "ows:Identifier", "default"))?;
        text(w, "Format", "image/png")?;
        for tms in TileMatrixSet::ALL {
            w.create_element("TileMatrixSetLink")
                .write_inner_content(|w| {
                    text(w, "TileMatrixSet", tms.id())?;
                    w.create_element("TileMatrixSetLimits")
                        .write_inner_content(|w| {
                            let bounds = m.fp.grid_bounds(tms);
                            for z in 0..=m.fp.max_zoom(tms, TILE_PX) {
                                let l = tile_limits(tms, bounds, z);
                                w.create_element("TileMatrixLimits")
                                    .write_inner_content(|w| {
                                        text(w, "TileMatrix", &z.to_string())?;
                                        text(w, "MinTileRow", &l.min_row.to_string())?;
                                        text(w, "MaxTileRow", &l.max_row.to_string())?;
                                        text(w, "MinTileCol", &l.min_col.to_string())?;
                                        text(w, "MaxTileCol", &l.max_col.to_string())
                                    })?;
                            }
                            Ok(())
                        })?;
                    Ok(())
                })?;
        }
        // {TileMatrixSet} is the standard identifier, which the tile route accepts as
        // the grid segment (web_grid.rs `grid`).
        // GDAL and QGIS read PNG pixels exactly: alpha marks no-data for them.
        let template = match shows {
            Shows::Heights(enc) => format!(
                "{base}/v1/datasets/{}/{{TileMatrixSet}}/{{TileMatrix}}/{{TileCol}}/{{TileRow}}.png?encoding={}&size={TILE_PX}&nodata=transparent&v={}",
                m.ds.name,
                enc.name(),
                m.ds.content_hash()
            ),
            Shows::Rendered(kind) => format!(
                "{base}/v1/datasets/{}/{{TileMatrixSet}}/{}/{{TileMatrix}}/{{TileCol}}/{{TileRow}}.png?size={TILE_PX}&v={}",
                m.ds.name,
                kind.name(),
                m.ds.content_hash()
            ),
        };
        w.create_element("ResourceURL")
            .with_attributes([
                ("format", "image/png"),
                ("resourceType", "tile"),
                ("template", template.as_str()),
            ])
            .write_empty()?;
        Ok(())
    })?;
    Ok(())
}

fn matrix_set(w: &mut Xml, tms: TileMatrixSet, deepest: u8) -> io::Result<()> {
    let [x0, _, _, y1] = tms.extent();
    w.create_element("TileMatrixSet").write_inner_content(|w| {
        text(w, "ows:Identifier", tms.id())?;
        text(w, "ows:SupportedCRS", crs_urn(tms))?;
        text(w, "WellKnownScaleSet", well_known_scale_set(tms))?;
        for z in 0..=deepest {
            let (cols, rows) = tms.matrix_size(z);
            w.create_element("TileMatrix").write_inner_content(|w| {
                text(w, "ows:Identifier", &z.to_string())?;
                text(
                    w,
                    "ScaleDenominator",
                    &tms.scale_denominator(z, TILE_PX).to_string(),
                )?;
                text(w, "TopLeftCorner", &format!("{x0} {y1}"))?;
                text(w, "TileWidth", &TILE_PX.to_string())?;
                text(w, "TileHeight", &TILE_PX.to_string())?;
                text(w, "MatrixWidth", &cols.to_string())?;
                text(w, "MatrixHeight", &rows.to_string())
            })?;
        }
        Ok(())
    })?;
    Ok(())
}

/// Scheme and authority for the document's absolute URLs, and whether they came
/// from the request's `Host` (routes/base_url.rs): WMTS clients (GDAL, QGIS) do not
/// resolve relative templates, so without one the request is a 400.
fn absolute_base(state: &AppState, headers: &HeaderMap, uri: &Uri) -> ApiResult<(String, bool)> {
    base_url::absolute(state, headers, uri)?
        .map(|b| (b.url, b.from_host))
        .ok_or_else(|| {
            ApiError::bad_request(
                "the WMTS capabilities need absolute URLs: send one valid Host header (host[:port]), or run the server with --public-url",
            )
        })
}

/// The XML response, or its 304, with the given validators.
fn respond(
    state: &AppState,
    headers: &HeaderMap,
    etag: &str,
    last_modified: LastModified,
    pin: bool,
    from_host: bool,
    body: impl FnOnce() -> String,
) -> Response {
    let mut r = if cache::not_modified(headers, etag, last_modified) {
        cache::not_modified_response(etag, last_modified, pin, state.cache_max_age)
    } else {
        let mut r = body().into_response();
        r.headers_mut().insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/xml"),
        );
        cache::set_headers(
            r.headers_mut(),
            etag,
            last_modified,
            pin,
            state.cache_max_age,
        );
        r
    };
    base_url::private(r.headers_mut(), from_host, state.cache_max_age);
    r
}

/// A hash naming the content of several datasets at once (names and content
/// hashes), 16 hex digits, for the ETag of documents about all of them.
pub fn combined_hash<'a>(datasets: impl IntoIterator<Item = &'a Dataset>) -> String {
    let mut s = String::new();
    for d in datasets {
        let _ = writeln!(s, "{} {}", d.name, d.content_hash());
    }
    format!("{:016x}", xxhash_rust::xxh3::xxh3_64(s.as_bytes()))
}

/// The latest modification time of several datasets.
pub fn latest(datasets: &[Arc<Dataset>]) -> LastModified {
    LastModified::new(datasets.iter().filter_map(|d| d.last_modified.time()).max())
}

/// A dataset and its footprint (or why it has none).
pub type MappedDataset = (Arc<Dataset>, Arc<Footprint>);

/// Every available dataset that has a place on a map, with its footprint, in name
/// order (the others are left out: they have no standard-grid tiles).
pub fn mapped_datasets(state: &AppState) -> Vec<MappedDataset> {
    state
        .registry()
        .datasets
        .values()
        .filter(|d| d.available().is_ok())
        .filter_map(|d| footprint(state, d).ok().map(|fp| (d.clone(), fp)))
        .collect()
}

/// `GET /wmts/1.0.0/WMTSCapabilities.xml`: every dataset with a place on a map.
pub async fn all(
    State(state): State<Arc<AppState>>,
    headers: HeaderMap,
    uri: Uri,
) -> ApiResult<Response> {
    let (base, from_host) = absolute_base(&state, &headers, &uri)?;
    let found = mapped_datasets(&state);
    let ds: Vec<Arc<Dataset>> = found.iter().map(|(d, _)| d.clone()).collect();
    let etag = cache::etag(
        &combined_hash(ds.iter().map(AsRef::as_ref)),
        &format!("wmts {base}"),
    );
    Ok(respond(
        &state,
        &headers,
        &etag,
        latest(&ds),
        false,
        from_host,
        || {
            let layers: Vec<Mapped<'_>> =
                found.iter().map(|(d, fp)| Mapped { ds: d, fp }).collect();
            capabilities(&layers, &base, &format!("{base}{}", routes::WMTS))
        },
    ))
}

/// `GET /v1/datasets/{name}/wmts/1.0.0/WMTSCapabilities.xml`: one dataset (404
/// when it has no place on a map).
pub async fn one(
    State(state): State<Arc<AppState>>,
    Segments(name): Segments<String>,
    Params(query): Params,
    headers: HeaderMap,
    uri: Uri,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    let (base, from_host) = absolute_base(&state, &headers, &uri)?;
    let fp = footprint(&state, &ds)?;
    let pin = pinned(&ds, &query);
    let etag = cache::etag(ds.content_hash(), &format!("wmts {base}"));
    let me = format!(
        "{base}{}",
        tessera_shared::api::fill(routes::DATASET_WMTS, &[("name", &ds.name)])
    );
    Ok(respond(
        &state,
        &headers,
        &etag,
        ds.last_modified,
        pin,
        from_host,
        || capabilities(&[Mapped { ds: &ds, fp: &fp }], &base, &me),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::web::tile_matrix::WebTile;

    #[test]
    fn limits_cover_the_box_and_stay_in_the_matrix() {
        let tms = TileMatrixSet::WorldCrs84Quad;
        // 8°–9° E, 46°–47° N at zoom 7: tiles are 180/128 = 1.40625° wide.
        let l = tile_limits(tms, [8.0, 46.0, 9.0, 47.0], 7);
        assert_eq!((l.min_col, l.max_col), (133, 134));
        assert_eq!((l.min_row, l.max_row), (30, 31));
        // The box's corners lie in the tiles named.
        for (c, r) in [(l.min_col, l.min_row), (l.max_col, l.max_row)] {
            let b = WebTile::new(tms, 7, c, r).unwrap().bounds();
            assert!(
                b[0] < 9.0 && b[2] > 8.0 && b[1] < 47.0 && b[3] > 46.0,
                "{b:?}"
            );
        }
        // The whole world, and beyond, is the whole matrix.
        let w = tile_limits(tms, [-400.0, -100.0, 400.0, 100.0], 2);
        assert_eq!((w.min_col, w.max_col, w.min_row, w.max_row), (0, 7, 0, 3));
        // A box ending exactly on a tile edge does not reach into the next tile.
        let e = tile_limits(tms, [0.0, 0.0, 180.0, 90.0], 0);
        assert_eq!((e.min_col, e.max_col, e.min_row, e.max_row), (1, 1, 0, 0));
    }

    #[test]
    fn dataset_strings_are_escaped() {
        use super::super::xml_escape;
        assert_eq!(
            xml_escape("a<b>&\"c\"'\u{1}d"),
            "a&lt;b&gt;&amp;&quot;c&quot;&apos;d"
        );
    }
}
