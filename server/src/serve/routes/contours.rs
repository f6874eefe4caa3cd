//! Contour lines as Mapbox Vector Tiles on the standard grids (web/contour/,
//! DECISIONS.md "Contour tiles"), with a TileJSON document naming their layer.
//!
//! - `GET /v1/datasets/{name}/{grid}/contours/{z}/{x}/{y}.mvt?interval=&index=&unit=`
//! - `GET /v1/datasets/{name}/{grid}/contours/tilejson.json?interval=&index=&unit=`
//!
//! `interval` is units between lines, or `auto` (the default: one per zoom, see
//! web/contour/interval.rs); `index` makes every n-th line (counted from 0) an
//! index contour (default 5; 0 for none); `unit` is `m` (default) or `ft`. A tile
//! is traced on a grid of [`GRID`] samples across and [`BORDER`] more on each side,
//! read from its neighbours.

use super::web_grid::{self, Asked, grid, grid_tilejson, web_tile};
use super::{Params, Segments, dataset, pinned};
use crate::http::error::{ApiError, ApiResult, quoted};
use crate::serve::AppState;
use crate::serve::compute::{Kind as ComputeKind, Ticket};
use crate::serve::dataset::Dataset;
use crate::serve::web_cache::{Look, MadeKey, WebTiles};
use crate::web::contour::interval::{self, Interval};
use crate::web::contour::march::{self, Contouring, MAX_SEGMENTS};
use crate::web::contour::vector_tile::{self, Levels, Unit};
use crate::web::encoding::TileFormat;
use crate::web::footprint::Footprint;
use crate::web::resample;
use crate::web::tile_matrix::TileMatrixSet;
use axum::extract::State;
use axum::http::{HeaderMap, Uri};
use axum::response::Response;
use bytes::Bytes;
use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

/// Samples across a contour tile: as many as MapLibre's 512 screen pixels.
pub const GRID: u32 = 512;

/// Samples beyond each edge: the tile's buffer (16 of its 4096 units), the most the
/// neighbours' pixels reach (resample.rs `APRON`).
pub const BORDER: u32 = resample::APRON as u32;

/// Index contours every 5th line unless asked otherwise.
const DEFAULT_INDEX: u32 = 5;

/// The parameters contour routes take.
const OPTIONS: [&str; 5] = ["interval", "index", "unit", "v", "key"];

/// Contours as asked for: the interval, the index lines, their canonical
/// description (the cache key and ETag variant), and the query asking for them again.
#[derive(Clone, Debug)]
pub struct Style {
    pub interval: Interval,
    pub index: u32,
    pub unit: Unit,
    pub canonical: String,
    pub query: String,
}

impl Style {
    /// The levels a tile at zoom `z` draws, or a 400 naming `interval` when they are
    /// too fine there.
    pub fn levels(&self, fp: &Footprint, tms: TileMatrixSet, z: u8) -> ApiResult<Levels> {
        let ground = interval::ground_pixel(tms, z, GRID, fp.centre()[1])
            * interval::body_scale(fp.crs())
            * self.unit.per_metre();
        let interval = self.interval.at(ground, self.unit.name()).map_err(|why| {
            ApiError::bad_request(format!("interval: at zoom {z} of {}, {why}", tms.id()))
        })?;
        Ok(Levels {
            interval,
            index: self.index,
            unit: self.unit,
        })
    }
}

/// The contours the query asks for, or 400 naming the parameter.
pub fn style(query: &HashMap<String, String>) -> ApiResult<Style> {
    if let Some(k) = web_grid::unknown_parameter(query, &OPTIONS) {
        return Err(ApiError::bad_request(format!(
            "unknown parameter {} for contours: they take {}",
            quoted(k),
            OPTIONS.join(", ")
        )));
    }
    let interval = query.get("interval").map_or(Ok(Interval::Auto), |v| {
        Interval::parse(v).map_err(|why| ApiError::bad_request(format!("interval: {why}")))
    })?;
    let index = query.get("index").map_or(Ok(DEFAULT_INDEX), |v| {
        v.parse::<u32>()
            .ok()
            .filter(|n| *n <= 1000)
            .ok_or_else(|| {
                ApiError::bad_request(format!(
                    "index: {} is not a count of lines from 0 to 1000 (every n-th line is an index contour; 0 for none)",
                    quoted(v)
                ))
            })
    })?;
    let unit = query.get("unit").map_or(Ok(Unit::Metres), |v| {
        Unit::parse(v).ok_or_else(|| {
            ApiError::bad_request(format!(
                "unit: unknown unit {}: the units are {}",
                quoted(v),
                Unit::ALLOWED
            ))
        })
    })?;
    let q = format!(
        "interval={}&index={index}&unit={}",
        interval.name(),
        unit.name()
    );
    Ok(Style {
        interval,
        index,
        unit,
        canonical: format!("contours {q}"),
        query: q,
    })
}

