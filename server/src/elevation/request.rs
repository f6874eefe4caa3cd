//! An elevation request, from a query string, a JSON body or the command line:
//! which points, how to interpolate, from which level, in which datum (API.md
//! "Elevation queries"). Every refusal names the parameter.

use super::kernel::Interpolation;
use super::locations::{self, JsonLimit, LatLon};
use super::profile::{self, Body, Sampling};
use crate::http::error::quoted;
use serde::de::{self, DeserializeSeed, Deserializer, MapAccess, Visitor};
use std::collections::HashMap;
use std::fmt;

/// Which vertical datum answers are given in (`datum=`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Datum {
    /// The dataset's own (the default).
    Native,
    /// Above the EGM96 geoid.
    Egm96,
    /// Above the ellipsoid (WGS 84's on Earth).
    Ellipsoid,
}

impl Datum {
    pub const ALL: [Datum; 3] = [Self::Native, Self::Egm96, Self::Ellipsoid];

    pub const fn name(self) -> &'static str {
        match self {
            Self::Native => "native",
            Self::Egm96 => "egm96",
            Self::Ellipsoid => "ellipsoid",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|d| d.name() == s)
    }
}

/// How each point is answered.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Options {
    pub interpolation: Interpolation,
    /// Answer from the coarsest level whose bound at the point is within this many
    /// metres; `None`: from the finest data there.
    pub accuracy: Option<f64>,
    pub datum: Datum,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            interpolation: Interpolation::Bilinear,
            accuracy: None,
            datum: Datum::Native,
        }
    }
}

/// A whole request: its points (a profile already sampled) and options.
#[derive(Clone, Debug, PartialEq)]
pub struct Request {
    pub points: Vec<LatLon>,
    pub options: Options,
    /// What a point without data gets instead of `null` (`nodata_value=`).
    pub nodata_value: Option<f64>,
}

/// The parameters as given, before the profile is sampled.
#[derive(Debug, Default)]
pub struct Raw {
    pub locations: Option<Vec<LatLon>>,
    pub path: Option<Vec<LatLon>>,
    pub samples: Option<usize>,
    pub spacing: Option<f64>,
    pub interpolation: Option<Interpolation>,
    pub accuracy: Option<f64>,
    pub datum: Option<Datum>,
    pub nodata_value: Option<f64>,
}

/// The parameters the API takes (a query naming another is refused).
pub const PARAMETERS: &str =
    "locations, path, samples, spacing, interpolation, accuracy, datum, nodata_value";

/// Parameters a query may carry that do not change the answer: `v` (the content
/// pin, API.md "Caching") and `key` (Google's clients always send an API key).
pub const IGNORED: [&str; 2] = ["v", "key"];

fn positive(name: &str, raw: &str) -> Result<f64, String> {
    raw.trim()
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite() && *v > 0.0)
        .ok_or_else(|| {
            format!(
                "{name}={}: expected a positive number of metres",
                quoted(raw)
            )
        })
}

fn samples(raw: &str) -> Result<usize, String> {
    raw.trim()
        .parse::<usize>()
        .ok()
        .ok_or_else(|| format!("samples={}: expected a whole number of points", quoted(raw)))
}

fn interpolation(raw: &str) -> Result<Interpolation, String> {
    Interpolation::parse(raw).ok_or_else(|| {
        format!(
            "interpolation={}: the methods are nearest, bilinear and cubic",
            quoted(raw)
        )
    })
}

fn datum(raw: &str) -> Result<Datum, String> {
    Datum::parse(raw).ok_or_else(|| {
        format!(
            "datum={}: the datums are native, egm96 and ellipsoid",
            quoted(raw)
        )
    })
}

fn nodata_value(raw: &str) -> Result<Option<f64>, String> {
    if raw == "null" {
        return Ok(None);
    }
    raw.trim()
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .map(Some)
        .ok_or_else(|| format!("nodata_value={}: expected null or a number", quoted(raw)))
}

impl Raw {
    /// From a query string's parameters.
    pub fn from_query(query: &HashMap<String, String>, max: usize) -> Result<Self, String> {
        let mut raw = Raw::default();
        for (k, v) in query {
            match k.as_str() {
                "locations" => {
                    raw.locations =
                        Some(locations::parse(v, max).map_err(|e| format!("locations: {e}"))?);
                }
                "path" => {
                    raw.path = Some(locations::parse(v, max).map_err(|e| format!("path: {e}"))?);
                }
                "samples" => raw.samples = Some(samples(v)?),
                "spacing" => raw.spacing = Some(positive("spacing", v)?),
                "interpolation" => raw.interpolation = Some(interpolation(v)?),
                "accuracy" => raw.accuracy = Some(positive("accuracy", v)?),
                "datum" => raw.datum = Some(datum(v)?),
                "nodata_value" => raw.nodata_value = nodata_value(v)?,
                k if IGNORED.contains(&k) => {}
                other => {
                    return Err(format!(
                        "unknown parameter {}: the elevation API takes {PARAMETERS}",
                        quoted(other)
                    ));
                }
            }
        }
        Ok(raw)
    }

