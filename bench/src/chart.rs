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

use anyhow::Context;
use std::path::Path;
use tessera_charts::font::{GLYPH_HEIGHT, text_width};
use tessera_charts::format_compact;
use tessera_charts::plot::{AXIS, BACKGROUND, GRID, PALETTE, TEXT};
use tessera_charts::stats::nice_step;

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

/// The report raster (`tessera_charts::canvas`), with the marks
/// charts add on top: lines stamped centred on their points, labels on boxes, markers.
struct Canvas {
    raster: tessera_charts::canvas::Canvas,
    width: i64,
    height: i64,
}

impl Canvas {
    fn new(width: u32, height: u32) -> Self {
        Self {
            raster: tessera_charts::canvas::Canvas::new(width, height, BACKGROUND),
            width: i64::from(width),
            height: i64::from(height),
        }
    }

    fn fill(&mut self, x: i64, y: i64, w: i64, h: i64, colour: [u8; 4]) {
        self.raster.fill_rect(x, y, w, h, colour);
    }

    /// A `t`-pixel-thick straight line, centred on the points.
    fn line(&mut self, from: (i64, i64), to: (i64, i64), t: i64, colour: [u8; 4]) {
        let c = |(x, y): (i64, i64)| (x - t / 2, y - t / 2);
        self.raster.line(c(from), c(to), t, colour);
    }

    fn text(&mut self, x: i64, y: i64, text: &str, colour: [u8; 4], scale: u32) {
        self.raster.text(x, y, text, colour, scale);
    }

    /// Text on a background-coloured box, so it stays legible over lines.
    fn label(&mut self, x: i64, y: i64, text: &str, colour: [u8; 4], scale: u32) {
        let (w, h) = text_box(text, scale);
        self.fill(x - 2, y - 2, w + 4, h + 4, BACKGROUND);
        self.text(x, y, text, colour, scale);
    }

    /// A filled marker of `shape` (0–3: square, diamond, triangle, cross) centred
    /// on (`x`, `y`).
    fn marker(&mut self, x: i64, y: i64, shape: usize, colour: [u8; 4]) {
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

    fn into_image(self) -> Image {
        let (rgba, width, height) = self.raster.into_parts();
        Image {
            rgba,
            width,
            height,
        }
    }
}

/// Width and height in pixels of `text` at `scale`.
fn text_box(text: &str, scale: u32) -> (i64, i64) {
    (
        i64::from(text_width(text, scale)),
        i64::from(GLYPH_HEIGHT * scale),
    )
}

/// A value axis: `lo..hi` mapped onto pixels `near..far` (either direction).
#[derive(Clone, Copy, Debug)]
struct Axis {
    lo: f64,
    hi: f64,
    log: bool,
    near: i64,
    far: i64,
}

impl Axis {
    fn f(&self, v: f64) -> f64 {
        if self.log { v.log10() } else { v }
    }

    fn px(&self, v: f64) -> i64 {
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
fn linear_range(lo: f64, hi: f64) -> (f64, f64, Vec<f64>) {
    let (mut lo, mut hi) = (lo, hi);
    if hi <= lo {
        let d = if lo == 0.0 { 1.0 } else { lo.abs() * 0.1 };
        lo -= d;
        hi += d;
    }
    let step = nice_step((hi - lo) / 6.0);
    let (lo, hi) = ((lo / step).floor() * step, (hi / step).ceil() * step);
    let n = ((hi - lo) / step).round() as i64;
    let ticks = (0..=n).map(|k| lo + k as f64 * step).collect();
    (lo, hi, ticks)
}

/// Whole decades covering `lo..hi` (both > 0), starting strictly below `lo` so
/// that its bar has a height, and ticks at each decade, with 2× and 5× between
/// them when the range spans two decades or less.
fn log_range(lo: f64, hi: f64) -> (f64, f64, Vec<f64>) {
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
struct Area {
    left: i64,
    right: i64,
    top: i64,
    bottom: i64,
}

/// Title, legend (flowing in rows under the title) and y-axis unit; returns the
/// y where the plot area may start. `swatch` draws one legend key.
fn header(
    canvas: &mut Canvas,
    title: &str,
    y_label: &str,
    names: &[String],
    swatch: &dyn Fn(&mut Canvas, i64, i64, usize),
) -> i64 {
    let (_, ch) = text_box("X", SCALE);
    canvas.text(2 * PAD, 2 * PAD, &plain(title), TEXT, SCALE);
    let mut y = 2 * PAD + ch + 2 * PAD;
    let mut x = 2 * PAD;
    for (i, name) in names.iter().enumerate() {
        let name = plain(name);
        let w = ch + PAD + text_box(&name, SCALE).0;
        if x > 2 * PAD && x + w > canvas.width - 2 * PAD {
            x = 2 * PAD;
            y += ch + PAD;
        }
        swatch(canvas, x, y, i);
        canvas.text(x + ch + PAD, y, &name, TEXT, SCALE);
        x += w + 3 * PAD;
    }
    if !names.is_empty() {
        y += ch + 2 * PAD;
    }
    if !y_label.is_empty() {
        canvas.text(2 * PAD, y, &plain(y_label), TEXT, SCALE);
        y += ch + PAD;
    }
    y + PAD
}

/// Horizontal grid lines with labels left of the area, and the y axis line.
fn y_axis(canvas: &mut Canvas, area: Area, axis: Axis, ticks: &[f64]) {
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
fn label_width(ticks: &[f64]) -> i64 {
    ticks
        .iter()
        .map(|&t| text_box(&format_compact(t), SCALE).0)
        .max()
        .unwrap_or(0)
}

/// "No data" in the middle of an empty chart.
fn no_data(canvas: &mut Canvas, top: i64) {
    let msg = "no data";
    let (w, h) = text_box(msg, SCALE);
    canvas.text(
        (canvas.width - w) / 2,
        (top + canvas.height - h) / 2,
        msg,
        TEXT,
        SCALE,
    );
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
        let values: Vec<f64> = self
            .series
            .iter()
            .flat_map(|s| s.values.iter().flatten().copied())
            .chain(self.references.iter().map(|r| r.value))
            .filter(|&v| usable(v))
            .collect();
        if values.is_empty() || self.categories.is_empty() {
            no_data(&mut canvas, top);
            return (canvas.into_image(), Vec::new());
        }
        let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
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
        if points.is_empty() {
            no_data(&mut canvas, top);
            return canvas.into_image();
        }
        let fold = |f: fn(&Point) -> f64| {
            points
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                    (lo.min(f(p)), hi.max(f(p)))
                })
        };
        let (x_lo, x_hi) = fold(|p| p.x);
        let (y_lo, y_hi) = fold(|p| p.y);
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

    #[test]
    fn plain_replaces_what_the_font_lacks() {
        assert_eq!(plain("1–2 × τ ≤ 0.5 ÷ `x`"), "1-2 x τ <= 0.5 / x");
    }
}
