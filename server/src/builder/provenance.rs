//! What a pyramid records about its inputs (DECISIONS.md "Provenance"): for each, its
//! name, CRS, ground spacing, vertical datum, outline on the globe and the deepest
//! level its data supports. `info` lists them; `GET /v1/datasets/{name}/coverage`
//! serves them as GeoJSON.
//!
//! A collection of thousands of files would not fit the metadata (1 MiB), so beyond
//! [`MAX_SOURCES`] inputs are summarised per kind (same CRS, spacing to the millimetre
//! and datum): "1 834 files like N46E008.tif", with the outline of their union's
//! bounding box.

use crate::crs::{Crs, ground_spacing};
use crate::ingest::InputSummary;
use crate::ingest::reproject::{border_ring, bounds};
use tessera_shared::{GeoRef, GroundSpacing, SourceRecord, VerticalDatum};

/// Inputs recorded one by one; more are summarised per kind.
pub const MAX_SOURCES: usize = 256;
/// Points per edge of an outline (a projected grid's edges curve in longitude/latitude).
const EDGE_POINTS: u32 = 8;

/// The records of `inputs` for a pyramid whose finest level `finest` has samples
/// `spacing` metres apart.
pub(super) fn records(
    inputs: &[InputSummary],
    spacing: Option<GroundSpacing>,
    finest: u8,
) -> Vec<SourceRecord> {
    let each: Vec<SourceRecord> = inputs.iter().map(|i| record(i, spacing, finest)).collect();
    if each.len() <= MAX_SOURCES {
        return each;
    }
    summarise(each)
}

fn record(i: &InputSummary, pyramid: Option<GroundSpacing>, finest: u8) -> SourceRecord {
    let crs = i.georef.as_ref().and_then(Crs::of);
    let spacing = i
        .georef
        .as_ref()
        .and_then(|g| ground_spacing(g, i.width, i.height).ok());
    let level = match (spacing, pyramid, tessera_shared::Level::new(finest)) {
        (Some(s), Some(p), Some(f)) => {
            super::support::supported_level((s.x * s.y).sqrt(), (p.x * p.y).sqrt(), f)
        }
        _ => finest,
    };
    SourceRecord {
        name: i.name.clone(),
        crs: crs.as_ref().map(Crs::label).unwrap_or_default(),
        spacing,
        vertical_datum: i.datum.unwrap_or(VerticalDatum::Unknown),
        footprint: match (&i.georef, &crs) {
            (Some(g), Some(c)) => outline(g, c, i.width, i.height).unwrap_or_default(),
            _ => Vec::new(),
        },
        level,
    }
}

/// The grid's outer pixel edges in longitude/latitude: WGS 84 for a CRS on the Earth,
/// the body's own for another (the Moon's).
fn outline(g: &GeoRef, crs: &Crs, w: u32, h: u32) -> Option<Vec<[f64; 2]>> {
    let mut ring = border_ring(&g.geotransform, f64::from(w), f64::from(h), EDGE_POINTS);
    let target = if crs.is_earth() {
        Crs::from_epsg(4326).ok()?
    } else {
        crs.own_geographic().ok()?
    };
    crs.transform_points(&target, &mut ring).ok()?;
    let mut out: Vec<[f64; 2]> = ring.iter().map(|p| [round(p[0]), round(p[1])]).collect();
    out.push(out[0]);
    Some(out)
}

/// Degrees to 1e-7 (1 cm): the metadata need not carry more.
fn round(v: f64) -> f64 {
    (v * 1e7).round() / 1e7
}

