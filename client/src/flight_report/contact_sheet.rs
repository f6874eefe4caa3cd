//! Contact sheets: many frames of a fly-through as labelled thumbnails on one image.
//!
//! Thumbnails are area averages (a box filter with fractional edge weights, in
//! exact integer arithmetic), so a thumbnail pixel is the rounded mean of the
//! source pixels it covers — no aliasing shimmer on distant terrain, and an
//! integer reduction gives exactly the block means.

use tessera_charts::canvas::Canvas;
use tessera_charts::font::{ADVANCE, GLYPH_HEIGHT};

/// Space between thumbnails and around the sheet, in pixels.
pub const GAP: u32 = 6;
/// The sheet's background.
pub const BACKGROUND: [u8; 4] = [24, 24, 28, 255];
/// Frame numbers under the thumbnails.
pub const LABEL_COLOUR: [u8; 4] = [210, 210, 210, 255];
/// What a frame that is not a `width`×`height` RGBA8 image shows as.
const PLACEHOLDER: [u8; 4] = [56, 56, 62, 255];
/// Space above and below a label, in pixels.
const LABEL_PAD: u32 = 3;

/// Tiles `frames` (RGBA8, each `(pixels, width, height)`, normally all the same
/// size) into a grid of `columns` thumbnails `thumb_width` pixels wide, each with
/// its index in `frames` printed below it. Returns `(rgba, width, height)`.
///
/// See [`contact_sheet_labelled`] for the layout and for other labels (the
/// frame numbers of frames chosen with [`pick_evenly`], say).
pub fn contact_sheet(
    frames: &[(Vec<u8>, u32, u32)],
    columns: u32,
    thumb_width: u32,
) -> (Vec<u8>, u32, u32) {
    let labels: Vec<String> = (0..frames.len()).map(|i| i.to_string()).collect();
    contact_sheet_labelled(frames, &labels, columns, thumb_width)
}

/// [`contact_sheet`] with the text under each thumbnail given: `labels[i]` goes
/// under `frames[i]` (missing labels leave the space empty; a label wider than
/// its thumbnail is cut short).
///
/// Layout: thumbnails are `thumb_width` (at least 1) pixels wide and as tall as
/// the first frame's aspect ratio makes them; every frame is scaled to that size.
/// A row holds `columns` thumbnails (at least 1, at most `frames.len()`), in
/// order, left to right, then top to bottom. [`GAP`] pixels of [`BACKGROUND`]
/// separate thumbnails and surround the grid, and under each thumbnail is a
/// label strip of 7 font pixels plus 3 pixels above and below, at a font scale
/// of `thumb_width / 160` clamped to 1..=3. Frames that are not valid RGBA8
/// images show as a grey placeholder. With no frames the sheet is a [`GAP`]×[`GAP`]
/// square of background.
pub fn contact_sheet_labelled<S: AsRef<str>>(
    frames: &[(Vec<u8>, u32, u32)],
    labels: &[S],
    columns: u32,
    thumb_width: u32,
) -> (Vec<u8>, u32, u32) {
    let n = frames.len() as u32;
    if n == 0 {
        return Canvas::new(GAP, GAP, BACKGROUND).into_parts();
    }
    let cols = columns.clamp(1, n);
    let rows = n.div_ceil(cols);
    let tw = thumb_width.max(1);
    let th = frames
        .iter()
        .find(|f| f.1 > 0 && f.2 > 0)
        .map_or(tw, |&(_, w, h)| {
            ((u64::from(tw) * u64::from(h) + u64::from(w) / 2) / u64::from(w)).max(1) as u32
        });
    let scale = (tw / 160).clamp(1, 3);
    let label_h = GLYPH_HEIGHT * scale + 2 * LABEL_PAD;
    let cell_h = th + label_h;
    let mut sheet = Canvas::new(
        cols * tw + (cols + 1) * GAP,
        rows * cell_h + (rows + 1) * GAP,
        BACKGROUND,
    );
    let max_chars = ((tw + 1) / (ADVANCE * scale)) as usize;
    for (i, (rgba, w, h)) in frames.iter().enumerate() {
        let (col, row) = (i as u32 % cols, i as u32 / cols);
        let x = i64::from(GAP + col * (tw + GAP));
        let y = i64::from(GAP + row * (cell_h + GAP));
        if *w > 0 && *h > 0 && rgba.len() == *w as usize * *h as usize * 4 {
            let thumb = area_resample(rgba, *w, *h, tw, th);
            for (k, px) in thumb.chunks_exact(4).enumerate() {
                let (tx, ty) = (k as u32 % tw, k as u32 / tw);
                sheet.put(
                    x + i64::from(tx),
                    y + i64::from(ty),
                    [px[0], px[1], px[2], px[3]],
                );
            }
        } else {
            sheet.fill_rect(x, y, i64::from(tw), i64::from(th), PLACEHOLDER);
        }
        if let Some(label) = labels.get(i) {
            let label: String = label.as_ref().chars().take(max_chars).collect();
            sheet.text(
                x,
                y + i64::from(th + LABEL_PAD),
                &label,
                LABEL_COLOUR,
                scale,
            );
        }
    }
    sheet.into_parts()
}

