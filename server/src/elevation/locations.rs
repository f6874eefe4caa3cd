//! Points on Earth (or the dataset's body) as the elevation API takes them: WGS 84
//! latitude and longitude in degrees, in the forms Google's Elevation API and
//! opentopodata accept (`lat,lon|lat,lon`, an encoded polyline) and as JSON.

use crate::http::error::quoted;
use serde::de::{self, Deserializer, MapAccess, SeqAccess, Visitor};
use std::fmt;

/// A checked point: latitude in −90..=90 and longitude in −180..=180 degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LatLon {
    lat: f64,
    lon: f64,
}

impl LatLon {
    /// The point, or why it is not one (naming the value out of range).
    pub fn new(lat: f64, lon: f64) -> Result<Self, String> {
        if !(lat.is_finite() && (-90.0..=90.0).contains(&lat)) {
            return Err(format!("latitude {lat} is not in -90..90"));
        }
        if !(lon.is_finite() && (-180.0..=180.0).contains(&lon)) {
            return Err(format!("longitude {lon} is not in -180..180"));
        }
        Ok(Self { lat, lon })
    }

    pub const fn lat(self) -> f64 {
        self.lat
    }

    pub const fn lon(self) -> f64 {
        self.lon
    }
}

/// Points written as text: `lat,lon|lat,lon|…`, or an encoded polyline (Google's
/// algorithm, precision 5), either prefixed `enc:` as Google writes it or bare as
/// opentopodata accepts it (a value without a comma). At most `max` points.
pub fn parse(text: &str, max: usize) -> Result<Vec<LatLon>, String> {
    let text = text.trim();
    if text.is_empty() {
        return Err("no points given".into());
    }
    if let Some(encoded) = text.strip_prefix("enc:") {
        return polyline(encoded, max);
    }
    if !text.contains(',') {
        return polyline(text, max);
    }
    let count = text.split('|').count();
    if count > max {
        return Err(format!("{count} points, more than the {max} allowed"));
    }
    text.split('|')
        .enumerate()
        .map(|(i, pair)| {
            let fail = |why: &str| format!("point {} ({}): {why}", i + 1, quoted(pair));
            let (a, b) = pair
                .split_once(',')
                .ok_or_else(|| fail("not \"lat,lon\""))?;
            let num = |s: &str, what: &str| {
                let s = s.trim();
                s.parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| fail(&format!("{what} {} is not a number", quoted(s))))
            };
            let (lat, lon) = (num(a, "latitude")?, num(b, "longitude")?);
            LatLon::new(lat, lon).map_err(|e| fail(&e))
        })
        .collect()
}

/// An encoded polyline's points.
fn polyline(encoded: &str, max: usize) -> Result<Vec<LatLon>, String> {
    let line = polyline::decode_polyline(encoded, 5)
        .map_err(|e| format!("not lat,lon pairs nor an encoded polyline ({e})"))?;
    if line.0.is_empty() {
        return Err("the encoded polyline holds no points".into());
    }
    if line.0.len() > max {
        return Err(format!(
            "{} points, more than the {max} allowed",
            line.0.len()
        ));
    }
    line.0
        .iter()
        .enumerate()
        .map(|(i, c)| LatLon::new(c.y, c.x).map_err(|e| format!("polyline point {}: {e}", i + 1)))
        .collect()
}

/// Points as a JSON body gives them: the same text as a query, or an array of
/// `[lat, lon]` pairs or `{"lat": …, "lng"|"lon": …}` objects.
#[derive(Debug)]
pub struct JsonPoints(pub Vec<LatLon>);

/// A JSON array's points, at most this many (a larger array stops at the first
/// point past it, before the rest is parsed).
#[derive(Debug)]
pub struct JsonLimit(pub usize);

impl<'de> de::DeserializeSeed<'de> for JsonLimit {
    type Value = JsonPoints;

    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<JsonPoints, D::Error> {
        d.deserialize_any(PointsVisitor(self.0))
    }
}

struct PointsVisitor(usize);

impl<'de> Visitor<'de> for PointsVisitor {
    type Value = JsonPoints;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("\"lat,lon|lat,lon\", an encoded polyline, or an array of [lat, lon] or {\"lat\", \"lng\"} points")
    }

    fn visit_str<E: de::Error>(self, v: &str) -> Result<JsonPoints, E> {
        parse(v, self.0).map(JsonPoints).map_err(E::custom)
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<JsonPoints, A::Error> {
        let mut out = Vec::with_capacity(seq.size_hint().unwrap_or(0).min(self.0));
        loop {
            let i = out.len();
            let p = seq
                .next_element::<JsonPoint>()
                .map_err(|e| de::Error::custom(format!("point {}: {e}", i + 1)))?;
            let Some(JsonPoint(p)) = p else { break };
            if i >= self.0 {
                return Err(de::Error::custom(format!(
                    "more than the {} points allowed",
                    self.0
                )));
            }
            out.push(p);
        }
        if out.is_empty() {
            return Err(de::Error::custom("no points given"));
        }
        Ok(JsonPoints(out))
    }
}

