//! Answers written out: JSON shaped as Google's Elevation API and opentopodata
//! answer (so their clients read it; API.md "Elevation queries" maps the fields),
//! CSV and GeoJSON (`tessera-server query`). Numbers are written in full (Rust's
//! shortest round-trip form), so a profile's points asked for again as locations
//! are the same points.

use super::Answer;
use std::fmt::Write;

/// What every answer of a batch shares.
#[derive(Clone, Copy, Debug)]
pub struct Context<'a> {
    pub dataset: &'a str,
    /// The datum answers are in (its name).
    pub datum: &'a str,
    pub interpolation: &'a str,
    /// What a point without data gets instead of `null`.
    pub nodata_value: Option<f64>,
}

/// A height to the micrometre: what floating-point sums leave beyond it is noise
/// (3338 rather than 3337.9999999999927).
pub fn micro(v: f64) -> f64 {
    (v * 1e6).round() / 1e6
}

/// A bound to the micrometre, rounded up (it must not shrink).
pub fn micro_up(v: f64) -> f64 {
    (v * 1e6).ceil() / 1e6
}

fn number(out: &mut String, v: f64) {
    // Finite by construction; `null` rather than invalid JSON if not.
    if v.is_finite() {
        out.push_str(ryu::Buffer::new().format_finite(v));
    } else {
        out.push_str("null");
    }
}

fn json_string(out: &mut String, s: &str) {
    out.push_str(&serde_json::Value::from(s).to_string());
}

/// Bytes of JSON per answer, at most about (for reserving memory before writing,
/// and sizing the string once: a full-precision point, height and bound take 230).
pub const JSON_BYTES_PER_ANSWER: usize = 256;

/// `{"status": "OK", "results": [...]}` with one object per answer.
pub fn json(answers: &[Answer], cx: &Context) -> String {
    let mut out = String::with_capacity(128 + answers.len() * JSON_BYTES_PER_ANSWER);
    out.push_str("{\"status\":\"OK\",\"dataset\":");
    json_string(&mut out, cx.dataset);
    out.push_str(",\"interpolation\":");
    json_string(&mut out, cx.interpolation);
    out.push_str(",\"datum\":");
    json_string(&mut out, cx.datum);
    out.push_str(",\"results\":[");
    let mut dataset = String::new();
    json_string(&mut dataset, cx.dataset);
    let mut datum = String::new();
    json_string(&mut datum, cx.datum);
    for (i, a) in answers.iter().enumerate() {
        if i > 0 {
            out.push(',');
        }
        // Each coordinate formatted once, written twice.
        let (mut a_lat, mut a_lon) = (ryu::Buffer::new(), ryu::Buffer::new());
        let lat = a_lat.format_finite(a.point.lat());
        let lon = a_lon.format_finite(a.point.lon());
        for piece in [
            "{\"lat\":",
            lat,
            ",\"lon\":",
            lon,
            ",\"location\":{\"lat\":",
            lat,
            ",\"lng\":",
            lon,
        ] {
            out.push_str(piece);
        }
        out.push_str("},\"elevation\":");
        if let Ok(h) = &a.height {
            number(&mut out, micro(h.elevation));
            let _ = write!(out, ",\"level\":{},\"error_bound\":", h.level.get());
            number(&mut out, micro_up(h.error_bound));
            out.push_str(",\"resolution\":");
            number(&mut out, h.resolution);
        } else {
            match cx.nodata_value {
                Some(v) => number(&mut out, v),
                None => out.push_str("null"),
            }
            out.push_str(",\"level\":null,\"error_bound\":null,\"resolution\":null");
        }
        out.push_str(",\"datum\":");
        out.push_str(&datum);
        out.push_str(",\"dataset\":");
        out.push_str(&dataset);
        if let Err(m) = &a.height {
            out.push_str(",\"reason\":");
            json_string(&mut out, m.reason());
        }
        out.push('}');
    }
    out.push_str("]}");
    out
}

/// A header row, then `lat,lon,elevation,level,error_bound,resolution,datum,reason`
/// per answer (empty cells where there is no height).
pub fn csv(answers: &[Answer], cx: &Context) -> String {
    let mut out = String::from("lat,lon,elevation,level,error_bound,resolution,datum,reason\n");
    for a in answers {
        let _ = write!(out, "{},{},", a.point.lat(), a.point.lon());
        match &a.height {
            Ok(h) => {
                let _ = write!(
                    out,
                    "{},{},{},{},{},",
                    micro(h.elevation),
                    h.level.get(),
                    micro_up(h.error_bound),
                    h.resolution,
                    cx.datum
                );
            }
            Err(m) => {
                if let Some(v) = cx.nodata_value {
                    let _ = write!(out, "{v}");
                }
                let _ = write!(out, ",,,,{},\"{}\"", cx.datum, m.reason());
            }
        }
        out.push('\n');
    }
    out
}