/// `count` items spread evenly over `items`, in order, always including the first
/// and the last (for `count` ≥ 2). All items if `count` ≥ `items.len()`; the
/// first alone if `count` is 1; none if `count` is 0.
pub fn pick_evenly<T: Clone>(items: &[T], count: usize) -> Vec<T> {
    pick_evenly_indices(items.len(), count)
        .into_iter()
        .map(|i| items[i].clone())
        .collect()
}

/// The indices [`pick_evenly`] picks from `len` items: strictly increasing,
/// `min(count, len)` of them, index `k` being `k·(len−1)/(count−1)` rounded.
pub fn pick_evenly_indices(len: usize, count: usize) -> Vec<usize> {
    match count.min(len) {
        0 => Vec::new(),
        1 => vec![0],
        c if c == len => (0..len).collect(),
        c => {
            let (span, steps) = (len - 1, c - 1);
            (0..c).map(|k| (k * span + steps / 2) / steps).collect()
        }
    }
}

/// For each destination pixel along an axis of `src` pixels scaled to `dst`: the
/// first source pixel it covers and the overlaps with the source pixels from there
/// on, in units where a source pixel is `dst` long and a destination pixel `src`
/// long (so the overlaps of each destination pixel add up to `src`).
fn axis_weights(src: u32, dst: u32) -> Vec<(usize, Vec<u64>)> {
    let (s, d) = (u64::from(src), u64::from(dst));
    (0..d)
        .map(|i| {
            let (start, end) = (i * s, (i + 1) * s);
            let (first, last) = (start / d, (end - 1) / d);
            let weights = (first..=last)
                .map(|j| end.min((j + 1) * d) - start.max(j * d))
                .collect();
            (first as usize, weights)
        })
        .collect()
}

