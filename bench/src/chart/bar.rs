//! [`BarChart`]: grouped bars with an optional logarithmic y axis, values above
//! the bars, and labelled dashed reference lines.

use super::axis::{Area, Axis, label_width, linear_range, log_range, y_axis};
use super::canvas::{Canvas, text_box};
use super::frame::{header, no_data};
use super::{Image, PAD, REFERENCE, SCALE, SMALL, plain};
use tessera_charts::format_compact;
use tessera_charts::plot::{PALETTE, TEXT};
use tessera_charts::stats::min_max;

/// A horizontal line across the plot at `value`, labelled at its right end.
#[derive(Clone, Debug)]
pub struct Reference {
    pub value: f64,
    pub label: String,
}

/// One series of bars: `values[i]` belongs to category `i`; `None` draws nothing.
#[derive(Clone, Debug)]
pub struct BarSeries {
    pub name: String,
    pub values: Vec<Option<f64>>,
}

#[derive(Clone, Debug, Default)]
pub struct BarChart {
    pub title: String,
    /// The unit of the values, written above the y axis.
    pub y_label: String,
    pub categories: Vec<String>,
    pub series: Vec<BarSeries>,
    pub references: Vec<Reference>,
    /// Logarithmic y axis (bars start at the lowest decade); values ≤ 0 are left out.
    pub log_y: bool,
}

/// A rectangle (x, y, w, h) that labels must not cover.
type Rect = (i64, i64, i64, i64);

fn overlaps(a: Rect, b: Rect) -> bool {
    a.0 < b.0 + b.2 && b.0 < a.0 + a.2 && a.1 < b.1 + b.3 && b.1 < a.1 + a.3
}

/// A dashed horizontal reference line across the plot area at row `y`.
fn reference_line(canvas: &mut Canvas, area: Area, y: i64) {
    let mut x = area.left + 1;
    while x < area.right {
        canvas.fill(x, y - 1, 8.min(area.right - x), 2, REFERENCE);
        x += 13;
    }
}

/// Places the label of the reference line at row `y` just above or below it,
/// sliding from its right end to its left, wherever it covers nothing in `taken`
/// (bars, value labels, other labels), and adds its box to `taken`. Returns false,
/// drawing nothing, where there is no such place.
fn reference_label(
    canvas: &mut Canvas,
    area: Area,
    y: i64,
    label: &str,
    taken: &mut Vec<Rect>,
) -> bool {
    let label = plain(label);
    if label.is_empty() {
        return true;
    }
    let (w, h) = text_box(&label, SCALE);
    let boxed = |(x, ly): (i64, i64)| (x - 2, ly - 2, w + 4, h + 4);
    let inside =
        |(x, ly): (i64, i64)| ly - 2 >= area.top && ly + h + 2 <= area.bottom && x > area.left;
    let mut candidates = Vec::new();
    let mut x = area.right - w - PAD;
    while x > area.left {
        candidates.extend([(x, y - h - 5), (x, y + 6)]);
        x -= 2 * PAD;
    }
    let Some(at) = candidates
        .into_iter()
        .find(|&c| inside(c) && !taken.iter().any(|&r| overlaps(r, boxed(c))))
    else {
        return false;
    };
    canvas.label(at.0, at.1, &label, REFERENCE, SCALE);
    taken.push(boxed(at));
    true
}

/// A legend key for a reference line: a short dashed line.
fn dashed_swatch(canvas: &mut Canvas, x: i64, y: i64) {
    let (_, ch) = text_box("X", SCALE);
    canvas.fill(x, y + ch / 2 - 1, 5, 2, REFERENCE);
    canvas.fill(x + 9, y + ch / 2 - 1, 5, 2, REFERENCE);
}

