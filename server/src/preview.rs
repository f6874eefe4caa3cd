//! `tessera-server preview`: a shaded-relief picture of one pyramid level, so a
//! person can see what was built (hypsometric tint × Lambert hillshade).

use anyhow::Context;
use std::io::BufWriter;
use std::path::Path;
use tessera_shared::{Level, Pyramid};

/// Picks the finest level whose samples across the DEM fit in `max_px` pixels.
pub fn auto_level(p: &Pyramid<tessera_shared::FileSource>, max_px: u32) -> Level {
    let g = p.geometry();
    g.levels()
        .rev()
        .find(|&l| {
            let s = g.spacing(l);
            (u64::from(g.width().max(g.height()) - 1) / s + 1) <= u64::from(max_px)
        })
        .unwrap_or(Level::ROOT)
}

/// Heights of one level over the DEM's extent, in metres, row-major.
fn level_heights(
    p: &Pyramid<tessera_shared::FileSource>,
    level: Level,
) -> anyhow::Result<(usize, usize, Vec<f32>)> {
    let g = *p.geometry();
    let q = p.metadata().quantization;
    let s = g.spacing(level);
    let w = ((u64::from(g.width()) - 1) / s + 1) as usize;
    let h = ((u64::from(g.height()) - 1) / s + 1) as usize;
    let mut out = vec![0f32; w * h];
    let ts = g.tile_samples();
    let t = g.tile_size() as usize;
    for tile in g.present_tiles(level) {
        let rec = p.read_tile(tile)?.context("present tile has no record")?;
        let (x0, y0) = ((tile.x() as usize) * t, (tile.y() as usize) * t);
        for j in 0..ts {
            let y = y0 + j;
            if y >= h {
                break;
            }
            for i in 0..ts.min(w.saturating_sub(x0)) {
                out[y * w + x0 + i] = q.height(rec.heights[j * ts + i]) as f32;
            }
        }
    }
    Ok((w, h, out))
}

/// Colour ramp for a normalised height in `[0, 1]`: lowland green to snow.
fn tint(v: f32) -> [f32; 3] {
    const STOPS: [(f32, [f32; 3]); 5] = [
        (0.0, [0.16, 0.36, 0.22]),
        (0.3, [0.55, 0.63, 0.35]),
        (0.6, [0.76, 0.63, 0.42]),
        (0.85, [0.55, 0.44, 0.36]),
        (1.0, [0.97, 0.97, 0.97]),
    ];
    let v = v.clamp(0.0, 1.0);
    for w in STOPS.windows(2) {
        let ((a, ca), (b, cb)) = (w[0], w[1]);
        if v <= b {
            let f = (v - a) / (b - a);
            return [0, 1, 2].map(|i| ca[i] + (cb[i] - ca[i]) * f);
        }
    }
    STOPS[4].1
}

/// The shaded relief of `w × h` heights (metres, row-major) as 8-bit RGB:
/// hypsometric tint between their lowest and highest value × Lambert hillshade
/// (sun from the north-west, 45° up), the slopes scaled so the 90th-percentile
/// one shows at 45° (a grid may carry no horizontal units). Also the server's
/// preview pictures (serve/viewer/preview.rs).
pub fn shade(w: usize, h: usize, z: &[f32]) -> Vec<u8> {
    assert_eq!(z.len(), w * h, "w × h heights");
    let (lo, hi) = z
        .iter()
        .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    let range = (hi - lo).max(1e-3);
    // Gradients in metres per sample; the z-factor makes the 90th-percentile slope 45°,
    // since a pyramid may carry no horizontal units.
    let at = |x: usize, y: usize| z[y.min(h - 1) * w + x.min(w - 1)];
    let grad = |x: usize, y: usize| {
        let dx = (at(x + 1, y) - at(x.saturating_sub(1), y)) * 0.5;
        let dy = (at(x, y + 1) - at(x, y.saturating_sub(1))) * 0.5;
        (dx, dy)
    };
    let mut mags: Vec<f32> = (0..w * h)
        .step_by(7)
        .map(|i| {
            let (dx, dy) = grad(i % w, i / w);
            dx.hypot(dy)
        })
        .collect();
    mags.sort_by(f32::total_cmp);
    let p90 = mags
        .get(mags.len() * 9 / 10)
        .copied()
        .unwrap_or(1.0)
        .max(1e-3);
    let zf = 1.0 / p90;
    let sun = {
        let (az, alt) = (315f32.to_radians(), 45f32.to_radians());
        [alt.cos() * az.sin(), -alt.cos() * az.cos(), alt.sin()]
    };
    let mut rgb = vec![0u8; w * h * 3];
    for y in 0..h {
        for x in 0..w {
            let (dx, dy) = grad(x, y);
            let n = [-dx * zf, -dy * zf, 1.0];
            let len = (n[0] * n[0] + n[1] * n[1] + 1.0).sqrt();
            let lambert = ((n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2]) / len).max(0.0);
            let light = 0.35 + 0.65 * lambert;
            let c = tint((at(x, y) - lo) / range);
            for i in 0..3 {
                rgb[(y * w + x) * 3 + i] = (c[i] * light * 255.0).round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    rgb
}

/// Renders `level` (or an automatic one) of `file` as a shaded-relief PNG at `out`.
pub fn preview(
    file: &Path,
    out: &Path,
    level: Option<u8>,
    max_px: u32,
) -> anyhow::Result<(Level, usize, usize)> {
    let p = Pyramid::open_file(file)?;
    let level = match level {
        Some(l) => Level::new(l)
            .filter(|l| *l <= p.geometry().finest())
            .with_context(|| {
                format!(
                    "level {l} is not in this pyramid (0..={})",
                    p.geometry().finest()
                )
            })?,
        None => auto_level(&p, max_px),
    };
    let (w, h, z) = level_heights(&p, level)?;
    let rgb = shade(w, h, &z);
    let dir = out
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let tmp = tempfile::NamedTempFile::new_in(dir)
        .with_context(|| format!("cannot create a file in {}", dir.display()))?;
    {
        let mut enc = png::Encoder::new(BufWriter::new(tmp.as_file()), w as u32, h as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header()?.write_image_data(&rgb)?;
    }
    // Temporary files are private (0600); a picture is an ordinary file.
    std::fs::set_permissions(
        tmp.path(),
        std::os::unix::fs::PermissionsExt::from_mode(0o644),
    )?;
    tmp.persist(out).map_err(|e| e.error)?;
    Ok((level, w, h))
}