/// One JSON point.
struct JsonPoint(LatLon);

impl<'de> de::Deserialize<'de> for JsonPoint {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(PointVisitor)
    }
}

struct PointVisitor;

impl<'de> Visitor<'de> for PointVisitor {
    type Value = JsonPoint;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("[lat, lon] or {\"lat\": …, \"lng\": …}")
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<JsonPoint, A::Error> {
        let lat: f64 = seq
            .next_element()?
            .ok_or_else(|| de::Error::custom("expected [lat, lon]"))?;
        let lon: f64 = seq
            .next_element()?
            .ok_or_else(|| de::Error::custom("expected [lat, lon]"))?;
        if seq.next_element::<de::IgnoredAny>()?.is_some() {
            return Err(de::Error::custom("expected [lat, lon], got more numbers"));
        }
        LatLon::new(lat, lon)
            .map(JsonPoint)
            .map_err(de::Error::custom)
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<JsonPoint, A::Error> {
        let (mut lat, mut lon) = (None, None);
        while let Some(key) = map.next_key::<std::borrow::Cow<'de, str>>()? {
            let slot = match key.as_ref() {
                "lat" | "latitude" => &mut lat,
                "lng" | "lon" | "longitude" => &mut lon,
                other => {
                    return Err(de::Error::custom(format!(
                        "unknown key {}: a point has \"lat\" and \"lng\" (or \"lon\")",
                        quoted(other)
                    )));
                }
            };
            if slot.is_some() {
                return Err(de::Error::custom(format!("{} given twice", quoted(&key))));
            }
            *slot = Some(map.next_value::<f64>()?);
        }
        match (lat, lon) {
            (Some(lat), Some(lon)) => LatLon::new(lat, lon)
                .map(JsonPoint)
                .map_err(de::Error::custom),
            _ => Err(de::Error::custom(
                "a point needs \"lat\" and \"lng\" (or \"lon\")",
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::de::DeserializeSeed;

    fn json(s: &str, max: usize) -> Result<Vec<LatLon>, String> {
        let mut d = serde_json::Deserializer::from_str(s);
        JsonLimit(max)
            .deserialize(&mut d)
            .map(|p| p.0)
            .map_err(|e| e.to_string())
    }

    #[test]
    fn pairs_polylines_and_json_give_the_same_points() {
        let text = parse("38.5,-120.2|40.7,-120.95|43.252,-126.453", 10).unwrap();
        // Google's own example polyline for these three points.
        let enc = parse("enc:_p~iF~ps|U_ulLnnqC_mqNvxq`@", 10).unwrap();
        let bare = parse("_p~iF~ps|U_ulLnnqC_mqNvxq`@", 10).unwrap();
        assert_eq!(text.len(), 3);
        for (a, b) in text.iter().zip(&enc) {
            assert!((a.lat() - b.lat()).abs() < 1e-9 && (a.lon() - b.lon()).abs() < 1e-9);
        }
        assert_eq!(enc, bare);
        let pairs = json("[[38.5, -120.2], [40.7, -120.95], [43.252, -126.453]]", 10).unwrap();
        let objects = json(
            r#"[{"lat": 38.5, "lng": -120.2}, {"lat": 40.7, "lon": -120.95}, {"lng": -126.453, "lat": 43.252}]"#,
            10,
        )
        .unwrap();
        assert_eq!(pairs, text);
        assert_eq!(objects, text);
        assert_eq!(
            json(r#""38.5,-120.2|40.7,-120.95|43.252,-126.453""#, 10).unwrap(),
            text
        );
    }

    #[test]
    fn bad_points_name_the_point_and_the_problem() {
        let e = parse("46.5,8.1|91,8.2", 10).unwrap_err();
        assert!(e.contains("point 2") && e.contains("latitude 91"), "{e}");
        let e = parse("46.5,8.1|46.6,181", 10).unwrap_err();
        assert!(e.contains("longitude 181"), "{e}");
        let e = parse("46.5,abc", 10).unwrap_err();
        assert!(e.contains("point 1") && e.contains("\"abc\""), "{e}");
        let e = parse("46.5,8|46.5", 10).unwrap_err();
        assert!(e.contains("point 2"), "{e}");
        assert!(parse("46.5,NaN", 10).is_err());
        assert!(
            parse("1,1|2,2|3,3", 2)
                .unwrap_err()
                .contains("more than the 2")
        );
        assert!(parse("", 2).is_err());
        assert!(parse("enc:", 2).is_err());
        let e = json("[[1, 2], [3]]", 10).unwrap_err();
        assert!(e.contains("point 2"), "{e}");
        let e = json(r#"[{"lat": 1, "x": 2}]"#, 10).unwrap_err();
        assert!(e.contains("unknown key \"x\""), "{e}");
        let e = json("[[1, 2], [3, 4], [5, 6]]", 2).unwrap_err();
        assert!(e.contains("more than the 2"), "{e}");
        assert!(json("[]", 2).is_err());
        assert!(json("[[95, 2]]", 2).unwrap_err().contains("latitude 95"));
    }
}
