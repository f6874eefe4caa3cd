//! Shaded relief as `gdaldem hillshade` computes it (GDAL's `gdaldem_lib.cpp`,
//! Horn gradient): grey levels 1–255 with 0 left for no data.
//!
//! With `z` the z-factor over Horn's 8, `x, y` the [`Gradient`], azimuth `az` and
//! altitude `alt`:
//! - **standard**: `c = (254·sin alt − 254·z·cos alt·(y·cos az − x·sin az)) /
//!   √(1 + z²(x² + y²))`; the grey is `1 + c`, or 1 where `c ≤ 0`.
//! - **combined** (`-combined`): the standard angle's arc cosine `θ`, then
//!   `c = 1 − θ·atan(√(z²(x² + y²)))·4/π²`, the grey `1 + 254·c` (1 where `c ≤ 0`):
//!   shading darkened by slope.
//! - **multidirectional** (`-multidirectional`, USGS OF 92-422): four lights at
//!   225°, 270°, 315° and 360°, each weighted by how squarely the slope faces it
//!   (weights `½g² − xy`, `x²`, `½g² + xy`, `y²` for `g² = x² + y²`), each light's
//!   value clamped at 0; the azimuth is not used.
//!
//! `gdaldem` approximates the reciprocal square root with one Newton step on
//! `rsqrt_ss` (relative error ≈ 1e-7); these use the exact one, so a grey can differ
//! by one level where the value lies within ~1e-5 of a half.

use super::gradient::Gradient;

/// Which of `gdaldem`'s shadings.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Method {
    Standard,
    Combined,
    Multidirectional,
}

impl Method {
    /// What `method=` accepts.
    pub const ALLOWED: &str = "standard, combined, multidirectional";

    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "standard" => Some(Self::Standard),
            "combined" => Some(Self::Combined),
            "multidirectional" => Some(Self::Multidirectional),
            _ => None,
        }
    }

    pub const fn name(self) -> &'static str {
        match self {
            Self::Standard => "standard",
            Self::Combined => "combined",
            Self::Multidirectional => "multidirectional",
        }
    }
}

/// The options of a hillshade, checked.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hillshade {
    /// Degrees clockwise from north, in `[0, 360)`.
    pub azimuth: f64,
    /// Degrees above the horizon, in `[0, 90]`.
    pub altitude: f64,
    /// Vertical exaggeration, `> 0`.
    pub z_factor: f64,
    pub method: Method,
}

impl Default for Hillshade {
    /// `gdaldem`'s defaults: light from the north-west, 45° up, no exaggeration.
    fn default() -> Self {
        Self {
            azimuth: 315.0,
            altitude: 45.0,
            z_factor: 1.0,
            method: Method::Standard,
        }
    }
}

