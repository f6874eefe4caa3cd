//! A tiny built-in 5×7 bitmap font for labels on report images.
//!
//! Each glyph is seven rows of five pixels; bit 4 of a row is its leftmost pixel.
//! The table covers the digits, `A`–`Z` (lower case draws with the upper-case
//! glyphs), space and `. , : ; - + / ( ) % _ = < > µ τ ρ #`. Anything else draws
//! as a small box, so a missing glyph is visible rather than silently dropped.
//! Text is a single line: no wrapping, no kerning, a fixed advance of
//! [`ADVANCE`] pixels (times the scale) per character.

/// Glyph width in font pixels.
pub const GLYPH_WIDTH: u32 = 5;
/// Glyph height in font pixels.
pub const GLYPH_HEIGHT: u32 = 7;
/// Horizontal distance between the left edges of neighbouring characters, in font
/// pixels (the glyph plus one column of spacing).
pub const ADVANCE: u32 = GLYPH_WIDTH + 1;

type Glyph = [u8; GLYPH_HEIGHT as usize];

/// What characters without a glyph draw as.
const BOX: Glyph = [
    0b00000, 0b11111, 0b10001, 0b10001, 0b10001, 0b11111, 0b00000,
];

/// The glyph for `c`, or `None` where the table has none.
#[rustfmt::skip]
fn glyph(c: char) -> Option<Glyph> {
    let g: Glyph = match c.to_ascii_uppercase() {
        ' ' => [0b00000, 0b00000, 0b00000, 0b00000, 0b00000, 0b00000, 0b00000],
        '0' => [0b01110, 0b10001, 0b10011, 0b10101, 0b11001, 0b10001, 0b01110],
        '1' => [0b00100, 0b01100, 0b00100, 0b00100, 0b00100, 0b00100, 0b01110],
        '2' => [0b01110, 0b10001, 0b00001, 0b00010, 0b00100, 0b01000, 0b11111],
        '3' => [0b11111, 0b00010, 0b00100, 0b00010, 0b00001, 0b10001, 0b01110],
        '4' => [0b00010, 0b00110, 0b01010, 0b10010, 0b11111, 0b00010, 0b00010],
        '5' => [0b11111, 0b10000, 0b11110, 0b00001, 0b00001, 0b10001, 0b01110],
        '6' => [0b00110, 0b01000, 0b10000, 0b11110, 0b10001, 0b10001, 0b01110],
        '7' => [0b11111, 0b00001, 0b00010, 0b00100, 0b01000, 0b01000, 0b01000],
        '8' => [0b01110, 0b10001, 0b10001, 0b01110, 0b10001, 0b10001, 0b01110],
        '9' => [0b01110, 0b10001, 0b10001, 0b01111, 0b00001, 0b00010, 0b01100],
        'A' => [0b01110, 0b10001, 0b10001, 0b11111, 0b10001, 0b10001, 0b10001],
        'B' => [0b11110, 0b10001, 0b10001, 0b11110, 0b10001, 0b10001, 0b11110],
        'C' => [0b01110, 0b10001, 0b10000, 0b10000, 0b10000, 0b10001, 0b01110],
        'D' => [0b11100, 0b10010, 0b10001, 0b10001, 0b10001, 0b10010, 0b11100],
        'E' => [0b11111, 0b10000, 0b10000, 0b11110, 0b10000, 0b10000, 0b11111],
        'F' => [0b11111, 0b10000, 0b10000, 0b11110, 0b10000, 0b10000, 0b10000],
        'G' => [0b01110, 0b10001, 0b10000, 0b10111, 0b10001, 0b10001, 0b01111],
        'H' => [0b10001, 0b10001, 0b10001, 0b11111, 0b10001, 0b10001, 0b10001],
        'I' => [0b01110, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b01110],
        'J' => [0b00111, 0b00010, 0b00010, 0b00010, 0b00010, 0b10010, 0b01100],
        'K' => [0b10001, 0b10010, 0b10100, 0b11000, 0b10100, 0b10010, 0b10001],
        'L' => [0b10000, 0b10000, 0b10000, 0b10000, 0b10000, 0b10000, 0b11111],
        'M' => [0b10001, 0b11011, 0b10101, 0b10101, 0b10001, 0b10001, 0b10001],
        'N' => [0b10001, 0b10001, 0b11001, 0b10101, 0b10011, 0b10001, 0b10001],
        'O' => [0b01110, 0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b01110],
        'P' => [0b11110, 0b10001, 0b10001, 0b11110, 0b10000, 0b10000, 0b10000],
        'Q' => [0b01110, 0b10001, 0b10001, 0b10001, 0b10101, 0b10010, 0b01101],
        'R' => [0b11110, 0b10001, 0b10001, 0b11110, 0b10100, 0b10010, 0b10001],
        'S' => [0b01111, 0b10000, 0b10000, 0b01110, 0b00001, 0b00001, 0b11110],
        'T' => [0b11111, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100],
        'U' => [0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b01110],
        'V' => [0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b01010, 0b00100],
        'W' => [0b10001, 0b10001, 0b10001, 0b10101, 0b10101, 0b10101, 0b01010],
        'X' => [0b10001, 0b10001, 0b01010, 0b00100, 0b01010, 0b10001, 0b10001],
        'Y' => [0b10001, 0b10001, 0b01010, 0b00100, 0b00100, 0b00100, 0b00100],
        'Z' => [0b11111, 0b00001, 0b00010, 0b00100, 0b01000, 0b10000, 0b11111],
        '.' => [0b00000, 0b00000, 0b00000, 0b00000, 0b00000, 0b01100, 0b01100],
        ',' => [0b00000, 0b00000, 0b00000, 0b00000, 0b01100, 0b00100, 0b01000],
        ':' => [0b00000, 0b01100, 0b01100, 0b00000, 0b01100, 0b01100, 0b00000],
        ';' => [0b00000, 0b01100, 0b01100, 0b00000, 0b01100, 0b00100, 0b01000],
        '-' => [0b00000, 0b00000, 0b00000, 0b11111, 0b00000, 0b00000, 0b00000],
        '+' => [0b00000, 0b00100, 0b00100, 0b11111, 0b00100, 0b00100, 0b00000],
        '/' => [0b00001, 0b00001, 0b00010, 0b00100, 0b01000, 0b10000, 0b10000],
        '(' => [0b00010, 0b00100, 0b01000, 0b01000, 0b01000, 0b00100, 0b00010],
        ')' => [0b01000, 0b00100, 0b00010, 0b00010, 0b00010, 0b00100, 0b01000],
        '%' => [0b11000, 0b11001, 0b00010, 0b00100, 0b01000, 0b10011, 0b00011],
        '_' => [0b00000, 0b00000, 0b00000, 0b00000, 0b00000, 0b00000, 0b11111],
        '=' => [0b00000, 0b00000, 0b11111, 0b00000, 0b11111, 0b00000, 0b00000],
        '<' => [0b00010, 0b00100, 0b01000, 0b10000, 0b01000, 0b00100, 0b00010],
        '>' => [0b01000, 0b00100, 0b00010, 0b00001, 0b00010, 0b00100, 0b01000],
        '#' => [0b01010, 0b01010, 0b11111, 0b01010, 0b11111, 0b01010, 0b01010],
        // MICRO SIGN and GREEK SMALL LETTER MU look the same.
        '\u{b5}' | '\u{3bc}' =>
               [0b00000, 0b10001, 0b10001, 0b10001, 0b10011, 0b11101, 0b10000],
        // GREEK SMALL LETTER TAU
        '\u{3c4}' =>
               [0b00000, 0b00000, 0b11111, 0b00100, 0b00100, 0b00100, 0b00011],
        // GREEK SMALL LETTER RHO
        '\u{3c1}' =>
               [0b00000, 0b00000, 0b01110, 0b10001, 0b10001, 0b11110, 0b10000],
        _ => return None,
    };
    Some(g)
}

