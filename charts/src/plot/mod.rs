//! Line plots of per-frame statistics: one panel per series, stacked vertically,
//! sharing an x axis of frame numbers.
//!
//! This module lays the panels out ([`plot_panels`]) and holds the colours;
//! `panel` draws one panel (its grid, ticks, frame and polyline) and `format`
//! writes the numbers on the axes ([`format_compact`]).

mod format;
mod panel;

pub use format::format_compact;

use crate::canvas::Canvas;
use crate::font::{GLYPH_HEIGHT, text_width};
use panel::{Area, draw_panel, summary, y_range};

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
}
