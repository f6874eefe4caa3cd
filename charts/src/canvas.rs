//! A minimal RGBA8 raster for the report images: filled rectangles, thick lines
//! and text, all clipped to the image.

use crate::font;

/// An RGBA8 image, row-major, top row first.
#[derive(Debug)]
pub struct Canvas {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<u8>,
}

impl Canvas {
    pub fn new(width: u32, height: u32, background: [u8; 4]) -> Self {
        Self {
            width,
            height,
            rgba: background.repeat(width as usize * height as usize),
        }
    }

    pub fn into_parts(self) -> (Vec<u8>, u32, u32) {
        (self.rgba, self.width, self.height)
    }

    /// Blends `colour` onto pixel (`x`, `y`) if it lies inside the image.
    pub fn put(&mut self, x: i64, y: i64, colour: [u8; 4]) {
        if (0..i64::from(self.width)).contains(&x) && (0..i64::from(self.height)).contains(&y) {
            let at = ((y * i64::from(self.width) + x) * 4) as usize;
            font::blend(&mut self.rgba[at..at + 4], colour);
        }
    }

    /// Fills the `w`×`h` rectangle with its top-left corner at (`x`, `y`).
    pub fn fill_rect(&mut self, x: i64, y: i64, w: i64, h: i64, colour: [u8; 4]) {
        let (x0, x1) = (x.max(0), (x + w).min(i64::from(self.width)));
        let (y0, y1) = (y.max(0), (y + h).min(i64::from(self.height)));
        for py in y0..y1 {
            for px in x0..x1 {
                self.put(px, py, colour);
            }
        }
    }

    /// A line from (`x0`, `y0`) to (`x1`, `y1`), each point a `thickness`-pixel
    /// square whose top-left is the point (Bresenham).
    pub fn line(
        &mut self,
        (x0, y0): (i64, i64),
        (x1, y1): (i64, i64),
        thickness: i64,
        colour: [u8; 4],
    ) {
        let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
        let (sx, sy) = (if x0 < x1 { 1 } else { -1 }, if y0 < y1 { 1 } else { -1 });
        let (mut x, mut y, mut err) = (x0, y0, dx + dy);
        loop {
            self.fill_rect(x, y, thickness, thickness, colour);
            if x == x1 && y == y1 {
                break;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    pub fn text(&mut self, x: i64, y: i64, text: &str, colour: [u8; 4], scale: u32) {
        let clamp = |v: i64| v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
        font::draw_text(
            &mut self.rgba,
            self.width,
            self.height,
            clamp(x),
            clamp(y),
            text,
            colour,
            scale,
        );
    }
}
