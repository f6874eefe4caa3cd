//! Line plots of per-frame statistics: one panel per series, stacked vertically,
//! sharing an x axis of frame numbers.

use crate::canvas::Canvas;
use crate::font::{GLYPH_HEIGHT, text_width};
use crate::stats::nice_step;

/// One plotted quantity: a value per frame (frame `i` is `values[i]`).
/// Non-finite values (NaN, ±∞) are gaps in the line and do not affect the axes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Series {
    /// The panel's title ("triangles", "draw calls", …).
    pub title: String,
    /// Shown after the title in parentheses when not empty ("ms", "MB", …).
    pub unit: String,
    pub values: Vec<f64>,
}

impl Series {
    pub fn new(title: impl Into<String>, unit: impl Into<String>, values: Vec<f64>) -> Self {
        Self {
            title: title.into(),
            unit: unit.into(),
            values,
        }
    }
}

/// The plot's background.
pub const BACKGROUND: [u8; 4] = [255, 255, 255, 255];
/// Grid lines.
pub const GRID: [u8; 4] = [226, 226, 226, 255];
/// The plot-area frame and tick marks.
pub const AXIS: [u8; 4] = [150, 150, 150, 255];
/// Titles and labels.
pub const TEXT: [u8; 4] = [35, 35, 35, 255];
/// Line colours, one per panel in turn.
pub const PALETTE: [[u8; 4]; 6] = [
    [31, 119, 180, 255],
    [214, 39, 40, 255],
    [44, 160, 44, 255],
    [148, 103, 189, 255],
    [255, 127, 14, 255],
    [23, 190, 207, 255],
];
/// Line thickness in pixels.
const LINE: i64 = 2;
/// Horizontal grid intervals per panel.
const Y_DIVISIONS: i64 = 4;

/// Plots `series` as panels `panel_height` pixels tall stacked in a `width`-wide
/// image, with `x_label` centred under the last one. Returns `(rgba, width, height)`;
/// the height is `series.len()`·`panel_height` plus a footer strip for `x_label`
/// (a lone panel saying "no series" stands in for an empty `series`).
///
/// Each panel has its title (and unit) top left, min/mean/max of its finite
/// values top right where there is room, its y range (the finite values' minimum
/// and maximum, widened around a constant series) labelled at the top and bottom
/// of the plot area, a light grid, frame-number ticks under the plot area, and
/// the values as a 2-pixel polyline, broken at non-finite values. All panels
/// share the x axis, so frame `i` is in the same column in each. Text is drawn at
/// scale 2 in images at least 700 wide with panels at least 150 tall, else at 1.
/// Degenerate sizes give degenerate (possibly empty) images, never a panic.
pub fn plot_panels(
    series: &[Series],
    x_label: &str,
    width: u32,
    panel_height: u32,
) -> (Vec<u8>, u32, u32) {
    let scale = if width >= 700 && panel_height >= 150 {
        2
    } else {
        1
    };
    let ch = i64::from(GLYPH_HEIGHT * scale);
    let pad = 4 * i64::from(scale);
    let footer = if x_label.is_empty() {
        pad
    } else {
        ch + 2 * pad
    };
    let panels = series.len().max(1) as i64;
    let height = (panels * i64::from(panel_height) + footer).min(i64::from(u32::MAX)) as u32;
    let mut canvas = Canvas::new(width, height, BACKGROUND);
    let w = i64::from(width);
    let ph = i64::from(panel_height);

    let ranges: Vec<Option<(f64, f64)>> = series.iter().map(|s| y_range(&s.values)).collect();
    let tick_labels: Vec<Option<(String, String)>> = ranges
        .iter()
        .map(|r| r.map(|(lo, hi)| (format_compact(lo), format_compact(hi))))
        .collect();
    // Shared x axis: the left margin fits every panel's y labels, the right one
    // half the widest frame number.
    let label_w = tick_labels
        .iter()
        .flatten()
        .map(|(lo, hi)| text_width(lo, scale).max(text_width(hi, scale)))
        .max()
        .unwrap_or(0)
        .max(text_width("0", scale));
    let frames = series.iter().map(|s| s.values.len()).max().unwrap_or(0);
    let frame_label_w = i64::from(text_width(&frames.saturating_sub(1).to_string(), scale));
    let ax0 = i64::from(label_w) + 2 * pad;
    let ax1 = w - (frame_label_w / 2).max(pad) - pad;
    let area_ok = ax1 - ax0 >= 8 && ph - 2 * (ch + 2 * pad) >= 8;

    if series.is_empty() {
        let msg = "no series";
        let mw = i64::from(text_width(msg, scale));
        canvas.text((w - mw) / 2, (ph - ch) / 2, msg, TEXT, scale);
    }
    for (i, s) in series.iter().enumerate() {
        let y0 = i as i64 * ph;
        let colour = PALETTE[i % PALETTE.len()];
        let title = if s.unit.is_empty() {
            s.title.clone()
        } else {
            format!("{} ({})", s.title, s.unit)
        };
        let title_x = if area_ok { ax0 } else { pad };
        canvas.text(title_x, y0 + pad, &title, TEXT, scale);
        if !area_ok {
            continue;
        }
        let area = Area {
            x0: ax0,
            x1: ax1,
            y0: y0 + ch + 2 * pad,
            y1: y0 + ph - ch - 2 * pad,
        };
        if let Some(summary) = summary(&s.values) {
            let sw = i64::from(text_width(&summary, scale));
            let title_end = title_x + i64::from(text_width(&title, scale));
            if ax1 - sw > title_end + 2 * ch {
                canvas.text(ax1 - sw, y0 + pad, &summary, TEXT, scale);
            }
        }
        draw_panel(&mut canvas, &area, s, ranges[i], frames, scale, colour);
        if let Some((lo, hi)) = &tick_labels[i] {
            let right = |t: &str| ax0 - pad - i64::from(text_width(t, scale));
            canvas.text(right(hi), area.y0, hi, TEXT, scale);
            canvas.text(right(lo), area.y1 - ch, lo, TEXT, scale);
        }
    }
    if !x_label.is_empty() {
        let lw = i64::from(text_width(x_label, scale));
        let centre = if area_ok {
            i64::midpoint(ax0, ax1)
        } else {
            w / 2
        };
        let x = (centre - lw / 2).clamp(0, (w - lw).max(0));
        canvas.text(x, panels * ph + pad, x_label, TEXT, scale);
    }
    canvas.into_parts()
}

