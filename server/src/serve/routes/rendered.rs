//! Rendered terrain tiles for 2-D maps (web/render/, DECISIONS.md "Rendered terrain
//! tiles"): hillshade, colour relief and slope on the standard grids, as PNG or WebP,
//! with a TileJSON document per layer and options.
//!
//! - `GET /v1/datasets/{name}/{grid}/{layer}/{z}/{x}/{y}.png|.webp?size=&…`
//! - `GET /v1/datasets/{name}/{grid}/{layer}/tilejson.json?size=&format=&…`
//!
//! `{layer}` is `hillshade` (`azimuth`, `altitude`, `z_factor`, `method`),
//! `color-relief` (`ramp`) or `slope` (`unit`, `ramp`). Options are `gdaldem`'s;
//! an unknown option, or one of another layer, is a 400 naming it (a typo must not
//! silently draw the default).

use super::web_grid::{self, Asked, grid, grid_tilejson, size, web_tile};
use super::{Params, Segments, dataset, pinned};
use crate::http::error::{ApiError, ApiResult, quoted};
use crate::serve::AppState;
use crate::serve::compute::{Kind as ComputeKind, Ticket};
use crate::serve::dataset::Dataset;
use crate::serve::web_cache::{Look, MadeKey, WebTiles};
use crate::web::encoding::{ImageFormat, TileFormat};
use crate::web::footprint::Footprint;
use crate::web::render::ground::{self, Radii};
use crate::web::render::hillshade::{Hillshade, Method};
use crate::web::render::ramp::{self, RampSpec};
use crate::web::render::{self, Bordered, Kind, Layer, slope};
use crate::web::resample;
use crate::web::tile_matrix::TileMatrixSet;
use axum::extract::State;
use axum::http::{HeaderMap, Uri};
use axum::response::Response;
use bytes::Bytes;
use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

/// Query parameters every rendered route takes besides a layer's options: the
/// tile size, the content pin, and an API key some map clients append.
const COMMON: [&str; 3] = ["size", "v", "key"];

/// A layer as asked for: what to draw, its canonical description (the cache key and
/// ETag variant), and the query that asks for it again (TileJSON's URLs).
#[derive(Clone, Debug)]
pub struct Style {
    pub layer: Layer,
    pub canonical: String,
    pub query: String,
}

/// The layer a path segment names, or 404 naming the layers.
pub fn kind(raw: &str) -> ApiResult<Kind> {
    Kind::parse(raw).ok_or_else(|| {
        ApiError::not_found(format!(
            "unknown layer {}: the rendered layers are hillshade, color-relief and slope",
            quoted(raw)
        ))
    })
}

/// The options a layer takes.
const fn options(kind: Kind) -> &'static [&'static str] {
    match kind {
        Kind::Hillshade => &["azimuth", "altitude", "z_factor", "method"],
        Kind::ColorRelief => &["ramp"],
        Kind::Slope => &["unit", "ramp"],
    }
}

fn number(query: &HashMap<String, String>, name: &str, default: f64) -> ApiResult<f64> {
    query.get(name).map_or(Ok(default), |v| {
        v.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| ApiError::bad_request(format!("{name}: {} is not a number", quoted(v))))
    })
}

/// A ramp by name: one loaded with `--ramp`, else a built-in one.
fn ramp_spec(ramps: &BTreeMap<String, RampSpec>, name: &str) -> ApiResult<RampSpec> {
    if let Some(r) = ramps.get(name) {
        return Ok(r.clone());
    }
    ramp::built_in(name).ok_or_else(|| {
        let mut names: Vec<&str> = ramp::BUILT_IN.iter().map(|(n, _, _)| *n).collect();
        names.extend(ramps.keys().map(String::as_str));
        ApiError::bad_request(format!(
            "ramp: unknown ramp {}; the ramps are {} (more with `serve --ramp NAME=FILE`)",
            quoted(name),
            names.join(", ")
        ))
    })
}