/// Inputs of one kind merged: their count, the first's name, their union's box.
fn summarise(each: Vec<SourceRecord>) -> Vec<SourceRecord> {
    let mut kinds: Vec<(SourceRecord, usize, [f64; 4])> = Vec::new();
    let key = |r: &SourceRecord| {
        (
            r.crs.clone(),
            r.vertical_datum,
            r.spacing
                .map(|s| ((s.x * 1e3).round() as i64, (s.y * 1e3).round() as i64)),
        )
    };
    for r in each {
        let b = bounds(&r.footprint);
        match kinds.iter_mut().find(|(k, _, _)| key(k) == key(&r)) {
            Some((_, n, u)) => {
                *n += 1;
                *u = [
                    u[0].min(b[0]),
                    u[1].min(b[1]),
                    u[2].max(b[2]),
                    u[3].max(b[3]),
                ];
            }
            None => kinds.push((r, 1, b)),
        }
    }
    kinds
        .into_iter()
        .map(|(mut r, n, b)| {
            if n > 1 {
                r.name = format!("{n} files like {}", r.name);
                r.footprint = if b[0].is_finite() {
                    vec![
                        [b[0], b[3]],
                        [b[0], b[1]],
                        [b[2], b[1]],
                        [b[2], b[3]],
                        [b[0], b[3]],
                    ]
                } else {
                    Vec::new()
                };
            }
            r
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::RasterType;

    fn input(name: &str, epsg: u32, gt: [f64; 6], w: u32, h: u32) -> InputSummary {
        InputSummary {
            name: name.into(),
            georef: Some(GeoRef {
                epsg: Some(epsg),
                crs_name: None,
                proj: None,
                wkt: None,
                geotransform: gt,
                raster_type: RasterType::PixelIsArea,
            }),
            width: w,
            height: h,
            datum: Some(VerticalDatum::Egm96),
        }
    }

    #[test]
    fn each_input_has_its_crs_spacing_outline_and_level() {
        let step = 1.0 / 1200.0;
        let fine = input(
            "fine.tif",
            4326,
            [8.0, step, 0.0, 47.0, 0.0, -step],
            1200,
            1200,
        );
        let coarse = input(
            "coarse.tif",
            4326,
            [8.0, 10.0 * step, 0.0, 47.0, 0.0, -10.0 * step],
            120,
            120,
        );
        let lv95 = input(
            "aletsch.tif",
            2056,
            [2_601_100.0, 200.0, 0.0, 1_184_500.0, 0.0, -200.0],
            358,
            310,
        );
        let pyramid = ground_spacing(fine.georef.as_ref().unwrap(), 1200, 1200).unwrap();
        let r = records(&[fine, coarse, lv95], Some(pyramid), 5);
        assert_eq!(r[0].level, 5);
        // Ten times coarser: 3 levels up (8×), not 4 (16× would lose data).
        assert_eq!(r[1].level, 2);
        assert_eq!(r[2].crs, "EPSG:2056 (CH1903+ / LV95)");
        assert!((r[2].spacing.unwrap().x - 200.0).abs() < 0.1);
        let ring = &r[2].footprint;
        assert_eq!(ring.len(), 4 * EDGE_POINTS as usize + 1);
        assert_eq!(ring.first(), ring.last());
        // Aletsch's grid lies around 7.45–8.4° E, 46.3–46.9° N.
        assert!(
            ring.iter()
                .all(|p| (7.4..8.45).contains(&p[0]) && (46.25..46.95).contains(&p[1]))
        );
    }

    #[test]
    fn thousands_of_inputs_are_summarised_per_kind() {
        let step = 1.0 / 1200.0;
        let mut inputs: Vec<InputSummary> = (0..300)
            .map(|k| {
                let lon = 8.0 + f64::from(k % 20) * 0.25;
                input(
                    &format!("t{k}.tif"),
                    4326,
                    [lon, step, 0.0, 47.0, 0.0, -step],
                    300,
                    300,
                )
            })
            .collect();
        inputs.push(input(
            "aletsch.tif",
            2056,
            [2_601_100.0, 200.0, 0.0, 1_184_500.0, 0.0, -200.0],
            358,
            310,
        ));
        let r = records(&inputs, None, 3);
        assert_eq!(r.len(), 2);
        assert_eq!(r[0].name, "300 files like t0.tif");
        assert_eq!(r[0].footprint.len(), 5);
        assert!((r[0].footprint[2][0] - (8.0 + 19.0 * 0.25 + 0.25)).abs() < 1e-6);
        assert_eq!(r[1].name, "aletsch.tif");
    }
}
