//! Which contour levels a tile draws: a fixed interval, or one chosen per zoom from
//! the 1-2-5 series so that lines keep a readable distance on screen; and the
//! finest interval a zoom accepts.

use crate::crs::Crs;
use crate::web::tile_matrix::TileMatrixSet;

/// An automatic interval is the smallest 1-2-5 step at least this many pixels'
/// ground size: on a 45° slope its lines lie at least 3 pixels apart, on a 20°
/// slope 8 (512-pixel tiles in the Alps, 13 m pixels at zoom 12, get 50 m there
/// and 10 m at zoom 14).
pub const AUTO_PIXELS: f64 = 3.0;

/// The finest interval a zoom accepts, as a fraction of a pixel's ground size: at
/// 1 % a 45° slope already crosses 100 levels per pixel, ink and no map.
pub const MIN_PIXEL_FRACTION: f64 = 0.01;

/// The finest interval at any zoom, in the unit asked for (metres or feet): heights
/// are not known better.
pub const MIN_INTERVAL: f64 = 0.01;

/// The interval asked for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Interval {
    /// One per zoom ([`AUTO_PIXELS`]).
    Auto,
    /// Metres between lines, at every zoom.
    Fixed(f64),
}

impl Interval {
    /// `auto` or a positive number of units.
    pub fn parse(raw: &str) -> Result<Self, String> {
        if raw == "auto" {
            return Ok(Self::Auto);
        }
        match raw.parse::<f64>() {
            Ok(v) if v.is_finite() && v >= MIN_INTERVAL => Ok(Self::Fixed(v)),
            Ok(v) if v.is_finite() => Err(format!(
                "{raw:?} is finer than the finest interval, {MIN_INTERVAL}{}",
                if v <= 0.0 {
                    " (it must be positive)"
                } else {
                    ""
                }
            )),
            _ => Err(format!("{raw:?} is neither a number nor auto")),
        }
    }

    /// How the interval reads in a query: `auto` or its number.
    pub fn name(self) -> String {
        match self {
            Self::Auto => "auto".into(),
            Self::Fixed(v) => format!("{v}"),
        }
    }

    /// The interval where a pixel is `ground` across (both in the unit named `unit`), or
    /// why that is too fine there (naming the finest allowed).
    pub fn at(self, ground: f64, unit: &str) -> Result<f64, String> {
        match self {
            Self::Auto => Ok(nice_at_least(ground * AUTO_PIXELS).max(MIN_INTERVAL)),
            Self::Fixed(v) => {
                let finest = ground * MIN_PIXEL_FRACTION;
                if v < finest {
                    Err(format!(
                        "{v} {unit} is finer than this zoom can draw: its pixels are {ground:.1} {unit} across, and the finest interval is {} {unit} ({} % of a pixel)",
                        nice_at_least(finest),
                        MIN_PIXEL_FRACTION * 100.0
                    ))
                } else {
                    Ok(v)
                }
            }
        }
    }
}

/// The smallest value of the 1-2-5 series (…, 0.5, 1, 2, 5, 10, 20, …) not below `x`.
pub fn nice_at_least(x: f64) -> f64 {
    if !(x.is_finite() && x > 0.0) {
        return 1.0;
    }
    let decade = 10f64.powf(x.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * decade)
        .find(|&v| v >= x * (1.0 - 1e-12))
        .unwrap_or(10.0 * decade)
}

/// The ground size in metres of a pixel of a `px`-pixel tile at zoom `z`, at
/// latitude `lat` (degrees): Web Mercator's pixels shrink with the cosine of the
/// latitude; WorldCRS84Quad's are taken north–south (a degree of latitude).
pub fn ground_pixel(tms: TileMatrixSet, z: u8, px: u32, lat: f64) -> f64 {
    let size = tms.cell_size(z, px) * tms.metres_per_unit();
    match tms {
        TileMatrixSet::WebMercatorQuad => size * lat.to_radians().cos().max(0.01),
        TileMatrixSet::WorldCrs84Quad => size,
    }
}

/// How much smaller than the Earth's a dataset's body makes a pixel's ground: the
/// grids' metres are WGS 84's, and on another body the grid's longitudes and
/// latitudes are the dataset's own (routes/rendered.rs), so its pixels shrink with its
/// radius. 1 on the Earth.
pub fn body_scale(crs: &Crs) -> f64 {
    match crs.body_radii() {
        Some((a, _)) if !crs.is_earth() => a / 6_378_137.0,
        _ => 1.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_moons_pixels_are_smaller_by_its_radius() {
        let moon = Crs::parse("+proj=longlat +R=1737400 +no_defs").unwrap();
        assert!((body_scale(&moon) - 1_737_400.0 / 6_378_137.0).abs() < 1e-12);
        assert_eq!(body_scale(&Crs::from_epsg(4326).unwrap()), 1.0);
        assert_eq!(body_scale(&Crs::from_epsg(2056).unwrap()), 1.0);
    }

    #[test]
    fn the_series_is_one_two_five() {
        assert_eq!(nice_at_least(0.7), 1.0);
        assert_eq!(nice_at_least(1.0), 1.0);
        assert_eq!(nice_at_least(1.01), 2.0);
        assert_eq!(nice_at_least(36.0), 50.0);
        assert_eq!(nice_at_least(78.3), 100.0);
        assert_eq!(nice_at_least(100.0), 100.0);
        assert_eq!(nice_at_least(0.03), 0.05);
    }

    #[test]
    fn automatic_intervals_halve_per_zoom_or_so_and_are_readable() {
        let at = |z| {
            let g = ground_pixel(TileMatrixSet::WebMercatorQuad, z, 512, 46.5);
            Interval::Auto.at(g, "m").unwrap()
        };
        // The Alps at 512-pixel tiles: 13.2 m pixels at zoom 12.
        assert_eq!(at(12), 50.0);
        assert_eq!(at(14), 10.0);
        for z in 1..20 {
            let (coarse, fine) = (at(z), at(z + 1));
            assert!(
                fine <= coarse && fine >= coarse / 2.5,
                "{z}: {coarse} → {fine}"
            );
            let g = ground_pixel(TileMatrixSet::WebMercatorQuad, z, 512, 46.5);
            assert!(at(z) >= AUTO_PIXELS * g && at(z) < 2.5 * AUTO_PIXELS * g);
        }
    }

    #[test]
    fn absurd_intervals_are_refused_with_the_finest_allowed() {
        let g = ground_pixel(TileMatrixSet::WebMercatorQuad, 2, 512, 0.0);
        let why = Interval::Fixed(0.01).at(g, "m").unwrap_err();
        assert!(why.contains("finest interval is 200 m"), "{why}");
        assert_eq!(Interval::Fixed(200.0).at(g, "m"), Ok(200.0));
        assert!(Interval::parse("0.001").unwrap_err().contains("finer"));
        assert!(Interval::parse("-5").unwrap_err().contains("positive"));
        assert!(Interval::parse("NaN").is_err());
        assert!(Interval::parse("inf").is_err());
        assert_eq!(Interval::parse("auto"), Ok(Interval::Auto));
        assert_eq!(Interval::parse("12.5"), Ok(Interval::Fixed(12.5)));
    }
}
