//! Web-map views of a dataset: height tiles as Terrarium or Terrain-RGB PNGs, and a
//! TileJSON document pointing at them, so MapLibre-style clients and GIS tools can
//! read the same pyramid (DESIGN §4).
//!
//! A PNG tile is one pyramid tile in the dataset's own grid (`z` is the pyramid
//! level, `x` east, `y` south, both from 0): `T × T` pixels, pixel `(i, j)` being
//! tile sample `(i, j)`. The last row and column of the `(T+1)²` samples, shared
//! with the next tile east and south, are dropped, as web tiles do not overlap.
//! Tiles line up with a Web Mercator map only when the DEM itself is in that grid.

use super::{Params, Segments, dataset, level, pinned, stored_record, tile};
use crate::serve::dataset::Dataset;
use crate::serve::error::{ApiError, ApiResult};
use crate::serve::{AppState, TilesServed, cache};
use axum::Json;
use axum::body::Body;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, header};
use axum::response::{IntoResponse, Response};
use std::sync::Arc;
use tessera_shared::Quantization;
use tessera_shared::codec::{self, CodecError};

/// How heights become the colours of a PNG tile.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// Mapzen Terrarium: `h = R·256 + G + B/256 − 32768` (1/256 m steps).
    Terrarium,
    /// Mapbox Terrain-RGB: `h = −10000 + (R·65536 + G·256 + B)·0.1` (0.1 m steps).
    Mapbox,
}

impl Encoding {
    /// What `?encoding=` accepts.
    pub const ALLOWED: &str = "terrarium, mapbox";

    /// The encoding a query asks for (Terrarium when it names none), or 400.
    pub fn from_query(value: Option<&str>) -> ApiResult<Self> {
        match value {
            None | Some("terrarium") => Ok(Self::Terrarium),
            Some("mapbox") => Ok(Self::Mapbox),
            Some(other) => Err(ApiError::bad_request(format!(
                "unknown encoding {other:?}: allowed values are {}",
                Self::ALLOWED
            ))),
        }
    }

    pub const fn name(self) -> &'static str {
        match self {
            Self::Terrarium => "terrarium",
            Self::Mapbox => "mapbox",
        }
    }

    /// The colour of a height in metres.
    pub fn rgb(self, h: f64) -> [u8; 3] {
        match self {
            Self::Terrarium => terrarium(h),
            Self::Mapbox => mapbox(h),
        }
    }
}

/// Terrarium colour of a height in metres: `v = h + 32768` clamped to
/// `[0, 65536 − 1/256]`, `R = ⌊v / 256⌋`, `G = ⌊v⌋ mod 256`, `B = ⌊frac(v)·256⌋`.
/// Decoding gives `h` to within 1/256 m (rounded down) inside the range.
pub fn terrarium(h: f64) -> [u8; 3] {
    let v = (h + 32768.0).clamp(0.0, 65536.0 - 1.0 / 256.0);
    let v = if v.is_nan() { 0.0 } else { v };
    let whole = v.floor();
    [
        (v / 256.0).floor() as u8,
        (whole as u32 % 256) as u8,
        ((v - whole) * 256.0).floor() as u8,
    ]
}

/// Terrain-RGB colour of a height in metres: `v = round((h + 10000) / 0.1)` clamped
/// to `0..=2^24 − 1`, `R = v >> 16`, `G = (v >> 8) & 255`, `B = v & 255`.
/// Decoding gives `h` to within 0.05 m inside the range.
pub fn mapbox(h: f64) -> [u8; 3] {
    let v = ((h + 10000.0) / 0.1).round().clamp(0.0, 16_777_215.0);
    // NaN casts to 0.
    let v = v as u32;
    [(v >> 16) as u8, (v >> 8) as u8, v as u8]
}

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
    let (_, record) = stored_record(&state, &ds, tile)?;
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
    if cache::not_modified(&headers, &etag, ds.last_modified) {
        return Ok(cache::not_modified_response(
            &etag,
            ds.last_modified,
            pin,
            state.cache_max_age,
        ));
    }
    let geometry = *ds.pyramid.geometry();
    let layout = ds.pyramid.record_layout();
    let q = ds.pyramid.metadata().quantization;
    // Decoding and compressing a big tile takes milliseconds: keep it off the runtime.
    let made = tokio::task::spawn_blocking(move || {
        let decoded = codec::decode_record(&record, layout).map_err(PngFailure::Corrupt)?;
        let t = geometry.tile_size();
        let rgb = render(&decoded.heights, t as usize, &q, encoding);
        encode_png(&rgb, t).map_err(PngFailure::Encode)
    })
    .await
    .map_err(|e| ApiError::internal(format!("{tile}: PNG task failed: {e}")))?;
    let png = match made {
        Ok(png) => png,
        Err(PngFailure::Corrupt(e)) => {
            state.metrics.corrupt_read(ds.mark_undecodable(tile));
            // The codec's detail goes to the log; the body says what it means.
            tracing::error!(dataset = %ds.name, %tile, error = %e, "record does not decode");
            return Err(ApiError::internal(format!(
                "{tile}: record passes its checksum but its height data does not decode"
            )));
        }
        Err(PngFailure::Encode(e)) => {
            tracing::error!(dataset = %ds.name, %tile, error = %e, "PNG encoding failed");
            return Err(ApiError::internal(format!("{tile}: cannot encode the PNG")));
        }
    };
    let len = png.len();
    let mut r = Response::new(Body::from(png));
    let h = r.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static("image/png"));
    h.insert(header::CONTENT_LENGTH, HeaderValue::from(len));
    cache::set_headers(h, &etag, ds.last_modified, pin, state.cache_max_age);
    r.extensions_mut().insert(TilesServed(1));
    Ok(r)
}