    /// From a JSON body: an object with the same keys as the query (points also as
    /// arrays, numbers as numbers).
    pub fn from_json(body: &[u8], max: usize) -> Result<Self, String> {
        let mut d = serde_json::Deserializer::from_slice(body);
        let raw = BodySeed(max)
            .deserialize(&mut d)
            .and_then(|raw| d.end().map(|()| raw))
            .map_err(|e| format!("body: {e}"))?;
        Ok(raw)
    }

    /// The request: a profile sampled on `body` when a path (or `locations` with
    /// `samples`/`spacing`, as opentopodata takes it) is given.
    pub fn resolve(self, body: Body, max: usize) -> Result<Request, String> {
        let options = Options {
            interpolation: self.interpolation.unwrap_or(Interpolation::Bilinear),
            accuracy: self.accuracy,
            datum: self.datum.unwrap_or(Datum::Native),
        };
        let sampling = match (self.samples, self.spacing) {
            (Some(_), Some(_)) => {
                return Err("samples and spacing: give one of them, not both".into());
            }
            (Some(n), None) => Some(Sampling::Samples(n)),
            (None, Some(s)) => Some(Sampling::Spacing(s)),
            (None, None) => None,
        };
        let points = match (self.locations, self.path, sampling) {
            (Some(_), Some(_), _) => {
                return Err("locations and path: give one of them, not both".into());
            }
            (None, None, _) => return Err("locations= or path= is required".into()),
            (None, Some(_), None) => {
                return Err(
                    "path: a profile needs samples= (a number of points) or spacing= (metres)"
                        .into(),
                );
            }
            (Some(points), None, None) => points,
            (Some(path), None, Some(s)) | (None, Some(path), Some(s)) => {
                let name = match s {
                    Sampling::Samples(_) => "samples",
                    Sampling::Spacing(_) => "spacing",
                };
                profile::along(&path, s, body, max).map_err(|e| format!("{name}: {e}"))?
            }
        };
        Ok(Request {
            points,
            options,
            nodata_value: self.nodata_value,
        })
    }
}

/// A JSON body, points limited to `max`.
struct BodySeed(usize);

impl<'de> DeserializeSeed<'de> for BodySeed {
    type Value = Raw;

    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Raw, D::Error> {
        d.deserialize_map(self)
    }
}

impl<'de> Visitor<'de> for BodySeed {
    type Value = Raw;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(f, "an object with some of {PARAMETERS}")
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Raw, A::Error> {
        let mut raw = Raw::default();
        let mut seen: Vec<String> = Vec::new();
        let fail = |k: &str, e: String| de::Error::custom(format!("{k}: {e}"));
        while let Some(key) = map.next_key::<std::borrow::Cow<'de, str>>()? {
            if seen.iter().any(|s| s == key.as_ref()) {
                return Err(de::Error::custom(format!("{} given twice", quoted(&key))));
            }
            seen.push(key.to_string());
            match key.as_ref() {
                "locations" => raw.locations = Some(map.next_value_seed(JsonLimit(self.0))?.0),
                "path" => raw.path = Some(map.next_value_seed(JsonLimit(self.0))?.0),
                "samples" => {
                    let n: u64 = map.next_value()?;
                    raw.samples =
                        Some(usize::try_from(n).map_err(|_| fail("samples", "too large".into()))?);
                }
                "spacing" => {
                    let v: f64 = map.next_value()?;
                    raw.spacing =
                        Some(positive("spacing", &v.to_string()).map_err(de::Error::custom)?);
                }
                "accuracy" => {
                    let v: f64 = map.next_value()?;
                    raw.accuracy =
                        Some(positive("accuracy", &v.to_string()).map_err(de::Error::custom)?);
                }
                "interpolation" => {
                    let s: String = map.next_value()?;
                    raw.interpolation = Some(interpolation(&s).map_err(de::Error::custom)?);
                }
                "datum" => {
                    let s: String = map.next_value()?;
                    raw.datum = Some(datum(&s).map_err(de::Error::custom)?);
                }
                "nodata_value" => raw.nodata_value = map.next_value::<Option<f64>>()?,
                k if IGNORED.contains(&k) => {
                    map.next_value::<de::IgnoredAny>()?;
                }
                other => {
                    return Err(de::Error::custom(format!(
                        "unknown parameter {}: the elevation API takes {PARAMETERS}",
                        quoted(other)
                    )));
                }
            }
        }
        Ok(raw)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn query(pairs: &[(&str, &str)]) -> HashMap<String, String> {
        pairs
            .iter()
            .map(|(k, v)| ((*k).into(), (*v).into()))
            .collect()
    }