/// A panel's plot area: the frame is drawn on its outer pixels, `x0..x1` × `y0..y1`.
struct Area {
    x0: i64,
    x1: i64,
    y0: i64,
    y1: i64,
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

fn draw_panel(
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
fn y_range(values: &[f64]) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .iter()
        .filter(|v| v.is_finite())
        .fold(None, |acc: Option<(f64, f64)>, &v| {
            Some(acc.map_or((v, v), |(lo, hi)| (lo.min(v), hi.max(v))))
        })?;
    if lo < hi {
        Some((lo, hi))
    } else {
        let d = if lo == 0.0 { 1.0 } else { lo.abs() * 0.1 };
        Some((lo - d, hi + d))
    }
}

/// "min … mean … max …" of the finite values.
fn summary(values: &[f64]) -> Option<String> {
    let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    let lo = finite.iter().copied().reduce(f64::min)?;
    let hi = finite.iter().copied().reduce(f64::max)?;
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

/// `v` in at most three significant digits with an SI-style suffix: `0.25`, `12`,
/// `1.23k`, `3.4M`, `5G`, `2T`; `1e-5` and `1.2e15` beyond those; `nan`, `inf`.
pub fn format_compact(v: f64) -> String {
    if v.is_nan() {
        return "nan".into();
    }
    if v.is_infinite() {
        return if v > 0.0 { "inf" } else { "-inf" }.into();
    }
    if v == 0.0 {
        return "0".into();
    }
    let sign = if v < 0.0 { "-" } else { "" };
    let a = v.abs();
    let scientific = || {
        let s = format!("{a:.2e}");
        let (mantissa, exp) = s.split_once('e').unwrap_or((&s, "0"));
        format!("{sign}{}e{exp}", trim_zeros(mantissa))
    };
    let mut e = a.log10().floor() as i32;
    if !(-3..15).contains(&e) {
        return scientific();
    }
    // Three significant digits: a ≈ m·10^(e−2), 100 ≤ m ≤ 999.
    let digits = |e: i32| (a / 10f64.powi(e - 2)).round();
    let mut m = digits(e);
    for _ in 0..2 {
        if m >= 1000.0 {
            e += 1;
        } else if m < 100.0 {
            e -= 1;
        } else {
            break;
        }
        m = digits(e);
    }
    if !(-3..15).contains(&e) {
        return scientific();
    }
    let (div, suffix) = match e {
        12.. => (12, "T"),
        9.. => (9, "G"),
        6.. => (6, "M"),
        3.. => (3, "k"),
        _ => (0, ""),
    };
    let decimals = (div + 2 - e).max(0) as usize;
    let x = m * 10f64.powi(e - 2 - div);
    format!("{sign}{}{suffix}", trim_zeros(&format!("{x:.decimals$}")))
}

/// "1.50" → "1.5", "2.00" → "2", "120" → "120".
fn trim_zeros(s: &str) -> &str {
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.')
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pixel(rgba: &[u8], width: u32, x: u32, y: u32) -> [u8; 4] {
        let at = ((y * width + x) * 4) as usize;
        [rgba[at], rgba[at + 1], rgba[at + 2], rgba[at + 3]]
    }

    /// (x, y) of every pixel in `colour`, in rows `rows`.
    fn pixels_of(
        rgba: &[u8],
        w: u32,
        rows: std::ops::Range<u32>,
        colour: [u8; 4],
    ) -> Vec<(u32, u32)> {
        rows.flat_map(|y| (0..w).map(move |x| (x, y)))
            .filter(|&(x, y)| pixel(rgba, w, x, y) == colour)
            .collect()
    }

    /// For each column holding a line pixel: (x, topmost y, bottommost y).
    fn columns(px: &[(u32, u32)]) -> Vec<(u32, u32, u32)> {
        let mut cols: Vec<(u32, u32, u32)> = Vec::new();
        let mut sorted = px.to_vec();
        sorted.sort_unstable();
        for (x, y) in sorted {
            match cols.last_mut() {
                Some(c) if c.0 == x => c.2 = c.2.max(y),
                _ => cols.push((x, y, y)),
            }
        }
        cols
    }

    #[test]
    fn increasing_series_runs_lower_left_to_upper_right() {
        let values: Vec<f64> = (0..100).map(f64::from).collect();
        let (w, ph) = (400, 200);
        let (rgba, width, height) =
            plot_panels(&[Series::new("triangles", "", values)], "frame", w, ph);
        assert_eq!((width, height), (w, ph + 7 + 8));
        let line = pixels_of(&rgba, w, 0..ph, PALETTE[0]);
        let cols = columns(&line);
        assert!(cols.len() > 300, "line spans only {} columns", cols.len());
        let (first, last) = (cols[0], cols[cols.len() - 1]);
        assert!(
            first.0 < w / 8 && last.0 > w * 7 / 8,
            "{first:?} … {last:?}"
        );
        assert!(first.1 > ph * 3 / 4, "starts at row {} of {ph}", first.1);
        assert!(last.2 < ph / 4, "ends at row {} of {ph}", last.2);
        // Monotone: each column's top is at or above the previous column's.
        for pair in cols.windows(2) {
            assert!(pair[1].1 <= pair[0].1, "{:?} then {:?}", pair[0], pair[1]);
        }
        // Nothing in the line colour below the panel or outside the plot columns.
        assert!(pixels_of(&rgba, w, ph..height, PALETTE[0]).is_empty());
    }

    #[test]
    fn decreasing_series_runs_upper_left_to_lower_right() {
        let values: Vec<f64> = (0..50).map(|i| 1e6 - f64::from(i) * 1e4).collect();
        let (rgba, w, _) = plot_panels(&[Series::new("bytes", "B", values)], "", 300, 120);
        let cols = columns(&pixels_of(&rgba, w, 0..120, PALETTE[0]));
        let (first, last) = (cols[0], cols[cols.len() - 1]);
        assert!(first.1 < last.1 && first.0 < last.0);
    }

    #[test]
    fn panels_stack_with_their_own_colours() {
        let up: Vec<f64> = (0..20).map(f64::from).collect();
        let down: Vec<f64> = up.iter().rev().copied().collect();
        let series = [
            Series::new("triangles", "", up.clone()),
            Series::new("draw calls", "", down),
            Series::new("frame time", "ms", up),
        ];
        let (rgba, w, h) = plot_panels(&series, "frame", 800, 160);
        // Scale 2: footer of 14 + 16.
        assert_eq!((w, h), (800, 3 * 160 + 14 + 16));
        for (i, colour) in PALETTE.iter().take(3).enumerate() {
            let rows = i as u32 * 160..(i as u32 + 1) * 160;
            let mine = pixels_of(&rgba, w, rows.clone(), *colour);
            assert!(!mine.is_empty(), "panel {i} has no line");
            for (j, other) in PALETTE.iter().take(3).enumerate() {
                if j != i {
                    assert!(pixels_of(&rgba, w, rows.clone(), *other).is_empty());
                }
            }
        }
        // Shared x axis: every panel's line starts in the same column.
        let starts: Vec<u32> = (0..3)
            .map(|i| {
                let rows = i * 160..(i + 1) * 160;
                columns(&pixels_of(&rgba, w, rows, PALETTE[i as usize]))[0].0
            })
            .collect();
        assert!(starts.windows(2).all(|p| p[0] == p[1]), "{starts:?}");
    }

    #[test]
    fn non_finite_values_are_gaps_and_do_not_panic() {
        let values = vec![
            1.0,
            f64::NAN,
            f64::INFINITY,
            2.0,
            f64::NEG_INFINITY,
            3.0,
            f64::NAN,
        ];
        assert_eq!(y_range(&values), Some((1.0, 3.0)));
        let (rgba, w, _) = plot_panels(&[Series::new("t", "", values)], "frame", 300, 150);
        assert!(!pixels_of(&rgba, w, 0..150, PALETTE[0]).is_empty());
        // Two finite points separated by a NaN are not joined.
        let gappy = vec![0.0, f64::NAN, 1.0];
        let (rgba, w, _) = plot_panels(&[Series::new("t", "", gappy)], "", 300, 150);
        let cols = columns(&pixels_of(&rgba, w, 0..150, PALETTE[0]));
        assert!(
            cols.len() <= 2 * LINE as usize,
            "joined across the gap: {cols:?}"
        );
        for values in [
            vec![f64::NAN; 10],
            vec![f64::INFINITY, f64::NEG_INFINITY],
            vec![f64::MAX, -f64::MAX, 0.0],
            vec![f64::MIN_POSITIVE, 5e-324],
            Vec::new(),
        ] {
            let (rgba, w, h) = plot_panels(&[Series::new("x", "u", values)], "f", 200, 100);
            assert_eq!(rgba.len(), (w * h * 4) as usize);
        }
    }

    #[test]
    fn constant_series_is_a_level_line_mid_panel() {
        let (rgba, w, _) = plot_panels(
            &[Series::new("draw calls", "", vec![7.0; 30])],
            "frame",
            300,
            200,
        );
        let line = pixels_of(&rgba, w, 0..200, PALETTE[0]);
        let top = line.iter().map(|p| p.1).min().unwrap_or(0);
        let bottom = line.iter().map(|p| p.1).max().unwrap_or(0);
        assert!(bottom - top < LINE as u32, "rows {top}..={bottom}");
        assert!((80..120).contains(&top), "row {top}");
        assert_eq!(y_range(&[0.0, 0.0]), Some((-1.0, 1.0)));
    }

    #[test]
    fn single_value_draws_a_dot() {
        let (rgba, w, _) = plot_panels(&[Series::new("one", "", vec![5.0])], "", 200, 100);
        assert_eq!(
            pixels_of(&rgba, w, 0..100, PALETTE[0]).len(),
            (LINE * LINE) as usize
        );
    }

    #[test]
    fn degenerate_sizes_do_not_panic() {
        let s = [Series::new("triangles", "k", vec![1.0, 2.0, 3.0])];
        for (w, ph) in [
            (0, 0),
            (0, 100),
            (100, 0),
            (1, 1),
            (5, 5),
            (30, 20),
            (2000, 10),
        ] {
            let (rgba, width, height) = plot_panels(&s, "frame", w, ph);
            assert_eq!(rgba.len(), (width * height * 4) as usize);
            assert_eq!(width, w);
        }
        let (rgba, w, h) = plot_panels(&[], "frame", 200, 100);
        assert_eq!((w, h), (200, 100 + 7 + 8));
        assert!(
            rgba.chunks_exact(4).any(|p| p == TEXT),
            "no 'no series' text"
        );
    }

    #[test]
    fn plot_is_mostly_white_with_light_grid() {
        let values: Vec<f64> = (0..500).map(|i| (f64::from(i) / 30.0).sin()).collect();
        let (rgba, w, h) = plot_panels(&[Series::new("wave", "", values)], "frame", 600, 200);
        let total = (w * h) as usize;
        let white = rgba.chunks_exact(4).filter(|p| *p == BACKGROUND).count();
        let grid = rgba.chunks_exact(4).filter(|p| *p == GRID).count();
        assert!(white * 10 > total * 7, "{white} of {total} white");
        assert!(grid > 500, "only {grid} grid pixels");
    }

    #[test]
    fn numbers_format_compactly() {
        let cases = [
            (0.0, "0"),
            (-0.0, "0"),
            (0.25, "0.25"),
            (0.125, "0.125"),
            (0.001, "0.001"),
            (1.0, "1"),
            (12.0, "12"),
            (12.34, "12.3"),
            (999.0, "999"),
            (999.6, "1k"),
            (1200.0, "1.2k"),
            (1234.0, "1.23k"),
            (12_345.0, "12.3k"),
            (123_456.0, "123k"),
            (999_999.0, "1M"),
            (3.4e6, "3.4M"),
            (-1500.0, "-1.5k"),
            (5e9, "5G"),
            (2.5e13, "25T"),
            (1e-5, "1e-5"),
            (1.234e-7, "1.23e-7"),
            (1.2e15, "1.2e15"),
            (f64::NAN, "nan"),
            (f64::INFINITY, "inf"),
            (f64::NEG_INFINITY, "-inf"),
        ];
        for (v, want) in cases {
            assert_eq!(format_compact(v), want, "{v}");
        }
        for k in -300..300 {
            let v = 10f64.powi(k);
            assert!(!format_compact(v).is_empty());
            assert!(!format_compact(v * 0.9999).is_empty());
        }
    }

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
