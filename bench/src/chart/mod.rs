//! The two kinds of chart in BENCHMARKS.md, drawn as PNGs with the client's 5×7
//! bitmap font and plot colours (no plotting crates):
//!
//! - [`BarChart`]: grouped bars — categories along x, one bar per series in each,
//!   a y axis with a grid (linear from zero, or logarithmic), optional labelled
//!   horizontal reference lines ("aim 0.5 ms", "Kang 3.0 ms") and each bar's value
//!   written above it where it fits. For comparing a few measurements with their
//!   peers and with the aims.
//! - [`XyChart`]: one polyline with markers per series, optionally on a
//!   logarithmic x axis. For trade-offs such as image quality against triangles.
//!
//! Both have a title and a legend; charts are [`WIDTH`]×[`HEIGHT`] in the report.
//! The font has ASCII letters, digits and a little punctuation (plus µ, τ, ρ), so
//! labels are passed through [`plain`] first.
//!
//! `canvas` holds the raster with the marks charts draw, `axis` the value axes
//! and their ranges, `frame` the title, legend and "no data" both kinds share;
//! `bar` and `xy` are the two kinds.

mod axis;
mod bar;
mod canvas;
mod frame;
mod xy;

pub use bar::{BarChart, BarSeries, Reference};
pub use xy::{Point, XyChart, XySeries};

use anyhow::Context;
use std::path::Path;

/// The report's chart size.
pub const WIDTH: u32 = 900;
pub const HEIGHT: u32 = 500;

/// Reference lines and their labels.
const REFERENCE: [u8; 4] = [70, 70, 70, 255];
/// Text scale for titles, legends and axis labels (5×7 glyphs become 10×14).
const SCALE: u32 = 2;
/// Text scale for the small labels on bars and points.
const SMALL: u32 = 1;
const PAD: i64 = 8;

/// An RGBA8 image, rows top to bottom.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub rgba: Vec<u8>,
    pub width: u32,
    pub height: u32,
}

impl Image {
    /// The pixel at (`x`, `y`); panics outside the image.
    #[cfg(test)]
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 4] {
        let at = ((y * self.width + x) * 4) as usize;
        [
            self.rgba[at],
            self.rgba[at + 1],
            self.rgba[at + 2],
            self.rgba[at + 3],
        ]
    }

    /// Writes a PNG: to a temporary name beside `path`, then renamed into place.
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        tessera_charts::png::write_png(path, &self.rgba, self.width, self.height)
            .with_context(|| format!("{}: cannot write the chart", path.display()))
    }
}

/// `text` with the characters the bitmap font lacks replaced by look-alikes.
pub fn plain(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '–' | '—' | '−' => out.push('-'),
            '×' => out.push('x'),
            '÷' => out.push('/'),
            '≤' => out.push_str("<="),
            '≥' => out.push_str(">="),
            '±' => out.push_str("+/-"),
            '²' => out.push('2'),
            '³' => out.push('3'),
            'é' | 'è' => out.push('e'),
            'á' => out.push('a'),
            '`' | '"' | '\'' | '*' => {}
            _ => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_replaces_what_the_font_lacks() {
        assert_eq!(plain("1–2 × τ ≤ 0.5 ÷ `x`"), "1-2 x τ <= 0.5 / x");
    }
}
