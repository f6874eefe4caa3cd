//! One panel of a [`plot_panels`](super::plot_panels) image: its plot area, the
//! grid, frame-number ticks, frame and polyline, and the figures they need (the y
//! range, the min/mean/max summary, the tick step).

use super::{AXIS, GRID, LINE, Series, TEXT, format_compact};
use crate::canvas::Canvas;
use crate::font::{GLYPH_HEIGHT, text_width};
use crate::stats::{min_max, nice_step, widen_flat};

/// Horizontal grid intervals per panel.
const Y_DIVISIONS: i64 = 4;

/// A panel's plot area: the frame is drawn on its outer pixels, `x0..x1` × `y0..y1`.
pub(super) struct Area {
    pub(super) x0: i64,
    pub(super) x1: i64,
    pub(super) y0: i64,
    pub(super) y1: i64,
}

impl Area {
    /// Where a line's stamps may go (top-left corners), inside the frame.
    fn inner(&self) -> (i64, i64, i64, i64) {
        (
            self.x0 + 1,
            self.x1 - 1 - LINE,
            self.y0 + 1,
            self.y1 - 1 - LINE,
        )
    }

    /// The column of frame `i` of `frames`.
    fn x(&self, i: usize, frames: usize) -> i64 {
        let (l, r, _, _) = self.inner();
        if frames <= 1 {
            i64::midpoint(l, r)
        } else {
            l + ((r - l) as f64 * i as f64 / (frames - 1) as f64).round() as i64
        }
    }

    /// The row of `v` in `lo..=hi`, or `None` if it is not finite.
    fn y(&self, v: f64, (lo, hi): (f64, f64)) -> Option<i64> {
        let (_, _, t, b) = self.inner();
        // Halves, so that extreme ranges do not overflow to infinity.
        let f = (v / 2.0 - lo / 2.0) / (hi / 2.0 - lo / 2.0);
        f.is_finite()
            .then(|| b - ((b - t) as f64 * f.clamp(0.0, 1.0)).round() as i64)
    }
}

/// Draws one panel into `area`: grid, ticks, frame and the values of `s` on `range`
/// (or "no data" without one), `frames` columns wide.
pub(super) fn draw_panel(
    canvas: &mut Canvas,
    area: &Area,
    s: &Series,
    range: Option<(f64, f64)>,
    frames: usize,
    scale: u32,
    colour: [u8; 4],
) {
    let ch = i64::from(GLYPH_HEIGHT * scale);
    let pad = 4 * i64::from(scale);
    let (aw, ah) = (area.x1 - area.x0, area.y1 - area.y0);
    // Horizontal grid.
    if let Some(range) = range {
        for k in 1..Y_DIVISIONS {
            let v = range.0 + (range.1 - range.0) * k as f64 / Y_DIVISIONS as f64;
            if let Some(y) = area.y(v, range) {
                canvas.fill_rect(area.x0, y + LINE / 2, aw, 1, GRID);
            }
        }
    }
    // Vertical grid and frame-number ticks.
    if frames > 0 {
        let widest = i64::from(text_width(&(frames - 1).to_string(), scale));
        let max_ticks = (aw / (widest + 8 * pad)).max(1) as usize;
        let step = frame_step((frames - 1) as f64 / max_ticks as f64);
        for f in (0..frames).step_by(step) {
            let x = area.x(f, frames) + LINE / 2;
            canvas.fill_rect(x, area.y0, 1, ah, GRID);
            canvas.fill_rect(x, area.y1, 1, pad / 2 + 1, AXIS);
            let label = f.to_string();
            let lw = i64::from(text_width(&label, scale));
            let lx = (x - lw / 2).clamp(0, (i64::from(canvas.width) - lw).max(0));
            canvas.text(lx, area.y1 + pad, &label, TEXT, scale);
        }
    }
    // Frame.
    canvas.fill_rect(area.x0, area.y0, aw, 1, AXIS);
    canvas.fill_rect(area.x0, area.y1 - 1, aw, 1, AXIS);
    canvas.fill_rect(area.x0, area.y0, 1, ah, AXIS);
    canvas.fill_rect(area.x1 - 1, area.y0, 1, ah, AXIS);
    // The values.
    let Some(range) = range else {
        let msg = "no data";
        let mw = i64::from(text_width(msg, scale));
        canvas.text(
            area.x0 + (aw - mw) / 2,
            area.y0 + (ah - ch) / 2,
            msg,
            TEXT,
            scale,
        );
        return;
    };
    let mut prev = None;
    for (i, &v) in s.values.iter().enumerate() {
        prev = area.y(v, range).map(|y| {
            let p = (area.x(i, frames), y);
            canvas.line(prev.unwrap_or(p), p, LINE, colour);
            p
        });
    }
}

/// The y range of a panel: the finite values' minimum and maximum, widened to
/// ±10 % (±1 around 0) for a constant series; `None` without finite values.
pub(super) fn y_range(values: &[f64]) -> Option<(f64, f64)> {
    min_max(values.iter().copied()).map(|(lo, hi)| widen_flat(lo, hi))
}

/// "min … mean … max …" of the finite values.
pub(super) fn summary(values: &[f64]) -> Option<String> {
    let (lo, hi) = min_max(values.iter().copied())?;
    let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    let mean = finite.iter().map(|v| v / finite.len() as f64).sum::<f64>();
    Some(format!(
        "min {}  mean {}  max {}",
        format_compact(lo),
        format_compact(mean),
        format_compact(hi)
    ))
}

/// Frames between x ticks: a nice step (1, 2, 5 × 10^k) of at least one frame.
fn frame_step(raw: f64) -> usize {
    let raw = if raw.is_nan() { 1.0 } else { raw.max(1.0) };
    (nice_step(raw).round()).min(usize::MAX as f64) as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_steps_are_round() {
        assert_eq!(frame_step(0.3), 1);
        assert_eq!(frame_step(1.0), 1);
        assert_eq!(frame_step(1.5), 2);
        assert_eq!(frame_step(3.0), 5);
        assert_eq!(frame_step(7.0), 10);
        assert_eq!(frame_step(10.0), 10);
        assert_eq!(frame_step(11.0), 20);
        assert_eq!(frame_step(240.0), 500);
        assert_eq!(frame_step(f64::NAN), 1);
    }
}