/// Why hillshade options are refused: the parameter and the reason.
pub type Refusal = (&'static str, String);

impl Hillshade {
    /// Checked options (the azimuth taken modulo 360).
    pub fn new(
        azimuth: f64,
        altitude: f64,
        z_factor: f64,
        method: Method,
    ) -> Result<Self, Refusal> {
        if !azimuth.is_finite() {
            return Err(("azimuth", format!("{azimuth} is not a number of degrees")));
        }
        if !(0.0..=90.0).contains(&altitude) {
            return Err((
                "altitude",
                format!("{altitude} is not an angle above the horizon (0 to 90 degrees)"),
            ));
        }
        if !(z_factor.is_finite() && z_factor > 0.0 && z_factor <= 1e6) {
            return Err((
                "z_factor",
                format!("{z_factor} is not a vertical exaggeration (greater than 0, at most 1e6)"),
            ));
        }
        Ok(Self {
            azimuth: azimuth.rem_euclid(360.0),
            altitude,
            z_factor,
            method,
        })
    }

    /// The constants of every pixel's formula.
    pub fn lights(&self) -> Lights {
        let (sin_alt, cos_alt) = self.altitude.to_radians().sin_cos();
        let (sin_az, cos_az) = self.azimuth.to_radians().sin_cos();
        let z = self.z_factor / 8.0;
        Lights {
            method: self.method,
            z2: z * z,
            sin_alt,
            cz_cos_az: cos_alt * z * cos_az,
            cz_sin_az: cos_alt * z * sin_az,
            cz: cos_alt * z,
        }
    }
}

/// A hillshade's per-pixel constants.
#[derive(Clone, Copy, Debug)]
pub struct Lights {
    method: Method,
    z2: f64,
    sin_alt: f64,
    /// `cos alt · z · cos az`, and so on.
    cz_cos_az: f64,
    cz_sin_az: f64,
    cz: f64,
}

impl Lights {
    /// The grey level (1–255) of a pixel of gradient `g`.
    pub fn grey(&self, g: Gradient) -> u8 {
        let g2 = g.norm2();
        let value = match self.method {
            Method::Standard => {
                let c = 254.0 * (self.sin_alt - (g.y * self.cz_cos_az - g.x * self.cz_sin_az))
                    / (1.0 + self.z2 * g2).sqrt();
                if c <= 0.0 { 1.0 } else { 1.0 + c }
            }
            Method::Combined => {
                let slope2 = self.z2 * g2;
                let cos = (self.sin_alt - (g.y * self.cz_cos_az - g.x * self.cz_sin_az))
                    / (1.0 + slope2).sqrt();
                let theta = cos.clamp(-1.0, 1.0).acos();
                let c = 1.0 - theta * slope2.sqrt().atan() * 4.0 / (std::f64::consts::PI.powi(2));
                if c <= 0.0 { 1.0 } else { 1.0 + 254.0 * c }
            }
            Method::Multidirectional => {
                if g2 == 0.0 {
                    1.0 + 254.0 * self.sin_alt
                } else {
                    let s = 127.0 * self.sin_alt;
                    let c225 = 127.0 * std::f64::consts::FRAC_1_SQRT_2 * -self.cz;
                    let lit = |v: f64| v.max(0.0);
                    let v225 = lit(s + (g.x - g.y) * c225);
                    let v270 = lit(s - g.x * 127.0 * self.cz);
                    let v315 = lit(s + (g.x + g.y) * c225);
                    let v360 = lit(s - g.y * 127.0 * self.cz);
                    let w225 = 0.5 * g2 - g.x * g.y;
                    let weighted =
                        w225 * v225 + g.x * g.x * v270 + (g2 - w225) * v315 + g.y * g.y * v360;
                    1.0 + weighted / g2 / (1.0 + self.z2 * g2).sqrt()
                }
            }
        };
        // GDAL writes the float into a byte band: rounded, clamped.
        value.round().clamp(1.0, 255.0) as u8
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(east: f64, south: f64) -> Gradient {
        // A window rising `east` m per pixel eastwards and `south` southwards, 1 m pixels.
        let w: [f64; 9] = std::array::from_fn(|k| east * (k % 3) as f64 + south * (k / 3) as f64);
        Gradient::horn(&w, 1.0, 1.0)
    }

    #[test]
    fn flat_ground_is_lit_by_the_sine_of_the_altitude() {
        for method in [Method::Standard, Method::Multidirectional] {
            let h = Hillshade::new(315.0, 45.0, 1.0, method).unwrap();
            let grey = h.lights().grey(plane(0.0, 0.0));
            // 1 + 254·sin 45° = 180.6.
            assert_eq!(grey, 181, "{method:?}");
        }
        // Combined darkens by slope only: flat ground is white.
        let h = Hillshade::new(315.0, 45.0, 1.0, Method::Combined).unwrap();
        assert_eq!(h.lights().grey(plane(0.0, 0.0)), 255);
    }

    #[test]
    fn slopes_facing_the_light_are_brighter_than_slopes_facing_away() {
        let h = Hillshade::default().lights();
        // Ground rising to the south-east faces north-west, towards a 315° light.
        let towards = h.grey(plane(0.5, 0.5));
        let away = h.grey(plane(-0.5, -0.5));
        assert!(towards > 181 && away < 181, "{towards} {away}");
        // A light from the south-east swaps them.
        let se = Hillshade::new(135.0, 45.0, 1.0, Method::Standard)
            .unwrap()
            .lights();
        assert_eq!(se.grey(plane(-0.5, -0.5)), towards);
        // A face turned fully away from a low light is in shadow: grey 1.
        let low = Hillshade::new(315.0, 5.0, 1.0, Method::Standard)
            .unwrap()
            .lights();
        assert_eq!(low.grey(plane(-8.0, -8.0)), 1);
    }

    #[test]
    fn the_standard_formula_is_the_cosine_of_the_angle_of_incidence() {
        // cos i = sin alt·cos s + cos alt·sin s·cos(az − aspect), from first
        // principles, for a plane rising 0.4 east and 0.1 south (per 1 m pixel).
        let (p, q) = (0.4, 0.1);
        let slope = f64::atan(f64::hypot(p, q));
        // The downhill direction, clockwise from north (its east and north parts are
        // −p and +q): towards the west-north-west.
        let aspect = f64::atan2(-p, q);
        for (az, alt) in [(315.0f64, 45.0f64), (200.0, 30.0), (90.0, 60.0)] {
            let (az_r, alt_r) = (az.to_radians(), alt.to_radians());
            let cos_i =
                alt_r.sin() * slope.cos() + alt_r.cos() * slope.sin() * (az_r - aspect).cos();
            let want = if cos_i <= 0.0 {
                1.0
            } else {
                1.0 + 254.0 * cos_i
            };
            let got = Hillshade::new(az, alt, 1.0, Method::Standard)
                .unwrap()
                .lights()
                .grey(plane(p, q));
            assert_eq!(f64::from(got), want.round(), "az {az} alt {alt}");
        }
    }

    #[test]
    fn refused_options_name_their_parameter() {
        assert_eq!(
            Hillshade::new(0.0, 91.0, 1.0, Method::Standard)
                .unwrap_err()
                .0,
            "altitude"
        );
        assert_eq!(
            Hillshade::new(0.0, 45.0, 0.0, Method::Standard)
                .unwrap_err()
                .0,
            "z_factor"
        );
        assert_eq!(
            Hillshade::new(0.0, 45.0, -2.0, Method::Standard)
                .unwrap_err()
                .0,
            "z_factor"
        );
        assert_eq!(
            Hillshade::new(f64::NAN, 45.0, 1.0, Method::Standard)
                .unwrap_err()
                .0,
            "azimuth"
        );
        assert_eq!(
            Hillshade::new(-45.0, 45.0, 1.0, Method::Standard)
                .unwrap()
                .azimuth,
            315.0
        );
    }
}
