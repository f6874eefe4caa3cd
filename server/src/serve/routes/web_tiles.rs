//! Web-map views of a dataset: height tiles as Terrarium or Terrain-RGB PNGs, and a
//! TileJSON document pointing at them, so MapLibre-style clients and GIS tools can
//! read the same pyramid (docs/ARCHITECTURE.md#derived-outputs).
//!
//! A PNG tile is one pyramid tile in the dataset's own grid (`z` is the pyramid
//! level, `x` east, `y` south, both from 0): `T × T` pixels, pixel `(i, j)` being
//! tile sample `(i, j)`. The last row and column of the `(T+1)²` samples, shared
//! with the next tile east and south, are dropped, as web tiles do not overlap.
//! Tiles line up with a Web Mercator map only when the DEM itself is in that grid;
//! maps use the standard grids (routes/web_grid.rs) instead.

use super::{Params, Segments, base_url, dataset, level, pinned, stored_record, tile, xml_escape};
use crate::http::cache;
use crate::http::error::{ApiError, ApiResult};
use crate::serve::compute::{Kind, Stop};
use crate::serve::dataset::Dataset;
use crate::serve::{AppState, TilesServed};
pub use crate::web::encoding::{Encoding, mapbox, terrarium};
use axum::Json;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, Uri, header};
use axum::response::{IntoResponse, Response};
use bytes::Bytes;
use std::sync::Arc;
use tessera_shared::codec::{self, CodecError};
use tessera_shared::{GeoRef, Quantization, TileId};

/// The `T × T` RGB pixels of a tile's `(T+1)²` quantized heights.
pub fn render(heights: &[u16], tile_size: usize, q: &Quantization, encoding: Encoding) -> Vec<u8> {
    let side = tile_size + 1;
    assert_eq!(heights.len(), side * side, "a tile has (T+1)² heights");
    let mut rgb = Vec::with_capacity(tile_size * tile_size * 3);
    for row in heights.chunks_exact(side).take(tile_size) {
        for &h in &row[..tile_size] {
            rgb.extend_from_slice(&encoding.rgb(q.height(h)));
        }
    }
    rgb
}

/// An 8-bit RGB PNG of `side × side` pixels.
pub fn encode_png(rgb: &[u8], side: u32) -> Result<Vec<u8>, png::EncodingError> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, side, side);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header()?;
    w.write_image_data(rgb)?;
    w.finish()?;
    Ok(out)
}

/// Why a PNG tile could not be made.
enum PngFailure {
    Corrupt(CodecError),
    Encode(png::EncodingError),
}

/// The API error for a PNG that could not be made (the codec's detail goes to the
/// log; the body says what it means).
fn png_error(state: &AppState, ds: &Dataset, tile: TileId, f: PngFailure) -> ApiError {
    match f {
        PngFailure::Corrupt(e) => {
            state.metrics.corrupt_read(ds.mark_undecodable(tile));
            tracing::error!(dataset = %ds.name, %tile, error = %e, "record does not decode");
            ApiError::internal(format!(
                "{tile}: record passes its checksum but its height data does not decode"
            ))
        }
        PngFailure::Encode(e) => {
            tracing::error!(dataset = %ds.name, %tile, error = %e, "PNG encoding failed");
            ApiError::internal(format!("{tile}: cannot encode the PNG"))
        }
    }
}