/// Resamples an RGBA8 image to `dw`×`dh` by area averaging, rounding to nearest.
pub(super) fn area_resample(src: &[u8], sw: u32, sh: u32, dw: u32, dh: u32) -> Vec<u8> {
    let (xw, yw) = (axis_weights(sw, dw), axis_weights(sh, dh));
    let (sw, dw) = (sw as usize, dw as usize);
    // Horizontal pass: each value is a sum of weights × bytes, weights adding up to `sw`.
    let mut rows = vec![0u64; dw * sh as usize * 4];
    for y in 0..sh as usize {
        let src_row = &src[y * sw * 4..(y + 1) * sw * 4];
        for (x, (first, weights)) in xw.iter().enumerate() {
            let out = &mut rows[(y * dw + x) * 4..(y * dw + x) * 4 + 4];
            for (j, &wgt) in weights.iter().enumerate() {
                let p = &src_row[(first + j) * 4..(first + j) * 4 + 4];
                for c in 0..4 {
                    out[c] += wgt * u64::from(p[c]);
                }
            }
        }
    }
    // Vertical pass, then divide by the total weight `sw`·`sh`.
    let total = sw as u64 * u64::from(sh);
    let mut out = vec![0u8; dw * dh as usize * 4];
    for (y, (first, weights)) in yw.iter().enumerate() {
        for x in 0..dw {
            let mut acc = [0u64; 4];
            for (j, &wgt) in weights.iter().enumerate() {
                let at = ((first + j) * dw + x) * 4;
                for c in 0..4 {
                    acc[c] += wgt * rows[at + c];
                }
            }
            for c in 0..4 {
                out[(y * dw + x) * 4 + c] = ((acc[c] + total / 2) / total) as u8;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_charts::font;

    /// A `w`×`h` opaque frame whose pixel (x, y) is `f(x, y)` (RGB).
    fn frame(w: u32, h: u32, f: impl Fn(u32, u32) -> [u8; 3]) -> (Vec<u8>, u32, u32) {
        let mut rgba = Vec::with_capacity((w * h * 4) as usize);
        for y in 0..h {
            for x in 0..w {
                let [r, g, b] = f(x, y);
                rgba.extend_from_slice(&[r, g, b, 255]);
            }
        }
        (rgba, w, h)
    }

    fn pixel(rgba: &[u8], width: u32, x: u32, y: u32) -> [u8; 4] {
        let at = ((y * width + x) * 4) as usize;
        [rgba[at], rgba[at + 1], rgba[at + 2], rgba[at + 3]]
    }

    fn pattern(seed: u32) -> impl Fn(u32, u32) -> [u8; 3] {
        move |x, y| {
            let v = (x * 37 + y * 101 + seed * 53) ^ (x * y + seed);
            [(v % 251) as u8, (v / 7 % 256) as u8, (x * 8 + y) as u8]
        }
    }

    #[test]
    fn sheet_dimensions_follow_the_grid() {
        let frames: Vec<_> = (0..5).map(|s| frame(64, 32, pattern(s))).collect();
        let (rgba, w, h) = contact_sheet(&frames, 3, 16);
        let label_h = GLYPH_HEIGHT + 2 * LABEL_PAD;
        assert_eq!(w, 3 * 16 + 4 * GAP);
        assert_eq!(h, 2 * (8 + label_h) + 3 * GAP);
        assert_eq!(rgba.len(), (w * h * 4) as usize);
        // Fewer frames than columns: the grid narrows to the frames.
        let (_, w, h) = contact_sheet(&frames[..2], 10, 16);
        assert_eq!((w, h), (2 * 16 + 3 * GAP, 8 + label_h + 2 * GAP));
        // Aspect ratio is kept and rounded: 64×48 at 10 wide is 7.5 → 8 tall.
        let (_, _, h) = contact_sheet(&[frame(64, 48, pattern(0))], 1, 10);
        assert_eq!(h, 8 + label_h + 2 * GAP);
    }

    #[test]
    fn thumbnail_pixel_is_the_mean_of_its_source_block() {
        let frames: Vec<_> = (0..4).map(|s| frame(64, 32, pattern(s))).collect();
        let (rgba, w, _) = contact_sheet(&frames, 2, 16);
        let label_h = GLYPH_HEIGHT + 2 * LABEL_PAD;
        for (i, (src, sw, _)) in frames.iter().enumerate() {
            let (ox, oy) = (
                GAP + (i as u32 % 2) * (16 + GAP),
                GAP + (i as u32 / 2) * (8 + label_h + GAP),
            );
            for ty in 0..8 {
                for tx in 0..16 {
                    let mut sum = [0u32; 3];
                    for y in ty * 4..ty * 4 + 4 {
                        for x in tx * 4..tx * 4 + 4 {
                            let p = pixel(src, *sw, x, y);
                            for c in 0..3 {
                                sum[c] += u32::from(p[c]);
                            }
                        }
                    }
                    let mean = sum.map(|s| ((s + 8) / 16) as u8);
                    assert_eq!(
                        pixel(&rgba, w, ox + tx, oy + ty),
                        [mean[0], mean[1], mean[2], 255],
                        "frame {i}, thumbnail pixel ({tx}, {ty})"
                    );
                }
            }
        }
    }

    #[test]
    fn fractional_reduction_weights_partial_pixels() {
        // 3 source pixels into 2: the middle one is split between both halves.
        let src = frame(3, 1, |x, _| {
            [[0, 0, 0], [90, 90, 90], [180, 180, 180]][x as usize]
        });
        let out = area_resample(&src.0, 3, 1, 2, 1);
        // (0·1 + 90·0.5) / 1.5 = 30; (90·0.5 + 180·1) / 1.5 = 150.
        assert_eq!(&out[..3], &[30, 30, 30]);
        assert_eq!(&out[4..7], &[150, 150, 150]);
        for (s, d) in [(7, 3), (3, 7), (1920, 160), (5, 5), (1, 4)] {
            for (_, w) in axis_weights(s, d) {
                assert_eq!(w.iter().sum::<u64>(), u64::from(s), "{s} → {d}");
            }
        }
    }

    #[test]
    fn upscaling_a_flat_frame_stays_flat() {
        let f = frame(3, 2, |_, _| [40, 80, 120]);
        let (rgba, w, _) = contact_sheet(&[f], 1, 30);
        for y in 0..20 {
            for x in 0..30 {
                assert_eq!(pixel(&rgba, w, GAP + x, GAP + y), [40, 80, 120, 255]);
            }
        }
    }

    #[test]
    fn frame_numbers_are_printed_below_thumbnails() {
        let frames: Vec<_> = (0..12).map(|_| frame(40, 20, |_, _| [0, 0, 0])).collect();
        let (rgba, w, h) = contact_sheet(&frames, 4, 40);
        let label_h = GLYPH_HEIGHT + 2 * LABEL_PAD;
        let is_label = |p: [u8; 4]| p == LABEL_COLOUR;
        for i in 0..12u32 {
            let (x0, y0) = (
                GAP + (i % 4) * (40 + GAP),
                GAP + (i / 4) * (20 + label_h + GAP),
            );
            let label_box = (
                x0..x0 + font::text_width(&i.to_string(), 1),
                y0 + 20 + LABEL_PAD..y0 + 20 + LABEL_PAD + GLYPH_HEIGHT,
            );
            let inked = (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .filter(|&(x, y)| label_box.0.contains(&x) && label_box.1.contains(&y))
                .filter(|&(x, y)| is_label(pixel(&rgba, w, x, y)))
                .count();
            assert!(inked > 0, "no label under frame {i}");
        }
        // Label ink appears nowhere but in label strips.
        for y in 0..h {
            let in_strip = (0..3).any(|r| {
                let top = GAP + r * (20 + label_h + GAP) + 20;
                (top..top + label_h).contains(&y)
            });
            if !in_strip {
                assert!((0..w).all(|x| !is_label(pixel(&rgba, w, x, y))), "row {y}");
            }
        }
        // Two different labels draw differently.
        let strip = |i: u32| -> Vec<[u8; 4]> {
            let (x0, y0) = (GAP + (i % 4) * (40 + GAP), GAP + 20 + LABEL_PAD);
            (y0..y0 + GLYPH_HEIGHT)
                .flat_map(|y| (x0..x0 + 40).map(move |x| (x, y)))
                .map(|(x, y)| pixel(&rgba, w, x, y))
                .collect()
        };
        assert_ne!(strip(1), strip(2));
    }

    #[test]
    fn labels_are_cut_to_the_thumbnail() {
        let frames = vec![frame(20, 10, |_, _| [0, 0, 0]); 2];
        let labels = ["a very long label indeed", "x"];
        let (rgba, w, h) = contact_sheet_labelled(&frames, &labels, 2, 20);
        // Nothing of the first label spills into the gap or the second cell.
        for y in 0..h {
            for x in GAP + 20..w {
                let in_second_label = (GAP + 20 + GAP..GAP + 20 + GAP + 5).contains(&x);
                if !in_second_label {
                    assert_ne!(pixel(&rgba, w, x, y), LABEL_COLOUR, "({x}, {y})");
                }
            }
        }
    }

    #[test]
    fn odd_inputs_do_not_panic() {
        let (rgba, w, h) = contact_sheet(&[], 4, 100);
        assert_eq!((rgba.len(), w, h), ((GAP * GAP * 4) as usize, GAP, GAP));
        let good = frame(8, 8, pattern(1));
        let frames = vec![
            good.clone(),
            (vec![1, 2, 3], 8, 8),    // wrong length
            (Vec::new(), 0, 0),       // empty
            frame(5, 13, pattern(2)), // a different size
        ];
        for (cols, tw) in [(0, 0), (1, 1), (3, 7), (100, 33)] {
            let (rgba, w, h) = contact_sheet(&frames, cols, tw);
            assert_eq!(rgba.len(), (w * h * 4) as usize);
        }
        // The placeholder fills a broken frame's cell.
        let (rgba, w, _) = contact_sheet(&frames, 4, 8);
        assert_eq!(pixel(&rgba, w, GAP + 8 + GAP + 3, GAP + 3), PLACEHOLDER);
    }

    #[test]
    fn pick_evenly_includes_first_and_last() {
        let items: Vec<u32> = (100..200).collect();
        for count in 2..=100 {
            let picked = pick_evenly(&items, count);
            assert_eq!(picked.len(), count);
            assert_eq!(picked[0], 100);
            assert_eq!(*picked.last().unwrap_or(&0), 199);
            assert!(picked.windows(2).all(|p| p[0] < p[1]), "count {count}");
        }
        assert_eq!(pick_evenly(&items, 5), vec![100, 125, 150, 174, 199]);
        assert_eq!(pick_evenly(&[1, 2, 3], 10), vec![1, 2, 3]);
        assert_eq!(pick_evenly(&[1, 2, 3], 1), vec![1]);
        assert!(pick_evenly(&[1, 2, 3], 0).is_empty());
        assert!(pick_evenly::<u8>(&[], 4).is_empty());
        assert_eq!(pick_evenly_indices(11, 3), vec![0, 5, 10]);
    }

    #[test]
    fn pick_evenly_spreads_gaps_within_one() {
        for len in 2..60 {
            for count in 2..=len {
                let idx = pick_evenly_indices(len, count);
                let gaps: Vec<usize> = idx.windows(2).map(|p| p[1] - p[0]).collect();
                let (lo, hi) = (gaps.iter().min(), gaps.iter().max());
                assert!(
                    hi.zip(lo).is_some_and(|(h, l)| h - l <= 1),
                    "{len} {count}: {gaps:?}"
                );
            }
        }
    }
}
