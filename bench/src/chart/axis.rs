//! Value axes: ranges with their ticks (linear from nice steps, or whole decades),
//! values mapped to pixels, and the y axis drawn with its grid and labels.

use super::canvas::{Canvas, text_box};
use super::{PAD, SCALE};
use tessera_charts::format_compact;
use tessera_charts::plot::{AXIS, GRID, TEXT};
use tessera_charts::stats::{nice_step, widen_flat};

/// A value axis: `lo..hi` mapped onto pixels `near..far` (either direction).
#[derive(Clone, Copy, Debug)]
pub(super) struct Axis {
    pub(super) lo: f64,
    pub(super) hi: f64,
    pub(super) log: bool,
    pub(super) near: i64,
    pub(super) far: i64,
}

impl Axis {
    fn f(&self, v: f64) -> f64 {
        if self.log { v.log10() } else { v }
    }

    pub(super) fn px(&self, v: f64) -> i64 {
        let t = (self.f(v) - self.f(self.lo)) / (self.f(self.hi) - self.f(self.lo));
        let t = if t.is_finite() {
            t.clamp(0.0, 1.0)
        } else {
            0.0
        };
        self.near + ((self.far - self.near) as f64 * t).round() as i64
    }
}

/// A linear range covering `lo..hi` on multiples of a nice step, and the ticks.
pub(super) fn linear_range(lo: f64, hi: f64) -> (f64, f64, Vec<f64>) {
    let (lo, hi) = widen_flat(lo, hi);
    let step = nice_step((hi - lo) / 6.0);
    let (lo, hi) = ((lo / step).floor() * step, (hi / step).ceil() * step);
    let n = ((hi - lo) / step).round() as i64;
    let ticks = (0..=n).map(|k| lo + k as f64 * step).collect();
    (lo, hi, ticks)
}

/// Whole decades covering `lo..hi` (both > 0), starting strictly below `lo` so
/// that its bar has a height, and ticks at each decade, with 2× and 5× between
/// them when the range spans two decades or less.
pub(super) fn log_range(lo: f64, hi: f64) -> (f64, f64, Vec<f64>) {
    let mut a = lo.log10().floor() as i32;
    if 10f64.powi(a) >= lo * (1.0 - 1e-9) {
        a -= 1;
    }
    let b = (hi.log10().ceil() as i32).max(a + 1);
    let mut ticks = Vec::new();
    for e in a..=b {
        let d = 10f64.powi(e);
        ticks.push(d);
        if b - a <= 2 && e < b {
            ticks.extend([2.0 * d, 5.0 * d]);
        }
    }
    (10f64.powi(a), 10f64.powi(b), ticks)
}

/// The plot area's edges.
#[derive(Clone, Copy, Debug)]
pub(super) struct Area {
    pub(super) left: i64,
    pub(super) right: i64,
    pub(super) top: i64,
    pub(super) bottom: i64,
}

/// Horizontal grid lines with labels left of the area, and the y axis line.
pub(super) fn y_axis(canvas: &mut Canvas, area: Area, axis: Axis, ticks: &[f64]) {
    let (_, ch) = text_box("X", SCALE);
    for &t in ticks {
        let y = axis.px(t);
        canvas.fill(area.left, y, area.right - area.left, 1, GRID);
        let label = format_compact(t);
        let w = text_box(&label, SCALE).0;
        canvas.text(area.left - PAD - w, y - ch / 2, &label, TEXT, SCALE);
    }
    canvas.fill(area.left, area.top, 1, area.bottom - area.top + 1, AXIS);
    canvas.fill(area.left, area.bottom, area.right - area.left + 1, 1, AXIS);
}

/// The widest tick label.
pub(super) fn label_width(ticks: &[f64]) -> i64 {
    ticks
        .iter()
        .map(|&t| text_box(&format_compact(t), SCALE).0)
        .max()
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_and_steps_are_nice() {
        assert_eq!(nice_step(0.7), 1.0);
        assert_eq!(nice_step(1.2), 2.0);
        assert_eq!(nice_step(3.0), 5.0);
        assert_eq!(nice_step(700.0), 1000.0);
        let (lo, hi, ticks) = linear_range(0.0, 5368.0 * 1.08);
        assert_eq!((lo, hi), (0.0, 6000.0));
        assert_eq!(ticks.len(), 7);
        let (lo, hi, ticks) = log_range(11.0, 3000.0);
        assert_eq!((lo, hi), (10.0, 10000.0));
        assert_eq!(ticks, vec![10.0, 100.0, 1000.0, 10000.0]);
        assert_eq!(log_range(2.0, 50.0).2.len(), 7);
    }
}
