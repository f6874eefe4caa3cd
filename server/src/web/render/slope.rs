//! Slope as `gdaldem slope` computes it (Horn gradient): `atan(√(x² + y²) / 8)` in
//! degrees, or `100·√(x² + y²) / 8` in percent, for the [`Gradient`] `x, y`.

use super::gradient::Gradient;

/// The unit slopes are measured in (`unit=`), as `gdaldem slope [-p]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Unit {
    Degrees,
    Percent,
}

impl Unit {
    /// What `unit=` accepts.
    pub const ALLOWED: &str = "degrees, percent";

    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "degrees" => Some(Self::Degrees),
            "percent" => Some(Self::Percent),
            _ => None,
        }
    }

    pub const fn name(self) -> &'static str {
        match self {
            Self::Degrees => "degrees",
            Self::Percent => "percent",
        }
    }

    /// The slope of a pixel of gradient `g`.
    pub fn slope(self, g: Gradient) -> f64 {
        let rise = g.norm2().sqrt() / 8.0;
        match self {
            Self::Degrees => rise.atan().to_degrees(),
            Self::Percent => 100.0 * rise,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_one_in_one_plane_is_45_degrees_or_100_percent() {
        // Rising 3 m east and 4 m south per 5 m pixel: 1 m per metre.
        let w: [f64; 9] = std::array::from_fn(|k| 3.0 * (k % 3) as f64 + 4.0 * (k / 3) as f64);
        let g = Gradient::horn(&w, 5.0, 5.0);
        assert!((Unit::Degrees.slope(g) - 45.0).abs() < 1e-12);
        assert!((Unit::Percent.slope(g) - 100.0).abs() < 1e-12);
    }
}