/// `label` laid out in at most `width` pixels: one line at the normal scale, two
/// lines split at a space, or the small scale (one line, then two). The scale and
/// the lines.
fn fit(label: &str, width: i64) -> (u32, Vec<String>) {
    let fits = |t: &str, scale| text_box(t, scale).0 <= width;
    let halves = || {
        label
            .match_indices(' ')
            .map(|(i, _)| (label[..i].to_string(), label[i + 1..].to_string()))
            .min_by_key(|(a, b)| a.len().max(b.len()))
    };
    for scale in [SCALE, SMALL] {
        if fits(label, scale) {
            return (scale, vec![label.to_string()]);
        }
        if let Some((a, b)) = halves().filter(|(a, b)| fits(a, scale) && fits(b, scale)) {
            return (scale, vec![a, b]);
        }
    }
    (SMALL, vec![label.to_string()])
}

impl BarChart {
    /// Draws the chart into a `width`×`height` image.
    ///
    /// Reference lines are labelled beside the line where the label covers no bar
    /// or value; those that find no such place are labelled in the legend instead
    /// (a second layout, since the legend's height moves everything).
    pub fn draw(&self, width: u32, height: u32) -> Image {
        let (image, unplaced) = self.layout(width, height, &[]);
        if unplaced.is_empty() {
            image
        } else {
            self.layout(width, height, &unplaced).0
        }
    }