/// The layer `kind` of `ds` with the query's options, or 400 naming the option.
pub fn style(
    ramps: &BTreeMap<String, RampSpec>,
    ds: &Dataset,
    kind: Kind,
    query: &HashMap<String, String>,
    more: &[&str],
) -> ApiResult<Style> {
    let mut allowed: Vec<&str> = options(kind).to_vec();
    allowed.extend(COMMON.iter().chain(more));
    if let Some(k) = web_grid::unknown_parameter(query, &allowed) {
        return Err(ApiError::bad_request(format!(
            "unknown parameter {} for the {} layer: it takes {}",
            quoted(k),
            kind.name(),
            allowed.join(", ")
        )));
    }
    let m = ds.pyramid.metadata();
    let hash = |r: &ramp::Ramp| xxhash_rust::xxh3::xxh3_64(r.to_string().as_bytes());
    Ok(match kind {
        Kind::Hillshade => {
            let d = Hillshade::default();
            let method = query.get("method").map_or(Ok(d.method), |v| {
                Method::parse(v).ok_or_else(|| {
                    ApiError::bad_request(format!(
                        "method: unknown method {}: the methods are {}",
                        quoted(v),
                        Method::ALLOWED
                    ))
                })
            })?;
            let h = Hillshade::new(
                number(query, "azimuth", d.azimuth)?,
                number(query, "altitude", d.altitude)?,
                number(query, "z_factor", d.z_factor)?,
                method,
            )
            .map_err(|(p, why)| ApiError::bad_request(format!("{p}: {why}")))?;
            let q = format!(
                "azimuth={}&altitude={}&z_factor={}&method={}",
                h.azimuth,
                h.altitude,
                h.z_factor,
                h.method.name()
            );
            Style {
                layer: Layer::Hillshade(h),
                canonical: format!("hillshade {q}"),
                query: q,
            }
        }
        Kind::ColorRelief => {
            let name = query.get("ramp").map_or("hypsometric", String::as_str);
            let r = ramp_spec(ramps, name)?
                .resolve(Some((m.min_height, m.max_height)))
                .expect("a range resolves every ramp");
            let q = format!("ramp={name}");
            Style {
                canonical: format!("color-relief {q} {:016x}", hash(&r)),
                layer: Layer::ColorRelief(Arc::new(r)),
                query: q,
            }
        }
        Kind::Slope => {
            let unit = query.get("unit").map_or(Ok(slope::Unit::Degrees), |v| {
                slope::Unit::parse(v).ok_or_else(|| {
                    ApiError::bad_request(format!(
                        "unit: unknown unit {}: the units are {}",
                        quoted(v),
                        slope::Unit::ALLOWED
                    ))
                })
            })?;
            let default = match unit {
                slope::Unit::Degrees => "slope",
                slope::Unit::Percent => "slope-percent",
            };
            let name = query.get("ramp").map_or(default, String::as_str);
            let r = ramp_spec(ramps, name)?.resolve(None).ok_or_else(|| {
                ApiError::bad_request(format!(
                    "ramp: {} gives percentages, which mean nothing for slopes; give slopes in {}",
                    quoted(name),
                    unit.name()
                ))
            })?;
            let q = format!("unit={}&ramp={name}", unit.name());
            Style {
                canonical: format!("slope {q} {:016x}", hash(&r)),
                layer: Layer::Slope(unit, Arc::new(r)),
                query: q,
            }
        }
    })
}

/// Working memory of a rendered tile per pixel: the bordered `f64` heights and
/// flags, RGBA, and the encoder's buffers.
const RENDERED_BYTES_PER_PIXEL: u64 = 32;

/// The body the grid's lon/lat are on: WGS 84 for the Earth (the grids' datum),
/// else the dataset's own body (its lon/lat are the grid's, unshifted).
fn radii(fp: &Footprint) -> Radii {
    match fp.crs().body_radii() {
        Some((a, b)) if !fp.crs().is_earth() => Radii { a, b },
        _ => Radii::WGS84,
    }
}

/// The encoded tile: empty beyond the dataset's bounds (what its TileJSON states),
/// transparent where it has no terrain.
pub fn make(
    web: &WebTiles,
    ds: &Dataset,
    fp: &Footprint,
    key: MadeKey,
    layer: &Layer,
    ticket: &Ticket,
) -> Result<Bytes, web_grid::Failure> {
    if !fp.meets(key.tile) {
        return Ok(Bytes::new());
    }
    let TileFormat::Image(format) = key.format else {
        unreachable!("rendered tiles are images")
    };
    let px = key.px as usize;
    let working = (u64::from(key.px) + 2).pow(2) * RENDERED_BYTES_PER_PIXEL;
    let encode = |rgba: &[u8]| {
        format
            .encode(rgba, key.px)
            .map(Bytes::from)
            .map_err(web_grid::Failure::EncodeImage)
    };
    let Some(plan) = resample::plan(fp, ds.pyramid.geometry(), key.tile, key.px) else {
        let _memory = ticket
            .reserve(working)
            .map_err(web_grid::Failure::Stopped)?;
        return encode(&vec![0; px * px * 4]);
    };
    let (sources, memory) = web_grid::plan_sources(web, ds, &plan, working, ticket)?;
    let sampled = plan.sample_bordered(&sources, 1);
    drop(sources);
    let spacing = ground::row_spacing(key.tile, key.px, radii(fp), 0, px);
    let grid = Bordered {
        px,
        heights: &sampled.heights,
        terrain: &sampled.terrain,
    };
    let rgba = render::paint(layer, grid, &spacing);
    let encoded = if matches!(layer, Layer::Hillshade(_)) {
        // Grey: two bytes a pixel instead of four.
        let la: Vec<u8> = rgba.chunks_exact(4).flat_map(|p| [p[0], p[3]]).collect();
        format
            .encode_grey_alpha(&la, key.px)
            .map(Bytes::from)
            .map_err(web_grid::Failure::EncodeImage)
    } else {
        encode(&rgba)
    };
    drop(memory);
    encoded
}