/// `GET /v1/datasets/{name}/{z}/{x}/{y}.png?encoding=terrarium|mapbox`: one tile's
/// heights as a PNG (see the module documentation).
pub async fn png(
    State(state): State<Arc<AppState>>,
    Segments((name, z, x, y)): Segments<(String, String, String, String)>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let Some(y) = y.strip_suffix(".png") else {
        return Err(ApiError::not_found(
            "no such endpoint; PNG tiles are /v1/datasets/{name}/{z}/{x}/{y}.png (see API.md)",
        ));
    };
    let ds = dataset(&state, &name)?;
    let encoding = Encoding::from_query(query.get("encoding").map(String::as_str))?;
    let level = level(&ds, &z)?;
    let tile = tile(level, &x, y)?;
    let (_, record) = stored_record(&state, &ds, tile).await?;
    let pin = pinned(&ds, &query);
    let etag = cache::etag(
        ds.content_hash(),
        &format!(
            "png {} {}/{}/{}",
            encoding.name(),
            level,
            tile.x(),
            tile.y()
        ),
    );
    if let Some(r) = cache::revalidate(&headers, &etag, ds.last_modified, pin, state.cache_max_age)
    {
        return Ok(r);
    }
    let geometry = *ds.pyramid.geometry();
    let layout = ds.pyramid.record_layout();
    let q = ds.pyramid.metadata().quantization;
    let (st, d) = (state.clone(), ds.clone());
    let flight = format!(
        "{} png {} {}/{}/{}",
        ds.content_hash(),
        encoding.name(),
        level,
        tile.x(),
        tile.y()
    );
    // One PNG per distinct tile at a time, admitted and cancellable; decoding and
    // compressing a big tile take milliseconds: keep them off the runtime.
    let png = state
        .compute
        .run_blocking(Kind::PngTile, flight, move |ticket| {
            let t = geometry.tile_size();
            // Decoded heights, RGB and the encoder's buffers.
            let samples = u64::from(t + 1).pow(2);
            let _memory = ticket.reserve(samples * 16).map_err(Stop::into_error)?;
            let decoded = codec::decode_record(&record, layout)
                .map_err(|e| png_error(&st, &d, tile, PngFailure::Corrupt(e)))?;
            ticket.check().map_err(Stop::into_error)?;
            let rgb = render(&decoded.heights, t as usize, &q, encoding);
            let png =
                encode_png(&rgb, t).map_err(|e| png_error(&st, &d, tile, PngFailure::Encode(e)))?;
            Ok(ticket.made(Bytes::from(png), 1))
        })
        .await?;
    let len = png.bytes.len();
    let mut r = Response::new(png.body());
    let h = r.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static("image/png"));
    h.insert(header::CONTENT_LENGTH, HeaderValue::from(len));
    cache::set_headers(h, &etag, ds.last_modified, pin, state.cache_max_age);
    r.extensions_mut().insert(TilesServed(1));
    Ok(r)
}

/// The TileJSON 3.0.0 document of a dataset's own-grid tiles, their URLs under
/// `base` (scheme and authority, or `""` for server-relative URLs).
///
/// These tiles are the pyramid's own grid, not Web Mercator, so the document must
/// not let a map place them as XYZ tiles: `scheme` is `"tessera-dataset"` (not one
/// of TileJSON's `xyz`/`tms`, so a validating client refuses the source instead of
/// drawing it in the wrong place), there are no `bounds`, `crs` names the dataset's
/// own CRS, and `standard_grids` links the TileJSON of the tiles maps should use
/// (routes/web_grid.rs).
pub fn tilejson_doc(
    ds: &Dataset,
    base: &str,
    encoding: Encoding,
    attribution: Option<&str>,
) -> serde_json::Value {
    let m = ds.pyramid.metadata();
    let standard = |grid: &str| {
        format!(
            "{base}/v1/datasets/{}/{grid}/tilejson.json?encoding={}",
            ds.name,
            encoding.name()
        )
    };
    let mut doc = tilejson::tilejson! {
        tiles: vec![format!(
            "{base}/v1/datasets/{}/{{z}}/{{x}}/{{y}}.png?encoding={}&v={}",
            ds.name,
            encoding.name(),
            m.content_hash
        )],
        name: ds.name.clone(),
        description: "Height tiles in the dataset's own grid: z is the pyramid level, x and y its tile columns and rows. For web maps use a standard grid (standard_grids).".to_string(),
        minzoom: 0,
        maxzoom: ds.pyramid.geometry().finest().get(),
        scheme: "tessera-dataset".to_string(),
    };
    doc.attribution = attribution.map(xml_escape);
    // Beyond TileJSON's own fields.
    let more = &mut doc.other;
    more.insert("tileSize".into(), m.tile_size.into());
    more.insert("encoding".into(), encoding.name().into());
    more.insert(
        "standard_grids".into(),
        serde_json::json!({
            "WebMercatorQuad": standard("webmercator"),
            "WorldCRS84Quad": standard("crs84"),
        }),
    );
    if let Some(crs) = m.georef.as_ref().and_then(GeoRef::crs) {
        more.insert("crs".into(), crs.into());
    }
    // As a JSON value, whose keys serialize sorted as the documents always were.
    serde_json::to_value(doc).expect("a TileJSON document serializes")
}