/// The width in image pixels of `text` drawn at `scale` (no trailing spacing column);
/// its height is [`GLYPH_HEIGHT`] × `scale`. A scale of 0 counts as 1.
pub fn text_width(text: &str, scale: u32) -> u32 {
    let n = text.chars().count() as u32;
    if n == 0 {
        0
    } else {
        (n * ADVANCE - 1) * scale.max(1)
    }
}

/// Draws `text` with its top-left corner at (`x`, `y`) into a `width`×`height`
/// RGBA8 image, each font pixel a `scale`×`scale` square (a scale of 0 counts as 1).
///
/// Pixels outside the image are clipped, so text may start or run off any edge.
/// `colour` is blended over the image with its alpha ("source over", straight
/// alpha); an opaque colour simply replaces the pixels it covers. Only pixels
/// inside the text's box — [`text_width`] × [`GLYPH_HEIGHT`]·`scale` from
/// (`x`, `y`) — change. A buffer shorter than `width`×`height`×4 bytes is
/// clipped to the whole rows it holds.
#[allow(clippy::too_many_arguments)] // an image, a position, the text and its look
pub fn draw_text(
    rgba: &mut [u8],
    width: u32,
    height: u32,
    x: i32,
    y: i32,
    text: &str,
    colour: [u8; 4],
    scale: u32,
) {
    if width == 0 || colour[3] == 0 {
        return;
    }
    let rows = (rgba.len() / (width as usize * 4)).min(height as usize) as i64;
    let scale = i64::from(scale.max(1));
    let (w, x, y) = (i64::from(width), i64::from(x), i64::from(y));
    for (i, c) in text.chars().enumerate() {
        let left = x + i as i64 * i64::from(ADVANCE) * scale;
        if left >= w {
            break;
        }
        if left + i64::from(GLYPH_WIDTH) * scale <= 0 {
            continue;
        }
        let g = glyph(c).unwrap_or(BOX);
        for (gy, bits) in g.iter().enumerate() {
            for gx in 0..GLYPH_WIDTH {
                if (bits >> (GLYPH_WIDTH - 1 - gx)) & 1 == 0 {
                    continue;
                }
                let px0 = left + i64::from(gx) * scale;
                let py0 = y + gy as i64 * scale;
                for py in py0.max(0)..(py0 + scale).min(rows) {
                    for px in px0.max(0)..(px0 + scale).min(w) {
                        let at = ((py * w + px) * 4) as usize;
                        blend(&mut rgba[at..at + 4], colour);
                    }
                }
            }
        }
    }
}

