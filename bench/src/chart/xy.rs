//! [`XyChart`]: one polyline with markers per series, optionally on a logarithmic
//! x axis.

use super::axis::{Area, Axis, label_width, linear_range, log_range, y_axis};
use super::canvas::{Canvas, text_box};
use super::frame::{header, no_data};
use super::{Image, PAD, SCALE, SMALL, plain};
use tessera_charts::format_compact;
use tessera_charts::plot::{AXIS, GRID, PALETTE, TEXT};
use tessera_charts::stats::min_max;

/// A point of an [`XySeries`], with an optional small label beside its marker.
#[derive(Clone, Debug)]
pub struct Point {
    pub x: f64,
    pub y: f64,
    pub label: Option<String>,
}

#[derive(Clone, Debug)]
pub struct XySeries {
    pub name: String,
    pub points: Vec<Point>,
}

#[derive(Clone, Debug, Default)]
pub struct XyChart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<XySeries>,
    /// Logarithmic x axis; points with x ≤ 0 are left out.
    pub log_x: bool,
}

impl XyChart {
    /// Draws the chart into a `width`×`height` image.
    pub fn draw(&self, width: u32, height: u32) -> Image {
        let mut canvas = Canvas::new(width, height);
        let names: Vec<String> = self.series.iter().map(|s| s.name.clone()).collect();
        let swatch = |c: &mut Canvas, x: i64, y: i64, i: usize| {
            let (_, ch) = text_box("X", SCALE);
            let colour = PALETTE[i % PALETTE.len()];
            c.line((x, y + ch / 2), (x + ch, y + ch / 2), 2, colour);
            c.marker(x + ch / 2, y + ch / 2, i, colour);
        };
        let top = header(&mut canvas, &self.title, &self.y_label, &names, &swatch);
        let usable = |p: &Point| p.x.is_finite() && p.y.is_finite() && (!self.log_x || p.x > 0.0);
        let points: Vec<&Point> = self
            .series
            .iter()
            .flat_map(|s| s.points.iter())
            .filter(|p| usable(p))
            .collect();
        let (Some((x_lo, x_hi)), Some((y_lo, y_hi))) = (
            min_max(points.iter().map(|p| p.x)),
            min_max(points.iter().map(|p| p.y)),
        ) else {
            no_data(&mut canvas, top);
            return canvas.into_image();
        };
        let (x_lo, x_hi, x_ticks) = if self.log_x {
            log_range(x_lo, x_hi)
        } else {
            linear_range(x_lo, x_hi)
        };
        let margin = (y_hi - y_lo) * 0.05;
        let (y_lo, y_hi, y_ticks) = linear_range(y_lo - margin, y_hi + margin);
        let (_, ch) = text_box("X", SCALE);
        let x_label = plain(&self.x_label);
        let area = Area {
            left: 2 * PAD + label_width(&y_ticks) + PAD,
            right: canvas.width - 3 * PAD - label_width(&x_ticks) / 2,
            top,
            bottom: canvas.height - ch - 3 * PAD - if x_label.is_empty() { 0 } else { ch + PAD },
        };
        if area.right - area.left < 20 || area.bottom - area.top < 20 {
            return canvas.into_image();
        }
        let ax = Axis {
            lo: x_lo,
            hi: x_hi,
            log: self.log_x,
            near: area.left,
            far: area.right,
        };
        let ay = Axis {
            lo: y_lo,
            hi: y_hi,
            log: false,
            near: area.bottom,
            far: area.top,
        };
        y_axis(&mut canvas, area, ay, &y_ticks);
        for &t in &x_ticks {
            let x = ax.px(t);
            canvas.fill(x, area.top, 1, area.bottom - area.top, GRID);
            canvas.fill(x, area.bottom, 1, PAD / 2, AXIS);
            let label = format_compact(t);
            let w = text_box(&label, SCALE).0;
            canvas.text(x - w / 2, area.bottom + PAD, &label, TEXT, SCALE);
        }
        canvas.fill(area.left, area.top, 1, area.bottom - area.top + 1, AXIS);
        if !x_label.is_empty() {
            let w = text_box(&x_label, SCALE).0;
            let y = area.bottom + PAD + ch + PAD;
            canvas.text((area.left + area.right - w) / 2, y, &x_label, TEXT, SCALE);
        }
        for (i, s) in self.series.iter().enumerate() {
            let colour = PALETTE[i % PALETTE.len()];
            let mut pts: Vec<&Point> = s.points.iter().filter(|p| usable(p)).collect();
            pts.sort_by(|a, b| a.x.total_cmp(&b.x));
            let px: Vec<(i64, i64)> = pts.iter().map(|p| (ax.px(p.x), ay.px(p.y))).collect();
            for w in px.windows(2) {
                canvas.line(w[0], w[1], 2, colour);
            }
            for (p, &(x, y)) in pts.iter().zip(&px) {
                canvas.marker(x, y, i, colour);
                if let Some(label) = &p.label {
                    canvas.text(x + 7, y - 14, &plain(label), colour, SMALL);
                }
            }
        }
        canvas.into_image()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chart::{HEIGHT, WIDTH};

    #[test]
    fn xy_points_land_in_order_on_a_log_axis() {
        let chart = XyChart {
            title: "PSNR against triangles".into(),
            x_label: "triangles".into(),
            y_label: "dB".into(),
            series: vec![XySeries {
                name: "s".into(),
                points: [(1e3, 40.0), (1e4, 45.0), (1e5, 50.0)]
                    .into_iter()
                    .map(|(x, y)| Point { x, y, label: None })
                    .collect(),
            }],
            log_x: true,
        };
        let img = chart.draw(WIDTH, HEIGHT);
        assert_eq!((img.width, img.height), (WIDTH, HEIGHT));
        // Equal decades are equal distances: the marker columns are evenly spaced.
        let cols: Vec<u32> = (0..img.width)
            .filter(|&x| {
                (0..img.height)
                    .filter(|&y| img.pixel(x, y) == PALETTE[0])
                    .count()
                    >= 9
            })
            .collect();
        let centres = runs_centres(&cols);
        // The legend key is the first; then the three markers.
        assert_eq!(centres.len(), 4, "{centres:?}");
        let (d1, d2) = (centres[2] - centres[1], centres[3] - centres[2]);
        assert!(d1.abs_diff(d2) <= 2, "{centres:?}");
    }

    /// Centres of runs of consecutive numbers.
    fn runs_centres(v: &[u32]) -> Vec<u32> {
        let mut out = Vec::new();
        let mut start = None;
        for (i, &x) in v.iter().enumerate() {
            let s = *start.get_or_insert(x);
            if v.get(i + 1) != Some(&(x + 1)) {
                out.push(u32::midpoint(s, x));
                start = None;
            }
        }
        out
    }
}