/// Working memory per grid sample: its height, flags and level step.
const BYTES_PER_SAMPLE: u64 = 8 + 2 + 16;
/// Working memory per line piece: the piece, its two joins, its points and their
/// share of the encoded tile.
const BYTES_PER_SEGMENT: u64 = 16 + 2 * 32 + 2 * 16 + 8;

/// The encoded tile: empty beyond the dataset's bounds (what its TileJSON states), an
/// empty `contours` layer where no line passes; a [`web_grid::Failure::TooDense`]
/// when the levels would draw more than [`MAX_SEGMENTS`] pieces, found by counting
/// before any is traced.
pub fn make(
    web: &WebTiles,
    ds: &Dataset,
    fp: &Footprint,
    key: MadeKey,
    levels: Levels,
    ticket: &Ticket,
) -> Result<Bytes, web_grid::Failure> {
    if !fp.meets(key.tile) {
        return Ok(Bytes::new());
    }
    let encode = |lines: &[march::Line]| {
        vector_tile::encode(lines, levels, GRID, BORDER)
            .map(Bytes::from)
            .map_err(web_grid::Failure::EncodeVector)
    };
    let side = GRID + 2 * BORDER;
    let working = u64::from(side).pow(2) * BYTES_PER_SAMPLE;
    let Some(plan) = resample::plan(fp, ds.pyramid.geometry(), key.tile, GRID) else {
        return encode(&[]);
    };
    let (sources, memory) = web_grid::plan_sources(web, ds, &plan, working, ticket)?;
    let mut sampled = plan.sample_bordered(&sources, BORDER);
    drop(sources);
    let per_metre = levels.unit.per_metre();
    if per_metre != 1.0 {
        for h in &mut sampled.heights {
            *h *= per_metre;
        }
    }
    let grid = march::Grid {
        width: side as usize,
        height: side as usize,
        heights: &sampled.heights,
        valid: &sampled.terrain,
    };
    let contouring = Contouring::new(grid, levels.interval);
    let pieces = contouring.segments();
    if pieces > MAX_SEGMENTS {
        let coarser =
            interval::nice_at_least(levels.interval * pieces as f64 / MAX_SEGMENTS as f64);
        return Err(web_grid::Failure::TooDense(format!(
            "interval: {} {unit} draws {pieces} line pieces in tile {}, more than the {MAX_SEGMENTS} a contour tile may hold; an interval of {coarser} {unit} or more draws it",
            levels.interval,
            key.tile,
            unit = levels.unit.name()
        )));
    }
    ticket.check().map_err(web_grid::Failure::Stopped)?;
    let _lines = ticket
        .reserve(pieces * BYTES_PER_SEGMENT)
        .map_err(web_grid::Failure::Stopped)?;
    let lines = contouring.lines();
    let encoded = encode(&lines);
    drop(memory);
    encoded
}

/// `GET /v1/datasets/{name}/{grid}/contours/{z}/{x}/{y}.mvt`.
pub async fn tile(
    State(state): State<Arc<AppState>>,
    Segments((name, grid_name, z, x, y)): Segments<(String, String, String, String, String)>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let Some(y) = y.strip_suffix(".mvt").or_else(|| y.strip_suffix(".pbf")) else {
        return Err(ApiError::not_found(
            "no such endpoint; contour tiles are /v1/datasets/{name}/{grid}/contours/{z}/{x}/{y}.mvt (see API.md)",
        ));
    };
    let ds = dataset(&state, &name)?;
    let tms = grid(&grid_name)?;
    let style = style(&query)?;
    let tile = web_tile(tms, &z, &x, y)?;
    let fp = web_grid::footprint(&state, &ds)?;
    let levels = style.levels(&fp, tms, tile.z)?;
    let pin = pinned(&ds, &query);
    let variant = format!(
        "contours {} {} {}/{}/{}",
        tms.path(),
        style.canonical,
        tile.z,
        tile.x,
        tile.y
    );
    let asked = Asked {
        tile,
        px: GRID,
        look: Look::Contours(xxhash_rust::xxh3::xxh3_128(style.canonical.as_bytes())),
        format: TileFormat::Mvt,
        variant,
        pin,
    };
    web_grid::image_tile(
        state,
        ds,
        &headers,
        asked,
        ComputeKind::Contours,
        move |web, ds, fp, key, ticket| make(web, ds, fp, key, levels, ticket),
    )
    .await
}

/// The zooms whose pixels the style's interval suits, and their intervals.
pub fn zooms(style: &Style, fp: &Footprint, tms: TileMatrixSet) -> BTreeMap<u8, f64> {
    (0..=fp.max_zoom(tms, GRID))
        .filter_map(|z| Some((z, style.levels(fp, tms, z).ok()?.interval)))
        .collect()
}

