//! The report raster (`tessera_charts::canvas`) with the marks charts add on top.

use super::Image;
use tessera_charts::font::{GLYPH_HEIGHT, text_width};
use tessera_charts::plot::BACKGROUND;

/// The report raster (`tessera_charts::canvas`), with the marks
/// charts add on top: lines stamped centred on their points, labels on boxes, markers.
pub(super) struct Canvas {
    raster: tessera_charts::canvas::Canvas,
    pub(super) width: i64,
    pub(super) height: i64,
}

impl Canvas {
    pub(super) fn new(width: u32, height: u32) -> Self {
        Self {
            raster: tessera_charts::canvas::Canvas::new(width, height, BACKGROUND),
            width: i64::from(width),
            height: i64::from(height),
        }
    }

    pub(super) fn fill(&mut self, x: i64, y: i64, w: i64, h: i64, colour: [u8; 4]) {
        self.raster.fill_rect(x, y, w, h, colour);
    }

    /// A `t`-pixel-thick straight line, centred on the points.
    pub(super) fn line(&mut self, from: (i64, i64), to: (i64, i64), t: i64, colour: [u8; 4]) {
        let c = |(x, y): (i64, i64)| (x - t / 2, y - t / 2);
        self.raster.line(c(from), c(to), t, colour);
    }

    pub(super) fn text(&mut self, x: i64, y: i64, text: &str, colour: [u8; 4], scale: u32) {
        self.raster.text(x, y, text, colour, scale);
    }

    /// Text on a background-coloured box, so it stays legible over lines.
    pub(super) fn label(&mut self, x: i64, y: i64, text: &str, colour: [u8; 4], scale: u32) {
        let (w, h) = text_box(text, scale);
        self.fill(x - 2, y - 2, w + 4, h + 4, BACKGROUND);
        self.text(x, y, text, colour, scale);
    }

    /// A filled marker of `shape` (0–3: square, diamond, triangle, cross) centred
    /// on (`x`, `y`).
    pub(super) fn marker(&mut self, x: i64, y: i64, shape: usize, colour: [u8; 4]) {
        const R: i64 = 5;
        match shape % 4 {
            0 => self.fill(x - R + 1, y - R + 1, 2 * R - 1, 2 * R - 1, colour),
            1 => {
                for dy in -R..=R {
                    let half = R - dy.abs();
                    self.fill(x - half, y + dy, 2 * half + 1, 1, colour);
                }
            }
            2 => {
                for dy in 0..=2 * R {
                    let half = dy / 2;
                    self.fill(x - half, y - R + dy, 2 * half + 1, 1, colour);
                }
            }
            _ => {
                self.line((x - R, y - R), (x + R, y + R), 3, colour);
                self.line((x - R, y + R), (x + R, y - R), 3, colour);
            }
        }
    }

    pub(super) fn into_image(self) -> Image {
        let (rgba, width, height) = self.raster.into_parts();
        Image {
            rgba,
            width,
            height,
        }
    }
}

/// Width and height in pixels of `text` at `scale`.
pub(super) fn text_box(text: &str, scale: u32) -> (i64, i64) {
    (
        i64::from(text_width(text, scale)),
        i64::from(GLYPH_HEIGHT * scale),
    )
}