/// Whether `s` is a plain `host[:port]`: host names, IPv4 and bracketed IPv6
/// addresses and ports only (RFC 9110 §7.2), nothing that could change a URL's meaning.
fn valid_host(s: &str) -> bool {
    !s.is_empty()
        && s.len() <= 255
        && s.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b".-_:[]".contains(&b))
}

/// The first element of the only `name` header, if there is exactly one such header.
fn forwarded<'a>(headers: &'a HeaderMap, name: &str) -> ApiResult<Option<&'a str>> {
    let mut all = headers.get_all(name).iter();
    let Some(v) = all.next() else {
        return Ok(None);
    };
    let bad = || ApiError::bad_request(format!("invalid {name} header"));
    if all.next().is_some() {
        return Err(bad());
    }
    let s = v.to_str().map_err(|_| bad())?;
    // A chain of proxies appends; the first element is what the client used.
    Ok(Some(s.split(',').next().unwrap_or("").trim()))
}

/// Scheme and authority for absolute URLs, or `""` for URLs relative to the server.
///
/// The `Host` header is never used: it is whatever the client sent, and a CDN that
/// caches the document would hand one client's `Host` to everyone. The configured
/// `--public-url` wins; `X-Forwarded-Host`/`X-Forwarded-Proto` count only with
/// `--trust-forwarded` (a proxy in front sets them); otherwise the URLs are relative.
pub fn base_url(state: &AppState, headers: &HeaderMap) -> ApiResult<String> {
    if let Some(u) = &state.public_url {
        return Ok(u.clone());
    }
    if !state.trust_forwarded {
        return Ok(String::new());
    }
    let Some(host) = forwarded(headers, "x-forwarded-host")? else {
        return Ok(String::new());
    };
    if !valid_host(host) {
        return Err(ApiError::bad_request("invalid X-Forwarded-Host header"));
    }
    let proto = match forwarded(headers, "x-forwarded-proto")? {
        None => "http",
        Some(p) if p.eq_ignore_ascii_case("http") => "http",
        Some(p) if p.eq_ignore_ascii_case("https") => "https",
        Some(_) => {
            return Err(ApiError::bad_request(
                "invalid X-Forwarded-Proto header: want http or https",
            ));
        }
    };
    Ok(format!("{proto}://{host}"))
}

/// `&`, `<`, `>` and `"` as HTML entities (TileJSON attributions are shown as HTML).
fn html_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            c => out.push(c),
        }
    }
    out
}

/// The TileJSON 3.0.0 document of a dataset, its tile URLs under `base` (scheme
/// and authority, or `""` for server-relative URLs).
///
/// TileJSON `bounds` are WGS84 longitudes and latitudes, so they are given only for
/// datasets georeferenced in EPSG:4326 (clamped to ±180°, ±90°). A dataset in any
/// other CRS gets no `bounds` but a `crs` field (e.g. `"EPSG:32632"`) instead; one
/// with no georeferencing, or no EPSG code, gets neither.
pub fn tilejson_doc(ds: &Dataset, base: &str, encoding: Encoding) -> serde_json::Value {
    let m = ds.pyramid.metadata();
    let mut doc = serde_json::json!({
        "tilejson": "3.0.0",
        "name": ds.name,
        "tiles": [format!(
            "{base}/v1/datasets/{}/{{z}}/{{x}}/{{y}}.png?encoding={}&v={}",
            ds.name,
            encoding.name(),
            m.content_hash
        )],
        "minzoom": 0,
        "maxzoom": ds.pyramid.geometry().finest().get(),
        "tileSize": m.tile_size,
        "encoding": encoding.name(),
        "scheme": "xyz",
        "attribution": html_escape(&m.source),
    });
    if let Some(g) = &m.georef {
        if g.epsg == Some(4326) {
            let [w, s, e, n] = g.extent(m.width, m.height);
            doc["bounds"] = serde_json::json!([
                w.clamp(-180.0, 180.0),
                s.clamp(-90.0, 90.0),
                e.clamp(-180.0, 180.0),
                n.clamp(-90.0, 90.0),
            ]);
        } else if let Some(crs) = g.crs() {
            doc["crs"] = serde_json::Value::String(crs);
        }
    }
    doc
}