/// The TileJSON 3.0.0 document of the contour tiles: [`grid_tilejson`]'s, from the
/// first zoom the interval suits, with `vector_layers` and the interval per zoom.
pub fn tilejson_doc(
    ds: &Dataset,
    fp: &Footprint,
    tms: TileMatrixSet,
    base: &str,
    style: &Style,
    attribution: Option<&str>,
) -> serde_json::Value {
    let tiles = format!(
        "{base}/v1/datasets/{}/{}/contours/{{z}}/{{x}}/{{y}}.mvt?{}&v={}",
        ds.name,
        tms.path(),
        style.query,
        ds.content_hash()
    );
    let mut doc = grid_tilejson(ds, fp, tms, GRID, tiles, attribution);
    let intervals = zooms(style, fp, tms);
    let first = intervals
        .keys()
        .next()
        .copied()
        .unwrap_or(doc.maxzoom.unwrap_or(0));
    doc.minzoom = Some(first);
    if let Some(c) = doc.center.as_mut() {
        c.zoom = c.zoom.max(first);
    }
    let fields = BTreeMap::from([
        (
            "ele".to_string(),
            format!("Number: the line's elevation in {}", style.unit.word()),
        ),
        (
            "index".to_string(),
            format!(
                "Boolean: whether it is an index contour (every {} line from 0 {})",
                ordinal(style.index),
                style.unit.name()
            ),
        ),
    ]);
    let mut layer = tilejson::VectorLayer::new(vector_tile::LAYER.into(), fields);
    layer.description = Some(format!("Contour lines of {}", ds.name));
    layer.minzoom = doc.minzoom;
    layer.maxzoom = doc.maxzoom;
    doc.vector_layers = Some(vec![layer]);
    doc.description = Some(format!(
        "Contour lines of {} every {} ({})",
        ds.name,
        match style.interval {
            Interval::Auto => "interval of each zoom".to_string(),
            Interval::Fixed(v) => format!("{v} {}", style.unit.name()),
        },
        style.query.replace('&', ", ")
    ));
    doc.other.insert("format".into(), "pbf".into());
    doc.other
        .insert("contour_unit".into(), style.unit.name().into());
    doc.other.insert(
        "contour_intervals".into(),
        intervals
            .iter()
            .map(|(z, i)| (z.to_string(), serde_json::Value::from(*i)))
            .collect::<serde_json::Map<_, _>>()
            .into(),
    );
    serde_json::to_value(doc).expect("a TileJSON document serializes")
}

/// "5th", "2nd", …; "no" for 0.
fn ordinal(n: u32) -> String {
    if n == 0 {
        return "no".into();
    }
    let suffix = match (n % 10, n % 100) {
        (1, 11) | (2, 12) | (3, 13) => "th",
        (1, _) => "st",
        (2, _) => "nd",
        (3, _) => "rd",
        _ => "th",
    };
    format!("{n}{suffix}")
}

/// `GET /v1/datasets/{name}/{grid}/contours/tilejson.json`. Absolute URLs as the
/// height tiles' TileJSON (routes/base_url.rs).
pub async fn tilejson(
    State(state): State<Arc<AppState>>,
    Segments((name, grid_name)): Segments<(String, String)>,
    Params(query): Params,
    headers: HeaderMap,
    uri: Uri,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    let tms = grid(&grid_name)?;
    let style = style(&query)?;
    let variant = format!("contours tilejson {} {}", tms.path(), style.canonical);
    web_grid::tilejson_response(
        &state,
        &ds,
        &headers,
        &uri,
        &query,
        &variant,
        |fp, url, attribution| tilejson_doc(&ds, fp, tms, url, &style, attribution),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn query(pairs: &[(&str, &str)]) -> HashMap<String, String> {
        pairs
            .iter()
            .map(|(k, v)| ((*k).to_string(), (*v).to_string()))
            .collect()
    }

    #[test]
    fn styles_are_canonical_and_bad_options_are_named() {
        let s = style(&query(&[])).unwrap();
        assert_eq!(s.query, "interval=auto&index=5&unit=m");
        let s = style(&query(&[
            ("interval", "20"),
            ("index", "0"),
            ("unit", "ft"),
        ]))
        .unwrap();
        assert_eq!(s.query, "interval=20&index=0&unit=ft");
        let e = style(&query(&[("unit", "feet")])).unwrap_err();
        assert!(
            e.message.starts_with("unit:") && e.message.contains("m, ft"),
            "{}",
            e.message
        );
        let e = style(&query(&[("intervall", "20")])).unwrap_err();
        assert!(e.message.contains("\"intervall\""), "{}", e.message);
        let e = style(&query(&[("interval", "0")])).unwrap_err();
        assert!(e.message.starts_with("interval:"), "{}", e.message);
        let e = style(&query(&[("index", "-1")])).unwrap_err();
        assert!(e.message.starts_with("index:"), "{}", e.message);
    }

    #[test]
    fn ordinals_read_as_english() {
        let o: Vec<String> = [0, 1, 2, 3, 4, 5, 11, 12, 21].map(ordinal).into();
        assert_eq!(
            o,
            [
                "no", "1st", "2nd", "3rd", "4th", "5th", "11th", "12th", "21st"
            ]
        );
    }
}
