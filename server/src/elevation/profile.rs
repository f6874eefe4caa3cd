//! Profiles: points spaced evenly along a path's geodesics on the dataset's body
//! (WGS 84, or the sphere or ellipsoid the dataset's CRS names), by Karney's
//! algorithms (`geographiclib-rs`). A path's vertices are joined by the shortest
//! geodesic between them; the samples are spaced along the whole path's length, so
//! a vertex is a sample only where the spacing falls on it. The first and last
//! vertices always are.

use super::locations::LatLon;
use geographiclib_rs::{DirectGeodesic, Geodesic, InverseGeodesic};

/// How a profile is sampled.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Sampling {
    /// This many points, the first and last vertices included (`samples=`, ≥ 2).
    Samples(usize),
    /// A point every this many metres from the first vertex, then the last vertex
    /// (`spacing=`).
    Spacing(f64),
}

/// The body a profile runs on: equatorial and polar radii in metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Body {
    pub a: f64,
    pub b: f64,
}

impl Body {
    pub const WGS84: Body = Body {
        a: 6_378_137.0,
        b: 6_356_752.314_245_179,
    };

    /// The body of a dataset's CRS (WGS 84 where the CRS names none).
    pub fn of(footprint: &crate::web::footprint::Footprint) -> Self {
        footprint
            .crs()
            .body_radii()
            .map_or(Body::WGS84, |(a, b)| Body { a, b })
    }

    fn geodesic(self) -> Geodesic {
        Geodesic::new(self.a, (self.a - self.b) / self.a)
    }
}

/// The sampled points of `path` (at least two vertices), at most `max`; an error
/// says why there are none (too many, a bad spacing, a single vertex).
pub fn along(
    path: &[LatLon],
    sampling: Sampling,
    body: Body,
    max: usize,
) -> Result<Vec<LatLon>, String> {
    if path.len() < 2 {
        return Err("a path needs at least two points".into());
    }
    let g = body.geodesic();
    // Each leg: its start, azimuth there and length.
    let legs: Vec<(LatLon, f64, f64)> = path
        .windows(2)
        .map(|w| {
            let (s12, azi1, _azi2, _a12): (f64, f64, f64, f64) =
                g.inverse(w[0].lat(), w[0].lon(), w[1].lat(), w[1].lon());
            (w[0], azi1, s12)
        })
        .collect();
    let total: f64 = legs.iter().map(|l| l.2).sum();
    let distances: Vec<f64> = match sampling {
        Sampling::Samples(n) => {
            if n < 2 {
                return Err(format!("samples={n}: a profile needs at least 2"));
            }
            if n > max {
                return Err(format!("samples={n} is more than the {max} points allowed"));
            }
            (0..n).map(|i| total * i as f64 / (n - 1) as f64).collect()
        }
        Sampling::Spacing(step) => {
            if !(step.is_finite() && step > 0.0) {
                return Err(format!(
                    "spacing={step}: it must be a positive number of metres"
                ));
            }
            let inner = (total / step).ceil();
            if inner + 1.0 > max as f64 {
                return Err(format!(
                    "spacing={step} m over a path of {total:.1} m is {} points, more than the {max} allowed",
                    inner + 1.0
                ));
            }
            let mut d: Vec<f64> = (0..inner as usize).map(|i| step * i as f64).collect();
            d.push(total);
            if d.len() < 2 {
                d.insert(0, 0.0);
            }
            d
        }
    };
    let mut out = Vec::with_capacity(distances.len());
    let (mut leg, mut start) = (0usize, 0.0);
    for (i, &d) in distances.iter().enumerate() {
        while leg + 1 < legs.len() && d > start + legs[leg].2 {
            start += legs[leg].2;
            leg += 1;
        }
        let last = i + 1 == distances.len();
        let p = if last {
            // The last vertex as given, not as the geodesics arrive at it.
            path[path.len() - 1]
        } else {
            let (from, azi, len) = legs[leg];
            let s = (d - start).clamp(0.0, len);
            if s == 0.0 {
                from
            } else {
                let (lat, lon): (f64, f64) = g.direct(from.lat(), from.lon(), azi, s);
                LatLon::new(lat.clamp(-90.0, 90.0), wrap(lon))?
            }
        };
        out.push(p);
    }
    Ok(out)
}

