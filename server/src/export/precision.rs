//! Zoom-dependent vertical rounding for exported height tiles (`--precision auto`):
//! heights rounded to a step that grows with each zoom's pixel size, so neighbouring
//! pixels repeat more and PNG's deflate and WebP's lossless coder compress better
//! (the idea Mapterhorn ships its global terrain with).
//!
//! The step at zoom `z` is the largest power-of-two multiple of the encoding's own
//! step (1/256 m for Terrarium, 0.1 m for Terrain-RGB) that is at most `c(z)/32`,
//! where `c(z)` is the pixel's size at the equator (40 075 016.686 m / (px · 2^z)).
//! A rounded height is within half a step, at most `c(z)/64`, of the exact tile's; the
//! height difference between neighbouring pixels (`c(z)·cos φ` of ground apart at
//! latitude `φ`) changes by at most a step, so a slope between them by at most
//! `atan(1/(32·cos φ))`: 1.8° at the equator, 2.6° at 46° N. Steps never fall below
//! the encoding's own, where rounding changes nothing.

use crate::web::encoding::Encoding;

/// The equator's length on WGS 84, metres.
const EQUATOR_M: f64 = 40_075_016.685_578_5;

/// The rounding step (metres) of zoom `z` at `px`-pixel tiles for `encoding`.
pub fn step(z: u8, px: u32, encoding: Encoding) -> f64 {
    let pixel = EQUATOR_M / (f64::from(px) * f64::from(1u32 << z.min(31)));
    let unit = match encoding {
        Encoding::Terrarium => 1.0 / 256.0,
        Encoding::Mapbox => 0.1,
    };
    let k = (pixel / 32.0 / unit).log2().floor().max(0.0);
    unit * k.exp2()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_halve_with_each_zoom_and_stay_within_a_32nd_of_a_pixel() {
        for enc in [Encoding::Terrarium, Encoding::Mapbox] {
            for px in [256, 512] {
                let mut last = f64::INFINITY;
                for z in 0..=24 {
                    let q = step(z, px, enc);
                    let pixel = EQUATOR_M / (f64::from(px) * f64::from(1u32 << z));
                    let unit = if enc == Encoding::Terrarium {
                        1.0 / 256.0
                    } else {
                        0.1
                    };
                    assert!(q <= pixel / 32.0 || q == unit, "z{z}: {q} vs {pixel}");
                    assert!(q >= unit && q <= last);
                    // A power-of-two multiple of the unit: exactly representable.
                    assert_eq!((q / unit).log2().fract(), 0.0);
                    last = q;
                }
            }
        }
        // Terrarium at 512 px, zoom 12: 19.1 m pixels, 0.5 m steps.
        assert_eq!(step(12, 512, Encoding::Terrarium), 0.5);
    }
}