    /// One layout, with the labels of `in_legend` (indices into `references`) in
    /// the legend; also returns the references whose labels found no place.
    fn layout(&self, width: u32, height: u32, in_legend: &[usize]) -> (Image, Vec<usize>) {
        let mut canvas = Canvas::new(width, height);
        let mut names: Vec<String> = self.series.iter().map(|s| s.name.clone()).collect();
        names.extend(in_legend.iter().map(|&i| self.references[i].label.clone()));
        let n_series = self.series.len();
        let swatch = |c: &mut Canvas, x: i64, y: i64, i: usize| {
            let (_, ch) = text_box("X", SCALE);
            if i < n_series {
                c.fill(x, y, ch, ch, PALETTE[i % PALETTE.len()]);
            } else {
                dashed_swatch(c, x, y);
            }
        };
        let top = header(&mut canvas, &self.title, &self.y_label, &names, &swatch);
        let usable = |v: f64| v.is_finite() && (!self.log_y || v > 0.0);
        let values = self
            .series
            .iter()
            .flat_map(|s| s.values.iter().flatten().copied())
            .chain(self.references.iter().map(|r| r.value))
            .filter(|&v| usable(v));
        let Some((lo, hi)) = min_max(values).filter(|_| !self.categories.is_empty()) else {
            no_data(&mut canvas, top);
            return (canvas.into_image(), Vec::new());
        };
        let (lo, hi, ticks) = if self.log_y {
            log_range(lo, hi)
        } else {
            // From zero, with room above the tallest bar for its value label.
            linear_range(lo.min(0.0), hi.max(0.0) * 1.08)
        };
        let left = 2 * PAD + label_width(&ticks) + PAD;
        let right = canvas.width - 3 * PAD;
        let n_cat = self.categories.len() as i64;
        let group = (right - left) / n_cat;
        let labels: Vec<(u32, Vec<String>)> = self
            .categories
            .iter()
            .map(|c| fit(&plain(c), group - PAD))
            .collect();
        let line_h = |scale: u32| text_box("X", scale).1 + 4;
        let label_h = labels
            .iter()
            .map(|(scale, lines)| line_h(*scale) * lines.len() as i64)
            .max()
            .unwrap_or(0);
        let area = Area {
            left,
            right,
            top,
            bottom: canvas.height - label_h - 2 * PAD,
        };
        if area.right - area.left < 20 || area.bottom - area.top < 20 || group < 1 {
            return (canvas.into_image(), Vec::new());
        }
        let axis = Axis {
            lo,
            hi,
            log: self.log_y,
            near: area.bottom,
            far: area.top,
        };
        y_axis(&mut canvas, area, axis, &ticks);

        let n_ser = self.series.len().max(1) as i64;
        let bar = ((group * 4 / 5) / n_ser).max(1);
        let zero = axis.px(if self.log_y { lo } else { 0.0 });
        let mut taken: Vec<Rect> = Vec::new();
        let mut value_labels = Vec::new();
        for (c, (scale, lines)) in labels.iter().enumerate() {
            let gx = area.left + c as i64 * group + (group - bar * n_ser) / 2;
            for (s, series) in self.series.iter().enumerate() {
                let Some(v) = series
                    .values
                    .get(c)
                    .copied()
                    .flatten()
                    .filter(|&v| usable(v))
                else {
                    continue;
                };
                let x = gx + s as i64 * bar;
                let y = axis.px(v);
                let gap = i64::from(bar > 4);
                let (y0, y1) = (y.min(zero), y.max(zero));
                let rect = (x + gap, y0, bar - 2 * gap, (y1 - y0).max(1));
                canvas.fill(rect.0, rect.1, rect.2, rect.3, PALETTE[s % PALETTE.len()]);
                taken.push(rect);
                let label = format_compact(v);
                let fits = |scale| text_box(&label, scale).0 + PAD <= bar;
                let scale = if fits(SCALE) {
                    Some(SCALE)
                } else if text_box(&label, SMALL).0 <= bar + 2 * PAD {
                    Some(SMALL)
                } else {
                    None
                };
                if let Some(scale) = scale {
                    let (lw, lh) = text_box(&label, scale);
                    let at = (x + (bar - lw) / 2, y0 - lh - 4);
                    taken.push((at.0 - 1, at.1 - 1, lw + 2, lh + 2));
                    value_labels.push((at, label, scale));
                }
            }
            let cx = area.left + c as i64 * group + group / 2;
            for (k, line) in lines.iter().enumerate() {
                let lw = text_box(line, *scale).0;
                let y = area.bottom + PAD + k as i64 * line_h(*scale);
                canvas.text(cx - lw / 2, y, line, TEXT, *scale);
            }
        }
        let references: Vec<(usize, i64, &str)> = self
            .references
            .iter()
            .enumerate()
            .filter(|(_, r)| usable(r.value))
            .map(|(i, r)| (i, axis.px(r.value), r.label.as_str()))
            .collect();
        for &(_, y, _) in &references {
            reference_line(&mut canvas, area, y);
        }
        for ((x, y), label, scale) in value_labels {
            canvas.label(x, y, &label, TEXT, scale);
        }
        let mut unplaced = Vec::new();
        for &(i, y, label) in references.iter().filter(|r| !in_legend.contains(&r.0)) {
            if !reference_label(&mut canvas, area, y, label, &mut taken) {
                unplaced.push(i);
            }
        }
        (canvas.into_image(), unplaced)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chart::{HEIGHT, WIDTH};

    /// The longest vertical run of `colour` in any column: a bar's height.
    fn tallest_run(img: &Image, colour: [u8; 4]) -> u32 {
        let mut best = 0;
        for x in 0..img.width {
            let mut run = 0;
            for y in 0..img.height {
                if img.pixel(x, y) == colour {
                    run += 1;
                    best = best.max(run);
                } else {
                    run = 0;
                }
            }
        }
        best
    }

    /// Rows holding at least `n` pixels of `colour`.
    fn rows_with(img: &Image, colour: [u8; 4], n: usize) -> Vec<u32> {
        (0..img.height)
            .filter(|&y| {
                (0..img.width)
                    .filter(|&x| img.pixel(x, y) == colour)
                    .count()
                    >= n
            })
            .collect()
    }

    fn bars(values: [f64; 2], log_y: bool) -> BarChart {
        BarChart {
            title: "t".into(),
            y_label: "MB/s".into(),
            categories: vec!["64 conn".into()],
            series: vec![
                BarSeries {
                    name: "a".into(),
                    values: vec![Some(values[0])],
                },
                BarSeries {
                    name: "b".into(),
                    values: vec![Some(values[1])],
                },
            ],
            references: Vec::new(),
            log_y,
        }
    }

    #[test]
    fn bar_heights_are_proportional_to_values() {
        let img = bars([1000.0, 2000.0], false).draw(WIDTH, HEIGHT);
        assert_eq!((img.width, img.height), (WIDTH, HEIGHT));
        assert_eq!(img.rgba.len(), (WIDTH * HEIGHT * 4) as usize);
        let a = tallest_run(&img, PALETTE[0]);
        let b = tallest_run(&img, PALETTE[1]);
        assert!(a > 50, "bar a is {a} px");
        let r = f64::from(b) / f64::from(a);
        assert!((r - 2.0).abs() < 0.05, "heights {a} and {b}");
    }

    #[test]
    fn log_bars_grow_with_the_logarithm() {
        // Axis 10..10000: 100 is one decade above the bottom, 10000 three.
        let img = bars([100.0, 10000.0], true).draw(WIDTH, HEIGHT);
        let a = tallest_run(&img, PALETTE[0]);
        let b = tallest_run(&img, PALETTE[1]);
        let r = f64::from(b) / f64::from(a);
        assert!((r - 3.0).abs() < 0.1, "heights {a} and {b}");
    }

    #[test]
    fn reference_lines_are_drawn_at_their_value() {
        let mut chart = bars([500.0, 500.0], false);
        let plain_img = chart.draw(WIDTH, HEIGHT);
        assert!(rows_with(&plain_img, REFERENCE, 200).is_empty());
        chart.references.push(Reference {
            value: 250.0,
            label: "aim 250".into(),
        });
        let img = chart.draw(WIDTH, HEIGHT);
        let rows = rows_with(&img, REFERENCE, 200);
        assert_eq!(rows.len(), 2, "a 2-pixel dashed line: {rows:?}");
        // Half-way up the 500-high bars: the bars' tops and bottoms bracket it.
        let (top, bottom) = column_extent(&plain_img, PALETTE[0]);
        let mid = u32::midpoint(top, bottom);
        assert!(
            rows[0].abs_diff(mid) <= 2,
            "line at {rows:?}, bar {top}..{bottom}"
        );
    }

    /// The first and last row holding `colour` in the column of the tallest run.
    fn column_extent(img: &Image, colour: [u8; 4]) -> (u32, u32) {
        let h = tallest_run(img, colour);
        for x in 0..img.width {
            let ys: Vec<u32> = (0..img.height)
                .filter(|&y| img.pixel(x, y) == colour)
                .collect();
            if ys.len() as u32 == h {
                return (ys[0], ys[ys.len() - 1]);
            }
        }
        panic!("no column of height {h}");
    }

    #[test]
    fn missing_values_draw_no_bar_and_empty_charts_say_no_data() {
        let mut chart = bars([1.0, 2.0], false);
        chart.series[1].values = vec![None];
        let img = chart.draw(WIDTH, HEIGHT);
        // Only the legend swatch (14 px) is left in the second colour.
        assert!(tallest_run(&img, PALETTE[1]) < 20);
        let empty = BarChart::default().draw(WIDTH, HEIGHT);
        assert_eq!(tallest_run(&empty, PALETTE[0]), 0);
        assert!(empty.rgba.chunks_exact(4).any(|p| p == TEXT), "no text");
    }

    #[test]
    fn long_labels_wrap_or_shrink() {
        assert_eq!(fit("64 conn", 200), (SCALE, vec!["64 conn".to_string()]));
        // 22 characters are 262 pixels at scale 2: two lines of 10 and 11.
        let (scale, lines) = fit("synthetic 65537 canyon", 200);
        assert_eq!((scale, lines.len()), (SCALE, 2));
        assert!(
            lines.iter().all(|l| text_box(l, SCALE).0 <= 200),
            "{lines:?}"
        );
        assert_eq!(fit("synthetic:65537", 100).0, SMALL);
    }
}