/// A longitude into −180..=180.
fn wrap(lon: f64) -> f64 {
    if (-180.0..=180.0).contains(&lon) {
        lon
    } else {
        (lon + 180.0).rem_euclid(360.0) - 180.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(lat: f64, lon: f64) -> LatLon {
        LatLon::new(lat, lon).unwrap()
    }

    fn distance(a: LatLon, b: LatLon, body: Body) -> f64 {
        body.geodesic().inverse(a.lat(), a.lon(), b.lat(), b.lon())
    }

    /// Samples are evenly spaced along the geodesic (equal steps, summing to the
    /// path's length, each on the path), for both ways of asking.
    #[test]
    fn samples_are_even_along_the_geodesic() {
        let path = [p(46.0, 8.0), p(46.5, 8.5), p(46.9, 8.1)];
        let w = Body::WGS84;
        let total = distance(path[0], path[1], w) + distance(path[1], path[2], w);
        let s = along(&path, Sampling::Samples(11), w, 100).unwrap();
        assert_eq!(s.len(), 11);
        assert_eq!(s[0], path[0]);
        assert_eq!(s[10], path[2]);
        // The middle sample of a path whose legs are nearly equal is near the vertex,
        // and the steps are equal within a millimetre (the legs' corner aside).
        let steps: Vec<f64> = s.windows(2).map(|q| distance(q[0], q[1], w)).collect();
        for (i, d) in steps.iter().enumerate() {
            let on_corner = (total / 10.0 * i as f64) < distance(path[0], path[1], w)
                && (total / 10.0 * (i + 1) as f64) > distance(path[0], path[1], w);
            if !on_corner {
                assert!(
                    (d - total / 10.0).abs() < 1e-3,
                    "step {i}: {d} vs {}",
                    total / 10.0
                );
            }
        }
        // Spacing: every 1000 m, then the end.
        let s = along(&path, Sampling::Spacing(1000.0), w, 1000).unwrap();
        assert_eq!(s.len(), (total / 1000.0).ceil() as usize + 1);
        assert!((distance(s[0], s[1], w) - 1000.0).abs() < 1e-6);
        assert_eq!(*s.last().unwrap(), path[2]);
    }

    /// On the Moon's sphere a quarter meridian is a quarter of its circumference:
    /// the body is the dataset's, not the Earth's.
    #[test]
    fn profiles_run_on_the_datasets_body() {
        let moon = Body {
            a: 1_737_400.0,
            b: 1_737_400.0,
        };
        let s = along(
            &[p(0.0, 40.0), p(0.0, 50.0)],
            Sampling::Spacing(10_000.0),
            moon,
            1000,
        )
        .unwrap();
        let len = 1_737_400.0 * 10f64.to_radians();
        assert_eq!(s.len(), (len / 10_000.0).ceil() as usize + 1);
        // Along the equator the longitudes step evenly.
        let dlon = 10_000.0 / 1_737_400.0 * 180.0 / std::f64::consts::PI;
        assert!((s[1].lon() - 40.0 - dlon).abs() < 1e-9, "{}", s[1].lon());
    }

    #[test]
    fn bad_sampling_is_refused_with_a_reason() {
        let path = [p(46.0, 8.0), p(46.5, 8.5)];
        let w = Body::WGS84;
        assert!(
            along(&path[..1], Sampling::Samples(5), w, 10)
                .unwrap_err()
                .contains("two points")
        );
        assert!(
            along(&path, Sampling::Samples(1), w, 10)
                .unwrap_err()
                .contains("at least 2")
        );
        assert!(
            along(&path, Sampling::Samples(11), w, 10)
                .unwrap_err()
                .contains("more than the 10")
        );
        assert!(
            along(&path, Sampling::Spacing(0.0), w, 10)
                .unwrap_err()
                .contains("positive")
        );
        assert!(
            along(&path, Sampling::Spacing(1.0), w, 10)
                .unwrap_err()
                .contains("more than the 10")
        );
    }
}
