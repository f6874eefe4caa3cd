//! Rendered terrain for 2-D maps: hillshade, colour relief and slope tiles on the
//! standard grids, computed as `gdaldem` computes them from the heights that the
//! height tiles carry (DECISIONS.md "Rendered terrain tiles").
//!
//! A tile's heights are resampled with a one-pixel border taken from its neighbours
//! ([`crate::web::resample::Plan::sample_bordered`]), so every pixel, the edges
//! included, has its full 3 × 3 window and neighbouring tiles join without seams.
//! Each row's pixels are measured in metres of ground on the body ([`ground`]), so
//! slopes are right on either grid at any latitude.
//!
//! No data is transparent: a pixel is drawn when it is terrain and, for hillshade
//! and slope, when its whole 3 × 3 window is (`gdaldem`'s rule without
//! `-compute_edges`: a one-pixel transparent ring around voids and the DEM's edge).
//! A colour ramp's `nv` entry colours pixels without data instead.

pub mod gradient;
pub mod ground;
pub mod hillshade;
pub mod ramp;
pub mod slope;

use gradient::Gradient;
use hillshade::Hillshade;
use ramp::Ramp;
use std::sync::Arc;

/// What a rendered tile shows.
#[derive(Clone, Debug)]
pub enum Layer {
    Hillshade(Hillshade),
    /// Heights coloured by a ramp.
    ColorRelief(Arc<Ramp>),
    /// Slopes in `unit`, coloured by a ramp.
    Slope(slope::Unit, Arc<Ramp>),
}

/// The three kinds, as URL segments name them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Kind {
    Hillshade,
    ColorRelief,
    Slope,
}

impl Kind {
    pub const ALL: [Self; 3] = [Self::Hillshade, Self::ColorRelief, Self::Slope];

    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == s)
    }

    pub const fn name(self) -> &'static str {
        match self {
            Self::Hillshade => "hillshade",
            Self::ColorRelief => "color-relief",
            Self::Slope => "slope",
        }
    }

    /// A title for documents (TileJSON, WMTS).
    pub const fn title(self) -> &'static str {
        match self {
            Self::Hillshade => "hillshade",
            Self::ColorRelief => "colour relief",
            Self::Slope => "slope",
        }
    }
}

impl Layer {
    pub const fn kind(&self) -> Kind {
        match self {
            Self::Hillshade(_) => Kind::Hillshade,
            Self::ColorRelief(_) => Kind::ColorRelief,
            Self::Slope(..) => Kind::Slope,
        }
    }
}

/// A tile's heights with a one-pixel border: `(px + 2)²` values, row-major, row 0
/// being the row above the tile.
#[derive(Clone, Copy, Debug)]
pub struct Bordered<'a> {
    /// The tile's side in pixels (without the border).
    pub px: usize,
    pub heights: &'a [f64],
    /// Whether each value is terrain (not no-data, not beyond the DEM).
    pub terrain: &'a [bool],
}