/// Straight-alpha "source over" of `src` onto the pixel `dst`.
pub(super) fn blend(dst: &mut [u8], src: [u8; 4]) {
    let a = u32::from(src[3]);
    if a == 255 {
        dst.copy_from_slice(&src);
        return;
    }
    let inv = 255 - a;
    for k in 0..3 {
        dst[k] = ((u32::from(src[k]) * a + u32::from(dst[k]) * inv + 127) / 255) as u8;
    }
    dst[3] = (a + (u32::from(dst[3]) * inv + 127) / 255) as u8;
}

#[cfg(test)]
mod tests {
    use super::*;

    const BG: [u8; 4] = [10, 20, 30, 255];
    const INK: [u8; 4] = [250, 240, 230, 255];

    fn image(w: u32, h: u32) -> Vec<u8> {
        BG.repeat((w * h) as usize)
    }

    /// Pixels that differ from the background, as (x, y).
    fn changed(rgba: &[u8], w: u32) -> Vec<(i32, i32)> {
        rgba.chunks_exact(4)
            .enumerate()
            .filter(|(_, p)| *p != BG)
            .map(|(i, _)| ((i as u32 % w) as i32, (i as u32 / w) as i32))
            .collect()
    }

    #[test]
    fn text_changes_pixels_only_within_its_box() {
        let (w, h) = (120, 40);
        for scale in 1..=3 {
            let mut img = image(w, h);
            let text = "Ab9%#";
            let (x, y) = (7, 5);
            draw_text(&mut img, w, h, x, y, text, INK, scale);
            let bw = text_width(text, scale) as i32;
            let bh = (GLYPH_HEIGHT * scale) as i32;
            let px = changed(&img, w);
            assert!(!px.is_empty(), "scale {scale}: nothing drawn");
            for &(px, py) in &px {
                assert!(
                    (x..x + bw).contains(&px) && (y..y + bh).contains(&py),
                    "scale {scale}: ({px}, {py}) outside the text box"
                );
            }
            // The box is tight: ink touches its left, right, top and bottom edges.
            assert!(px.iter().any(|p| p.0 == x));
            assert!(px.iter().any(|p| p.0 == x + bw - 1));
            assert!(px.iter().any(|p| p.1 == y));
            assert!(px.iter().any(|p| p.1 == y + bh - 1));
        }
    }

