//! `GET /v1/datasets/{name}/preview.png`: the whole dataset as a shaded-relief picture
//! of at most [`MAX_PX`] pixels a side (the landing page's thumbnails), made from a
//! coarse level and admitted like every computed response (serve/compute).
//!
//! The level is the finest whose samples across the DEM are at most twice
//! [`MAX_PX`] + 1 (one to four tiles for the usual tile sizes; the root tile at least);
//! it is resampled bilinearly to the picture, whose sides follow the dataset's ground
//! extent (`ground_spacing`, so a 1° × 1° tile at 46° N is narrower than tall), and
//! shaded as `tessera-server preview` shades (hypsometric tint × hillshade,
//! [`crate::preview::shade`]). No-data (absent tiles, cells the validity mask calls
//! void) is transparent.

use super::super::AppState;
use super::super::compute::{Kind, Stop, Ticket};
use super::super::dataset::{Dataset, RecordError};
use super::super::routes::{Params, Segments, dataset, pinned, unavailable};
use crate::http::cache;
use crate::http::error::{ApiError, ApiResult};
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, header};
use axum::response::Response;
use bytes::Bytes;
use std::sync::Arc;
use tessera_shared::{Level, TileGeometry, codec};

/// The longest side of a preview, in pixels.
pub const MAX_PX: u32 = 256;

/// The level a preview reads, its samples across the DEM, and the picture's size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Plan {
    pub level: Level,
    /// Samples of `level` across the DEM (`(width − 1) / spacing + 1`, and height).
    pub samples: (usize, usize),
    /// The picture's width and height in pixels.
    pub size: (u32, u32),
}

/// The plan for a DEM of `g` whose neighbouring samples are `ground` metres apart
/// east–west and north–south (`None`: square samples).
pub fn plan(g: &TileGeometry, ground: Option<(f64, f64)>) -> Plan {
    let across = |l: Level| {
        let s = g.spacing(l);
        (
            ((u64::from(g.width()) - 1) / s + 1) as usize,
            ((u64::from(g.height()) - 1) / s + 1) as usize,
        )
    };
    let level = g
        .levels()
        .rev()
        .find(|&l| {
            let (w, h) = across(l);
            w.max(h) <= 2 * MAX_PX as usize + 1
        })
        .unwrap_or(Level::ROOT);
    let samples = across(level);
    // The ground extent's proportions (sample spacings can differ by axis).
    let (gx, gy) = ground
        .filter(|(x, y)| x.is_finite() && y.is_finite() && *x > 0.0 && *y > 0.0)
        .unwrap_or((1.0, 1.0));
    let ew = f64::from(g.width().max(2) - 1) * gx;
    let ns = f64::from(g.height().max(2) - 1) * gy;
    let long = f64::from(MAX_PX.min(samples.0.max(samples.1) as u32).max(1));
    let (w, h) = if ew >= ns {
        (long, (long * ns / ew).round())
    } else {
        ((long * ew / ns).round(), long)
    };
    Plan {
        level,
        samples,
        size: (w.max(1.0) as u32, h.max(1.0) as u32),
    }
}

/// Why a preview could not be made.
fn failed(state: &AppState, ds: &Dataset, e: RecordError) -> ApiError {
    match e {
        RecordError::Corrupt(c) => {
            state.metrics.corrupt_read(c.first);
            ApiError::internal(format!("{}: record fails its checksum", c.tile))
        }
        RecordError::Unavailable(reason) => {
            let _ = ds;
            unavailable(&reason)
        }
    }
}

/// The level's heights (metres) and validity over the DEM, row-major.
fn heights(
    state: &AppState,
    ds: &Dataset,
    p: &Plan,
    ticket: &Ticket,
) -> ApiResult<(Vec<f32>, Vec<bool>)> {
    let g = *ds.pyramid.geometry();
    let q = ds.pyramid.metadata().quantization;
    let layout = ds.pyramid.record_layout();
    let (w, h) = p.samples;
    let mut z = vec![0f32; w * h];
    let mut valid = vec![false; w * h];
    let t = g.tile_size() as usize;
    let side = t + 1;
    for tile in g.present_tiles(p.level) {
        ticket.check().map_err(Stop::into_error)?;
        let Some((_, record)) = ds.record(tile).map_err(|e| failed(state, ds, e))? else {
            continue; // absent: wholly no-data
        };
        let decoded = codec::decode_record(&record, layout).map_err(|e| {
            state.metrics.corrupt_read(ds.mark_undecodable(tile));
            tracing::error!(dataset = %ds.name, %tile, error = %e, "record does not decode");
            ApiError::internal(format!(
                "{tile}: record passes its checksum but its height data does not decode"
            ))
        })?;
        let (x0, y0) = (tile.x() as usize * t, tile.y() as usize * t);
        for j in 0..side.min(h.saturating_sub(y0)) {
            for i in 0..side.min(w.saturating_sub(x0)) {
                let at = (y0 + j) * w + x0 + i;
                z[at] = q.height(decoded.heights[j * side + i]) as f32;
                // A sample is terrain when one of the cells it bounds is (as the
                // web tiles count it).
                let cells_x = i.saturating_sub(1)..=i.min(t - 1);
                valid[at] = cells_x.into_iter().any(|ci| {
                    (j.saturating_sub(1)..=j.min(t - 1))
                        .any(|cj| decoded.mask.is_valid(ci as u32, cj as u32))
                });
            }
        }
    }
    Ok((z, valid))
}

