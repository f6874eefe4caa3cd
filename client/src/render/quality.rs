//! Image quality against a reference render: MSE, PSNR, and crack pixels.
//!
//! The sky is cleared to a colour the terrain shader never produces (it clamps its
//! output to `[0.02, 0.98]`), so a sky pixel is unambiguous.

/// The sky colour, RGBA8.
pub const SKY: [u8; 4] = [255, 0, 255, 255];

pub fn is_sky(px: &[u8]) -> bool {
    px[..3] == SKY[..3]
}

/// Sky pixels in an RGBA8 image.
pub fn sky_pixels(rgba: &[u8]) -> usize {
    rgba.chunks_exact(4).filter(|p| is_sky(p)).count()
}

/// Replaces the sky colour with a sky gradient for pictures people look at (the
/// raw frames keep the sky colour for crack detection).
pub fn paint_sky(rgba: &mut [u8], width: u32, height: u32) {
    let w = width as usize;
    for (i, px) in rgba.chunks_exact_mut(4).enumerate() {
        if is_sky(px) {
            px.copy_from_slice(&painted_sky((i / w.max(1)) as u32, height));
        }
    }
}

/// The colour [`paint_sky`] gives sky pixels of row `row` of an image `height`
/// rows high (so that written frames can still be told apart from the terrain).
pub fn painted_sky(row: u32, height: u32) -> [u8; 4] {
    let t = f64::from(row) / f64::from(height.max(1));
    let mix = |a: f64, b: f64| (a + (b - a) * t).round() as u8;
    [mix(70.0, 190.0), mix(120.0, 205.0), mix(190.0, 225.0), 255]
}

/// Mean squared error over the RGB channels (0–255 scale).
pub fn mse(a: &[u8], b: &[u8]) -> f64 {
    assert_eq!(a.len(), b.len(), "images differ in size");
    let (mut sum, mut n) = (0f64, 0u64);
    for (p, q) in a.chunks_exact(4).zip(b.chunks_exact(4)) {
        for c in 0..3 {
            let d = f64::from(p[c]) - f64::from(q[c]);
            sum += d * d;
        }
        n += 3;
    }
    sum / n.max(1) as f64
}

/// Peak signal-to-noise ratio in dB (infinite for identical images).
pub fn psnr(mse: f64) -> f64 {
    10.0 * (255.0 * 255.0 / mse).log10()
}

/// Mean absolute difference over RGB (0–255 scale).
pub fn mean_abs_diff(a: &[u8], b: &[u8]) -> f64 {
    assert_eq!(a.len(), b.len(), "images differ in size");
    let sum: u64 = a
        .chunks_exact(4)
        .zip(b.chunks_exact(4))
        .map(|(p, q)| (0..3).map(|c| u64::from(p[c].abs_diff(q[c]))).sum::<u64>())
        .sum();
    sum as f64 / (a.len() / 4 * 3).max(1) as f64
}

/// Crack pixels: sky in `image` where the reference shows terrain and so do all
/// eight of the reference's neighbouring pixels, i.e. strictly inside the
/// terrain's silhouette (a silhouette that moves by a pixel is not a crack).
pub fn crack_pixels(image: &[u8], reference: &[u8], width: u32, height: u32) -> usize {
    let (w, h) = (width as usize, height as usize);
    let terrain = |x: usize, y: usize| !is_sky(&reference[(y * w + x) * 4..]);
    let mut n = 0;
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            if is_sky(&image[(y * w + x) * 4..])
                && (y - 1..=y + 1).all(|yy| (x - 1..=x + 1).all(|xx| terrain(xx, yy)))
            {
                n += 1;
            }
        }
    }
    n
}

/// A difference image for a failed comparison: grey where equal, red where not,
/// brighter for larger differences.
pub fn difference_image(a: &[u8], b: &[u8]) -> Vec<u8> {
    a.chunks_exact(4)
        .zip(b.chunks_exact(4))
        .flat_map(|(p, q)| {
            let d = (0..3).map(|c| p[c].abs_diff(q[c])).max().unwrap_or(0);
            if d == 0 {
                [p[0] / 4 + 48, p[1] / 4 + 48, p[2] / 4 + 48, 255]
            } else {
                [128u8.saturating_add(d), 0, 0, 255]
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(w: usize, h: usize, f: impl Fn(usize, usize) -> [u8; 4]) -> Vec<u8> {
        let f = &f;
        (0..h)
            .flat_map(|y| (0..w).flat_map(move |x| f(x, y)))
            .collect()
    }

    #[test]
    fn cracks_are_sky_inside_the_reference_silhouette_only() {
        let grey = [90, 90, 90, 255];
        // Reference: sky above row 3, terrain below.
        let reference = image(8, 8, |_, y| if y < 3 { SKY } else { grey });
        // Ours: the silhouette one row lower (not a crack), and a hole at (4, 6).
        let ours = image(
            8,
            8,
            |x, y| if y < 4 || (x, y) == (4, 6) { SKY } else { grey },
        );
        assert_eq!(crack_pixels(&ours, &reference, 8, 8), 1);
        assert_eq!(sky_pixels(&ours), 33);
        assert_eq!(crack_pixels(&reference, &reference, 8, 8), 0);
    }

    #[test]
    fn mse_and_psnr() {
        let a = image(2, 1, |_, _| [10, 20, 30, 255]);
        let b = image(2, 1, |x, _| {
            if x == 0 {
                [10, 20, 30, 255]
            } else {
                [13, 20, 30, 255]
            }
        });
        assert_eq!(mse(&a, &a), 0.0);
        assert!(psnr(mse(&a, &a)).is_infinite());
        // One channel of six differs by 3: MSE 9/6.
        assert!((mse(&a, &b) - 1.5).abs() < 1e-12);
        assert!((mean_abs_diff(&a, &b) - 0.5).abs() < 1e-12);
        assert!((psnr(1.5) - 46.37).abs() < 0.01);
    }
}