    #[test]
    fn text_is_clipped_to_the_image() {
        let (w, h) = (20, 10);
        for (x, y) in [(-7, -3), (15, 6), (-100, 0), (0, 100), (i32::MIN, i32::MAX)] {
            let mut img = image(w, h);
            draw_text(&mut img, w, h, x, y, "Clipped 123", INK, 2);
            assert_eq!(img.len(), (w * h * 4) as usize);
        }
        // Partly visible text still draws its visible part.
        let mut img = image(w, h);
        draw_text(&mut img, w, h, -3, -2, "88", INK, 1);
        assert!(!changed(&img, w).is_empty());
        // A short buffer is clipped, not indexed out of bounds.
        let mut short = image(w, 3);
        draw_text(&mut short, w, h, 0, 0, "88", INK, 1);
    }

    #[test]
    fn scale_doubles_each_font_pixel() {
        let (w, h) = (40, 20);
        let mut one = image(w, h);
        let mut two = image(w, h);
        draw_text(&mut one, w, h, 0, 0, "7", INK, 1);
        draw_text(&mut two, w, h, 0, 0, "7", INK, 2);
        let one = changed(&one, w);
        let two = changed(&two, w);
        assert_eq!(two.len(), one.len() * 4);
        for (x, y) in one {
            assert!(two.contains(&(2 * x + 1, 2 * y + 1)));
        }
    }

    #[test]
    fn every_listed_character_has_its_own_glyph() {
        let listed = "0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZ.,:;-+/()%_=<>µτρ#";
        let mut seen: Vec<(char, Glyph)> = Vec::new();
        for c in listed.chars() {
            let g = glyph(c).unwrap_or_else(|| panic!("no glyph for {c:?}"));
            assert_ne!(g, BOX, "{c:?} draws as the unknown box");
            assert!(g.iter().any(|&r| r != 0), "{c:?} is blank");
            assert!(g.iter().all(|&r| r < 1 << GLYPH_WIDTH), "{c:?} too wide");
            if let Some((other, _)) = seen.iter().find(|(_, s)| *s == g) {
                panic!("{c:?} and {other:?} share a glyph");
            }
            seen.push((c, g));
        }
        assert_eq!(glyph(' '), Some([0; 7]));
        assert_eq!(glyph('\u{3bc}'), glyph('\u{b5}'));
    }

    #[test]
    fn lower_case_draws_as_upper_case() {
        for (lo, up) in ('a'..='z').zip('A'..='Z') {
            assert_eq!(glyph(lo), glyph(up));
        }
    }

    #[test]
    fn unknown_characters_draw_a_box() {
        let (w, h) = (12, 9);
        let mut unknown = image(w, h);
        let mut space = image(w, h);
        draw_text(&mut unknown, w, h, 1, 1, "\u{263a}", INK, 1);
        draw_text(&mut space, w, h, 1, 1, " ", INK, 1);
        assert!(changed(&space, w).is_empty());
        let drawn = changed(&unknown, w);
        assert_eq!(
            drawn.len(),
            BOX.iter().map(|r| r.count_ones() as usize).sum::<usize>()
        );
        assert!(drawn.contains(&(1, 2)) && drawn.contains(&(5, 6)));
    }

    #[test]
    fn translucent_ink_blends() {
        let (w, h) = (8, 8);
        let mut img = image(w, h);
        draw_text(&mut img, w, h, 0, 0, "#", [255, 255, 255, 128], 1);
        // '#' row 0 is 01010: (1, 0) is inked, (0, 0) is not.
        assert_eq!(&img[4..8], &[133, 138, 143, 255]);
        assert_eq!(&img[0..4], &BG);
    }

    #[test]
    fn width_counts_characters_not_bytes() {
        assert_eq!(text_width("", 3), 0);
        assert_eq!(text_width("τ", 1), 5);
        assert_eq!(text_width("µs", 1), 11);
        assert_eq!(text_width("ab", 0), 11);
        assert_eq!(text_width("ab", 2), 22);
    }
}