/// `GET /v1/datasets/{name}/tilejson.json`: see [`tilejson_doc`].
pub async fn tilejson(
    State(state): State<Arc<AppState>>,
    Segments(name): Segments<String>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    let base = base_url(&state, &headers)?;
    let encoding = Encoding::from_query(query.get("encoding").map(String::as_str))?;
    let pin = pinned(&ds, &query);
    // The document names the base URL and the encoding, so the ETag does too.
    let etag = cache::etag(
        ds.content_hash(),
        &format!("tilejson {base} {}", encoding.name()),
    );
    if cache::not_modified(&headers, &etag, ds.last_modified) {
        return Ok(cache::not_modified_response(
            &etag,
            ds.last_modified,
            pin,
            state.cache_max_age,
        ));
    }
    let mut r = Json(tilejson_doc(&ds, &base, encoding)).into_response();
    cache::set_headers(
        r.headers_mut(),
        &etag,
        ds.last_modified,
        pin,
        state.cache_max_age,
    );
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
        let opts = crate::build::BuildOptions {
            tile_size: 64,
            ..crate::build::BuildOptions::default()
        };
        crate::build::build("synthetic:257:3", &file, &opts).unwrap();
        let ds = Dataset::open("snap".into(), &file).unwrap();
        let tilejson = tilejson_doc(&ds, "", Encoding::Terrarium);
        insta::assert_snapshot!("tilejson", serde_json::to_string_pretty(&tilejson).unwrap());
        let info = super::super::datasets::describe(&ds);
        insta::assert_snapshot!("dataset", serde_json::to_string_pretty(&info).unwrap());
    }

    fn terrarium_height([r, g, b]: [u8; 3]) -> f64 {
        f64::from(r) * 256.0 + f64::from(g) + f64::from(b) / 256.0 - 32768.0
    }

    fn mapbox_height([r, g, b]: [u8; 3]) -> f64 {
        -10000.0 + f64::from(u32::from(r) * 65536 + u32::from(g) * 256 + u32::from(b)) * 0.1
    }

    /// Heights from −10000 to 9000 m in irregular steps, with fractions of all kinds.
    fn heights() -> impl Iterator<Item = f64> {
        (0..=190_000).map(|i| -10000.0 + f64::from(i) * 0.100_003_7)
    }

    #[test]
    fn terrarium_round_trips_within_a_256th() {
        for h in heights().chain([0.0, -0.001, 0.001, -1.0 / 256.0, 8848.86, -10000.0]) {
            let back = terrarium_height(terrarium(h));
            assert!(
                back <= h && h - back < 1.0 / 256.0,
                "{h} -> {back} ({:?})",
                terrarium(h)
            );
        }
        assert_eq!(terrarium(0.0), [128, 0, 0]);
        assert_eq!(terrarium(-1.0), [127, 255, 0]);
        assert_eq!(terrarium(1.5), [128, 1, 128]);
    }

    #[test]
    fn mapbox_round_trips_within_5_cm() {
        for h in heights().chain([0.0, -0.04, 0.05, 8848.86, -10000.0]) {
            let back = mapbox_height(mapbox(h));
            assert!((back - h).abs() <= 0.05 + 1e-9, "{h} -> {back}");
        }
        assert_eq!(mapbox(-10000.0), [0, 0, 0]);
        assert_eq!(mapbox(0.0), [1, 134, 160]); // 100000 = 0x0186A0
    }

    #[test]
    fn out_of_range_heights_clamp() {
        assert_eq!(terrarium(-40000.0), [0, 0, 0]);
        assert_eq!(terrarium(-32768.0), [0, 0, 0]);
        assert_eq!(terrarium(40000.0), [255, 255, 255]);
        assert_eq!(terrarium(f64::NAN), [0, 0, 0]);
        assert_eq!(mapbox(-10000.1), [0, 0, 0]);
        assert_eq!(mapbox(-1e9), [0, 0, 0]);
        assert_eq!(mapbox(1e9), [255, 255, 255]);
        assert_eq!(mapbox(f64::NAN), [0, 0, 0]);
        // The top of Terrain-RGB's range is −10000 + (2^24 − 1)·0.1 m.
        assert_eq!(mapbox(1_667_721.5), [255, 255, 255]);
    }

    #[test]
    fn encoding_from_query() {
        assert_eq!(Encoding::from_query(None).unwrap(), Encoding::Terrarium);
        assert_eq!(
            Encoding::from_query(Some("terrarium")).unwrap(),
            Encoding::Terrarium
        );
        assert_eq!(
            Encoding::from_query(Some("mapbox")).unwrap(),
            Encoding::Mapbox
        );
        let e = Encoding::from_query(Some("webp")).unwrap_err();
        assert_eq!(e.status, axum::http::StatusCode::BAD_REQUEST);
        assert!(e.message.contains("terrarium, mapbox"), "{}", e.message);
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
    fn hosts_are_checked() {
        for good in ["tiles.example:8080", "[::1]:80", "127.0.0.1"] {
            assert!(valid_host(good), "{good:?}");
        }
        for bad in ["evil/path", "a b", "x@y", "", "a\"b"] {
            assert!(!valid_host(bad), "{bad:?}");
        }
        assert_eq!(html_escape("a<b>&\"c\""), "a&lt;b&gt;&amp;&quot;c&quot;");
    }
}