    fn get(pairs: &[(&str, &str)]) -> Result<Request, String> {
        Raw::from_query(&query(pairs), 1000)?.resolve(Body::WGS84, 1000)
    }

    #[test]
    fn query_and_json_give_the_same_request() {
        let q = get(&[
            ("locations", "46.5,8.1|46.6,8.2"),
            ("interpolation", "cubic"),
            ("accuracy", "2.5"),
            ("datum", "ellipsoid"),
            ("key", "ignored"),
        ])
        .unwrap();
        let j = Raw::from_json(
            br#"{"locations": [[46.5, 8.1], {"lat": 46.6, "lng": 8.2}], "interpolation": "cubic", "accuracy": 2.5, "datum": "ellipsoid"}"#,
            1000,
        )
        .unwrap()
        .resolve(Body::WGS84, 1000)
        .unwrap();
        assert_eq!(q, j);
        assert_eq!(q.options.interpolation, Interpolation::Cubic);
        assert_eq!(q.options.accuracy, Some(2.5));
        assert_eq!(q.points.len(), 2);
        // Defaults: bilinear, the finest data, the dataset's datum.
        let d = get(&[("locations", "46.5,8.1")]).unwrap();
        assert_eq!(d.options, Options::default());
        // A path sampled; locations with samples are a path too (opentopodata).
        let p = get(&[("path", "46.5,8.1|46.6,8.2"), ("samples", "7")]).unwrap();
        assert_eq!(p.points.len(), 7);
        let l = get(&[("locations", "46.5,8.1|46.6,8.2"), ("samples", "7")]).unwrap();
        assert_eq!(p, l);
    }

    #[test]
    fn every_refusal_names_its_parameter() {
        let cases: &[(&[(&str, &str)], &str)] = &[
            (
                &[("locations", "46.5,8.1"), ("color", "red")],
                "unknown parameter \"color\"",
            ),
            (
                &[("locations", "46.5,8.1"), ("interpolation", "spline")],
                "interpolation=\"spline\"",
            ),
            (
                &[("locations", "46.5,8.1"), ("accuracy", "-1")],
                "accuracy=",
            ),
            (
                &[("locations", "46.5,8.1"), ("accuracy", "NaN")],
                "accuracy=",
            ),
            (&[("locations", "46.5,8.1"), ("datum", "navd88")], "datum="),
            (
                &[("locations", "46.5,8.1"), ("nodata_value", "x")],
                "nodata_value=",
            ),
            (&[("locations", "95,8.1")], "locations: point 1"),
            (&[("path", "46.5,8.1|46.6,8.2")], "path: a profile needs"),
            (
                &[("path", "46.5,8.1|46.6,8.2"), ("samples", "5000")],
                "samples: samples=5000",
            ),
            (
                &[("path", "46.5,8.1|46.6,8.2"), ("samples", "x")],
                "samples=\"x\"",
            ),
            (
                &[
                    ("path", "46.5,8.1|46.6,8.2"),
                    ("samples", "3"),
                    ("spacing", "10"),
                ],
                "samples and spacing",
            ),
            (
                &[("locations", "1,1"), ("path", "1,1|2,2"), ("samples", "3")],
                "locations and path",
            ),
            (&[], "locations= or path= is required"),
        ];
        for (pairs, want) in cases {
            let e = get(pairs).unwrap_err();
            assert!(e.contains(want), "{pairs:?}: {e}");
        }
        for (body, want) in [
            (
                &br#"{"locations": "1,1", "colour": 1}"#[..],
                "unknown parameter \"colour\"",
            ),
            (
                br#"{"locations": [[1, 1]], "locations": [[2, 2]]}"#,
                "given twice",
            ),
            (br#"{"locations": [[1, 1], [2]]}"#, "point 2"),
            (br#"{"locations": [[1, 1]], "samples": -3}"#, "body:"),
            (b"[1, 2]", "body:"),
            (br#"{"locations": [[1, 1]]} trailing"#, "body:"),
        ] {
            let e = Raw::from_json(body, 1000).unwrap_err();
            assert!(e.contains(want), "{}: {e}", String::from_utf8_lossy(body));
        }
    }
}