/// A GeoJSON FeatureCollection of points, `[lon, lat]`, with the answer in each
/// feature's properties.
pub fn geojson(answers: &[Answer], cx: &Context) -> String {
    let features: Vec<serde_json::Value> = answers
        .iter()
        .map(|a| {
            let mut props = serde_json::Map::new();
            match &a.height {
                Ok(h) => {
                    props.insert("elevation".into(), micro(h.elevation).into());
                    props.insert("level".into(), h.level.get().into());
                    props.insert("error_bound".into(), micro_up(h.error_bound).into());
                    props.insert("resolution".into(), h.resolution.into());
                }
                Err(m) => {
                    props.insert("elevation".into(), cx.nodata_value.into());
                    props.insert("reason".into(), m.reason().into());
                }
            }
            props.insert("datum".into(), cx.datum.into());
            props.insert("dataset".into(), cx.dataset.into());
            serde_json::json!({
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": [a.point.lon(), a.point.lat()]},
                "properties": props,
            })
        })
        .collect();
    let doc = serde_json::json!({"type": "FeatureCollection", "features": features});
    let mut s = doc.to_string();
    s.push('\n');
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::elevation::locations::LatLon;
    use crate::elevation::{Height, Missing};
    use tessera_shared::Level;

    fn answers() -> Vec<Answer> {
        vec![
            Answer {
                point: LatLon::new(46.5, 8.125).unwrap(),
                height: Ok(Height {
                    elevation: 1234.5,
                    level: Level::new(2).unwrap(),
                    error_bound: 0.25,
                    resolution: 90.0,
                }),
            },
            Answer {
                point: LatLon::new(-10.0, 170.0).unwrap(),
                height: Err(Missing::Outside),
            },
        ]
    }

    const CX: Context = Context {
        dataset: "alps",
        datum: "egm96",
        interpolation: "bilinear",
        nodata_value: None,
    };

    /// The JSON parses, and has Google's and opentopodata's fields where their
    /// clients read them.
    #[test]
    fn json_has_the_fields_clients_read() {
        let v: serde_json::Value = serde_json::from_str(&json(&answers(), &CX)).unwrap();
        assert_eq!(v["status"], "OK");
        let r = &v["results"];
        assert_eq!(r[0]["elevation"], 1234.5);
        assert_eq!(r[0]["location"]["lat"], 46.5);
        assert_eq!(r[0]["location"]["lng"], 8.125);
        assert_eq!(r[0]["lon"], 8.125);
        assert_eq!(r[0]["level"], 2);
        assert_eq!(r[0]["error_bound"], 0.25);
        assert_eq!(r[0]["resolution"], 90.0);
        assert_eq!(r[0]["dataset"], "alps");
        assert_eq!(r[0]["datum"], "egm96");
        assert!(r[0].get("reason").is_none());
        assert!(r[1]["elevation"].is_null());
        assert!(r[1]["error_bound"].is_null());
        assert_eq!(r[1]["reason"], "outside the dataset");
        // nodata_value replaces null, the reason stays.
        let cx = Context {
            nodata_value: Some(-9999.0),
            ..CX
        };
        let v: serde_json::Value = serde_json::from_str(&json(&answers(), &cx)).unwrap();
        assert_eq!(v["results"][1]["elevation"], -9999.0);
        assert_eq!(v["results"][1]["reason"], "outside the dataset");
    }

    #[test]
    fn csv_and_geojson_carry_the_same_answers() {
        let c = csv(&answers(), &CX);
        let lines: Vec<&str> = c.lines().collect();
        assert_eq!(lines[1], "46.5,8.125,1234.5,2,0.25,90,egm96,");
        assert_eq!(lines[2], "-10,170,,,,,egm96,\"outside the dataset\"");
        let g: serde_json::Value = serde_json::from_str(&geojson(&answers(), &CX)).unwrap();
        assert_eq!(g["features"][0]["geometry"]["coordinates"][0], 8.125);
        assert_eq!(g["features"][0]["properties"]["elevation"], 1234.5);
        assert!(g["features"][1]["properties"]["elevation"].is_null());
    }
}
