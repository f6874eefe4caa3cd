//! What both kinds of chart draw around the plot: the title, the legend and the
//! y-axis unit above it, or "no data" in its place.

use super::canvas::{Canvas, text_box};
use super::{PAD, SCALE, plain};
use tessera_charts::plot::TEXT;

/// Title, legend (flowing in rows under the title) and y-axis unit; returns the
/// y where the plot area may start. `swatch` draws one legend key.
pub(super) fn header(
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

/// "No data" in the middle of an empty chart.
pub(super) fn no_data(canvas: &mut Canvas, top: i64) {
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
