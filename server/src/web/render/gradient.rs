//! Horn's 3 × 3 gradient, as `gdaldem` computes it for hillshade and slope (its
//! default `-alg Horn`).

/// The weighted differences of a 3 × 3 window of heights, over the pixel's ground
/// spacing, without Horn's 1/8 (the products fold it into their own constants as
/// `gdaldem` does): `x` is west minus east, `y` north minus south, so both are
/// positive where the ground falls towards the east or the south.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gradient {
    pub x: f64,
    pub y: f64,
}

impl Gradient {
    /// The gradient of window `w` (row-major, north row first: `w[0]` north-west,
    /// `w[8]` south-east) over pixels `ew` by `ns` metres.
    pub fn horn(w: &[f64; 9], ew: f64, ns: f64) -> Self {
        let west = w[0] + 2.0 * w[3] + w[6];
        let east = w[2] + 2.0 * w[5] + w[8];
        let north = w[0] + 2.0 * w[1] + w[2];
        let south = w[6] + 2.0 * w[7] + w[8];
        Self {
            x: (west - east) / ew,
            y: (north - south) / ns,
        }
    }

    /// `x² + y²`.
    pub fn norm2(self) -> f64 {
        self.x * self.x + self.y * self.y
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plane_has_horns_gradient_times_eight() {
        // h = 3·col − 2·row on 10 m by 20 m pixels: rising east 0.3 m/m, falling
        // south 0.1 m/m.
        let w: [f64; 9] = std::array::from_fn(|k| 3.0 * (k % 3) as f64 - 2.0 * (k / 3) as f64);
        let g = Gradient::horn(&w, 10.0, 20.0);
        assert!((g.x / 8.0 + 0.3).abs() < 1e-12, "{g:?}");
        assert!((g.y / 8.0 - 0.1).abs() < 1e-12, "{g:?}");
    }
}