/// The picture as an RGBA PNG.
fn render(state: &AppState, ds: &Dataset, p: &Plan, ticket: &Ticket) -> ApiResult<Vec<u8>> {
    let (z, valid) = heights(state, ds, p, ticket)?;
    let (sw, sh) = p.samples;
    let (w, h) = (p.size.0 as usize, p.size.1 as usize);
    // Bilinear from the level's samples at each pixel's centre; a pixel shows
    // terrain when its nearest sample does.
    let mut out = vec![0f32; w * h];
    let mut alpha = vec![false; w * h];
    for y in 0..h {
        let fy = ((y as f64 + 0.5) / h as f64 * sh as f64 - 0.5).clamp(0.0, (sh - 1) as f64);
        let (j, ty) = (fy.floor() as usize, (fy - fy.floor()) as f32);
        let j1 = (j + 1).min(sh - 1);
        for x in 0..w {
            let fx = ((x as f64 + 0.5) / w as f64 * sw as f64 - 0.5).clamp(0.0, (sw - 1) as f64);
            let (i, tx) = (fx.floor() as usize, (fx - fx.floor()) as f32);
            let i1 = (i + 1).min(sw - 1);
            let top = z[j * sw + i] * (1.0 - tx) + z[j * sw + i1] * tx;
            let bottom = z[j1 * sw + i] * (1.0 - tx) + z[j1 * sw + i1] * tx;
            out[y * w + x] = top * (1.0 - ty) + bottom * ty;
            alpha[y * w + x] = valid[fy.round() as usize * sw + fx.round() as usize];
        }
    }
    // Void pixels carry no height: give them the lowest valid one, so they neither
    // stretch the tint nor make cliffs in the shading.
    let lowest = out
        .iter()
        .zip(&alpha)
        .filter(|(_, a)| **a)
        .map(|(v, _)| *v)
        .fold(f32::INFINITY, f32::min);
    let lowest = if lowest.is_finite() { lowest } else { 0.0 };
    for (v, a) in out.iter_mut().zip(&alpha) {
        if !*a {
            *v = lowest;
        }
    }
    ticket.check().map_err(Stop::into_error)?;
    let rgb = crate::preview::shade(w, h, &out);
    let mut rgba = Vec::with_capacity(w * h * 4);
    for (px, a) in rgb.chunks_exact(3).zip(&alpha) {
        rgba.extend_from_slice(px);
        rgba.push(if *a { 255 } else { 0 });
    }
    let mut png = Vec::new();
    let mut enc = png::Encoder::new(&mut png, p.size.0, p.size.1);
    enc.set_color(png::ColorType::Rgba);
    enc.set_depth(png::BitDepth::Eight);
    let encoded = enc
        .write_header()
        .and_then(|mut wr| wr.write_image_data(&rgba).and_then(|()| wr.finish()));
    encoded.map_err(|e| {
        tracing::error!(dataset = %ds.name, error = %e, "preview encoding failed");
        ApiError::internal("cannot encode the preview")
    })?;
    Ok(png)
}

/// `GET /v1/datasets/{name}/preview.png`: see the module documentation.
pub async fn get(
    State(state): State<Arc<AppState>>,
    Segments(name): Segments<String>,
    Params(query): Params,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    let pin = pinned(&ds, &query);
    let etag = cache::etag(ds.content_hash(), "preview");
    if let Some(r) = cache::revalidate(&headers, &etag, ds.last_modified, pin, state.cache_max_age)
    {
        return Ok(r);
    }
    let m = ds.pyramid.metadata();
    let plan = plan(ds.pyramid.geometry(), m.ground_spacing.map(|s| (s.x, s.y)));
    let (st, d) = (state.clone(), ds.clone());
    let key = format!("{} {} preview", ds.content_hash(), ds.path.display());
    let made = state
        .compute
        .run_blocking(Kind::Preview, key, move |ticket| {
            let (sw, sh) = plan.samples;
            let (w, h) = (plan.size.0 as u64, plan.size.1 as u64);
            let side = u64::from(d.pyramid.geometry().tile_size()) + 1;
            // Heights and flags of the level, the picture's heights, RGB, RGBA and
            // the PNG, and one decoded tile.
            let need = (sw * sh) as u64 * 5 + w * h * 16 + side * side * 4;
            let _memory = ticket.reserve(need).map_err(Stop::into_error)?;
            let png = render(&st, &d, &plan, ticket)?;
            Ok(ticket.made(Bytes::from(png), 0))
        })
        .await?;
    let len = made.bytes.len();
    let mut r = Response::new(made.body());
    let h = r.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static("image/png"));
    h.insert(header::CONTENT_LENGTH, HeaderValue::from(len));
    cache::set_headers(h, &etag, ds.last_modified, pin, state.cache_max_age);
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn previews_fit_256_pixels_and_follow_the_ground() {
        // N46E008: 1201² samples in 512-cell tiles (3 levels), 64 m × 93 m apart.
        let g = TileGeometry::new(1201, 1201, 512).unwrap();
        let p = plan(&g, Some((64.2, 92.7)));
        assert_eq!(p.level.get(), 0);
        assert_eq!(p.samples, (301, 301));
        assert_eq!(p.size, (177, 256));
        // Without spacings the samples are square.
        assert_eq!(plan(&g, None).size, (256, 256));
        // A big DEM in small tiles: the finest level that fits 512 samples.
        let g = TileGeometry::new(8193, 4097, 128).unwrap();
        let p = plan(&g, None);
        assert_eq!(p.samples, (513, 257));
        assert_eq!(p.size, (256, 128));
        // A small one is not blown up.
        let g = TileGeometry::new(100, 50, 64).unwrap();
        let p = plan(&g, None);
        assert_eq!((p.level.get(), p.samples), (1, (100, 50)));
        assert_eq!(p.size, (100, 49));
    }
}