/// `GET /v1/datasets/{name}/tilejson.json`: see [`tilejson_doc`]. Its URLs are
/// absolute (routes/base_url.rs), from the request's `Host` when nothing is configured.
pub async fn tilejson(
    State(state): State<Arc<AppState>>,
    Segments(name): Segments<String>,
    Params(query): Params,
    headers: HeaderMap,
    uri: Uri,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    let base = base_url::absolute(&state, &headers, &uri)?;
    let encoding = Encoding::from_query(query.get("encoding").map(String::as_str))?;
    let pin = pinned(&ds, &query);
    let (url, from_host) = base.map_or((String::new(), false), |b| (b.url, b.from_host));
    // The document names the base URL and the encoding, so the ETag does too.
    let etag = cache::etag(
        ds.content_hash(),
        // The attribution is configuration, not content: a new one must change the tag.
        &format!(
            "tilejson {url} {} {:?}",
            encoding.name(),
            state.web.config.attribution
        ),
    );
    let revalidated =
        cache::revalidate(&headers, &etag, ds.last_modified, pin, state.cache_max_age);
    let mut r = if let Some(r) = revalidated {
        r
    } else {
        let attribution = state.web.config.attribution.as_deref();
        let mut r = Json(tilejson_doc(&ds, &url, encoding, attribution)).into_response();
        cache::set_headers(
            r.headers_mut(),
            &etag,
            ds.last_modified,
            pin,
            state.cache_max_age,
        );
        r
    };
    base_url::private(r.headers_mut(), from_host, state.cache_max_age);
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// TileJSON and the dataset description of a real (small) pyramid, as clients
    /// see them. Builds are deterministic, so the content hash in them is too.
    #[test]
    fn tilejson_and_dataset_documents_are_stable() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("snap.tess");
        let opts = crate::builder::BuildOptions {
            tile_size: 64,
            ..crate::builder::BuildOptions::default()
        };
        crate::builder::build("synthetic:257:3", &file, &opts).unwrap();
        let ds = Dataset::open("snap".into(), &file).unwrap();
        let tilejson = tilejson_doc(&ds, "", Encoding::Terrarium, Some("© <test>"));
        insta::assert_snapshot!("tilejson", serde_json::to_string_pretty(&tilejson).unwrap());
        let info = super::super::datasets::describe(&ds);
        insta::assert_snapshot!("dataset", serde_json::to_string_pretty(&info).unwrap());
    }

    fn terrarium_height([r, g, b]: [u8; 3]) -> f64 {
        f64::from(r) * 256.0 + f64::from(g) + f64::from(b) / 256.0 - 32768.0
    }

    #[test]
    fn render_drops_the_shared_border_and_encodes_a_png() {
        let t = 4usize;
        let side = t + 1;
        let heights: Vec<u16> = (0..side * side).map(|i| i as u16).collect();
        let q = Quantization {
            offset: -100.0,
            scale: 0.5,
            max_error: 0.0,
        };
        let rgb = render(&heights, t, &q, Encoding::Terrarium);
        assert_eq!(rgb.len(), t * t * 3);
        for j in 0..t {
            for i in 0..t {
                let p = (j * t + i) * 3;
                let px = [rgb[p], rgb[p + 1], rgb[p + 2]];
                let want = q.height(heights[j * side + i]);
                assert_eq!(terrarium_height(px), want, "pixel ({i}, {j})");
            }
        }
        let png = encode_png(&rgb, t as u32).unwrap();
        let mut reader = png::Decoder::new(std::io::Cursor::new(png))
            .read_info()
            .unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (4, 4));
        assert_eq!(info.color_type, png::ColorType::Rgb);
        assert_eq!(&buf[..info.buffer_size()], &rgb[..]);
    }

    #[test]
    fn attributions_are_escaped() {
        assert_eq!(xml_escape("a<b>&\"c\""), "a&lt;b&gt;&amp;&quot;c&quot;");
    }
}