/// `GET /v1/datasets/{name}/{grid}/{layer}/{z}/{x}/{y}.{png,webp}`.
pub async fn tile(
    State(state): State<Arc<AppState>>,
    Segments((name, grid_name, layer, z, x, y)): Segments<(
        String,
        String,
        String,
        String,
        String,
        String,
    )>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let Some((y, format)) = ImageFormat::split(&y) else {
        return Err(ApiError::not_found(
            "no such endpoint; rendered tiles are /v1/datasets/{name}/{grid}/{layer}/{z}/{x}/{y}.png or .webp (see API.md)",
        ));
    };
    let ds = dataset(&state, &name)?;
    let tms = grid(&grid_name)?;
    let kind = kind(&layer)?;
    let px = size(&query)?;
    let style = style(&state.web.config.ramps, &ds, kind, &query, &[])?;
    let tile = web_tile(tms, &z, &x, y)?;
    let pin = pinned(&ds, &query);
    let variant = format!(
        "rendered {} {px} {} {} {}/{}/{}",
        tms.path(),
        style.canonical,
        format.extension(),
        tile.z,
        tile.x,
        tile.y
    );
    let asked = Asked {
        tile,
        px,
        look: Look::Rendered(xxhash_rust::xxh3::xxh3_128(style.canonical.as_bytes())),
        format: TileFormat::Image(format),
        variant,
        pin,
    };
    let layer = style.layer;
    web_grid::image_tile(
        state,
        ds,
        &headers,
        asked,
        ComputeKind::Rendered,
        move |web, ds, fp, key, ticket| make(web, ds, fp, key, &layer, ticket),
    )
    .await
}

/// `?format=` of a TileJSON request: the tiles' image format (PNG when absent).
fn format(query: &HashMap<String, String>) -> ApiResult<ImageFormat> {
    match query.get("format").map(String::as_str) {
        None | Some("png") => Ok(ImageFormat::Png),
        Some("webp") => Ok(ImageFormat::Webp),
        Some(other) => Err(ApiError::bad_request(format!(
            "format: unknown format {}: the formats are png, webp",
            quoted(other)
        ))),
    }
}

/// The TileJSON 3.0.0 document of a rendered layer: [`grid_tilejson`]'s, its tile
/// URLs carrying every option explicitly, plus `layer`.
#[allow(clippy::too_many_arguments)]
pub fn tilejson_doc(
    ds: &Dataset,
    fp: &Footprint,
    tms: TileMatrixSet,
    base: &str,
    style: &Style,
    px: u32,
    format: ImageFormat,
    attribution: Option<&str>,
) -> serde_json::Value {
    let kind = style.layer.kind();
    let tiles = format!(
        "{base}/v1/datasets/{}/{}/{}/{{z}}/{{x}}/{{y}}.{}?{}&size={px}&v={}",
        ds.name,
        tms.path(),
        kind.name(),
        format.extension(),
        style.query,
        ds.content_hash()
    );
    let mut doc = grid_tilejson(ds, fp, tms, px, tiles, attribution);
    doc.description = Some(format!(
        "{} of {}, rendered as gdaldem renders it ({})",
        kind.title(),
        ds.name,
        style.query.replace('&', ", ")
    ));
    doc.other.insert("layer".into(), kind.name().into());
    serde_json::to_value(doc).expect("a TileJSON document serializes")
}

/// `GET /v1/datasets/{name}/{grid}/{layer}/tilejson.json`. Absolute URLs as the
/// height tiles' TileJSON (routes/base_url.rs).
pub async fn tilejson(
    State(state): State<Arc<AppState>>,
    Segments((name, grid_name, layer)): Segments<(String, String, String)>,
    Params(query): Params,
    headers: HeaderMap,
    uri: Uri,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    let tms = grid(&grid_name)?;
    let kind = kind(&layer)?;
    let px = size(&query)?;
    let format = format(&query)?;
    let style = style(&state.web.config.ramps, &ds, kind, &query, &["format"])?;
    let variant = format!(
        "rendered tilejson {} {} {px} {}",
        tms.path(),
        style.canonical,
        format.extension()
    );
    web_grid::tilejson_response(
        &state,
        &ds,
        &headers,
        &uri,
        &query,
        &variant,
        |fp, url, attribution| tilejson_doc(&ds, fp, tms, url, &style, px, format, attribution),
    )
}