/// The tile's `px × px` RGBA pixels. `spacing[j]` is row `j`'s `[east–west,
/// north–south]` pixel size in metres of ground ([`ground::row_spacing`]).
pub fn paint(layer: &Layer, grid: Bordered<'_>, spacing: &[[f64; 2]]) -> Vec<u8> {
    let px = grid.px;
    let side = px + 2;
    assert_eq!(
        grid.heights.len(),
        side * side,
        "a bordered tile has (px + 2)² heights"
    );
    assert_eq!(spacing.len(), px, "one spacing per row");
    let mut out = vec![0u8; px * px * 4];
    let lights = match layer {
        Layer::Hillshade(h) => Some(h.lights()),
        _ => None,
    };
    let nodata = match layer {
        Layer::ColorRelief(r) | Layer::Slope(_, r) => r.nodata.unwrap_or([0; 4]),
        Layer::Hillshade(_) => [0; 4],
    };
    for (j, &[ew, ns]) in spacing.iter().enumerate() {
        for i in 0..px {
            // Pixel (i, j) of the tile is (i + 1, j + 1) of the bordered grid.
            let centre = (j + 1) * side + i + 1;
            let o = (j * px + i) * 4;
            let rgba = if !grid.terrain[centre] {
                nodata
            } else if let Layer::ColorRelief(r) = layer {
                r.colour(grid.heights[centre])
            } else {
                let at = |k: usize| (j + k / 3) * side + i + k % 3;
                if (0..9).all(|k| grid.terrain[at(k)]) {
                    let w: [f64; 9] = std::array::from_fn(|k| grid.heights[at(k)]);
                    let g = Gradient::horn(&w, ew, ns);
                    match (layer, &lights) {
                        (Layer::Slope(unit, r), _) => r.colour(unit.slope(g)),
                        (_, Some(l)) => {
                            let v = l.grey(g);
                            [v, v, v, 255]
                        }
                        _ => unreachable!("colour relief is handled above"),
                    }
                } else {
                    nodata
                }
            };
            out[o..o + 4].copy_from_slice(&rgba);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bordered 4 × 4 tile of a plane rising 1 m per pixel eastwards, with one
    /// void sample.
    fn plane(void: Option<usize>) -> (Vec<f64>, Vec<bool>) {
        let side = 6;
        let h = (0..side * side).map(|k| (k % side) as f64).collect();
        let mut t = vec![true; side * side];
        if let Some(v) = void {
            t[v] = false;
        }
        (h, t)
    }

    /// A ramp from its text, resolved without a range.
    fn ramp(text: &str) -> Arc<Ramp> {
        Arc::new(ramp::RampSpec::parse(text).unwrap().resolve(None).unwrap())
    }

    /// `layer` painted on [`plane`] with 1 m pixels.
    fn painted(layer: &Layer, void: Option<usize>) -> Vec<u8> {
        let (h, t) = plane(void);
        let grid = Bordered {
            px: 4,
            heights: &h,
            terrain: &t,
        };
        paint(layer, grid, &[[1.0, 1.0]; 4])
    }

    /// The tile pixels left transparent.
    fn blank(out: &[u8]) -> Vec<usize> {
        (0..16).filter(|&k| out[k * 4 + 3] == 0).collect()
    }

    #[test]
    fn every_pixel_reads_its_border_and_voids_leave_a_ring() {
        let layer = Layer::Slope(slope::Unit::Degrees, ramp("0 0 0 0\n90 180 0 0\n"));
        let out = painted(&layer, None);
        // 45° everywhere, edges included: 0.45 + 90 = 90.
        assert!(out.chunks(4).all(|p| p == [90, 0, 0, 255]), "{out:?}");
        // A void in the border's corner (bordered (0, 0)) blanks tile pixel (0, 0)
        // only; a void at the tile's pixel (2, 2) (bordered (3, 3)) blanks its 3 × 3.
        assert_eq!(blank(&painted(&layer, Some(0))), vec![0]);
        assert_eq!(
            blank(&painted(&layer, Some(3 * 6 + 3))),
            vec![5, 6, 7, 9, 10, 11, 13, 14, 15]
        );
        // Colour relief needs only the pixel itself.
        let relief = Layer::ColorRelief(ramp("0 0 0 0\n10 250 0 0\nnv 0 0 255 255\n"));
        let out = painted(&relief, Some(3 * 6 + 3));
        assert_eq!(
            &out[10 * 4..11 * 4],
            &[0, 0, 255, 255],
            "the void takes nv's colour"
        );
        assert_eq!(
            &out[9 * 4..10 * 4],
            &[50, 0, 0, 255],
            "height 2: 0.45 + 0.2·250"
        );
    }

    #[test]
    fn spacing_scales_the_slope() {
        let (h, t) = plane(None);
        let grid = Bordered {
            px: 4,
            heights: &h,
            terrain: &t,
        };
        let layer = Layer::Slope(slope::Unit::Percent, ramp("0 0 0 0\n255 255 0 0\n"));
        // 1 m per 2 m pixel in rows 0–1, per 0.5 m pixel in rows 2–3: 50 % and 200 %.
        let out = paint(
            &layer,
            grid,
            &[[2.0, 1.0], [2.0, 1.0], [0.5, 1.0], [0.5, 1.0]],
        );
        assert_eq!(out[0], 50);
        assert_eq!(out[3 * 16], 200);
    }
}
