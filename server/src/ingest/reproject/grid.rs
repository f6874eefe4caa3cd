//! The output grid of a reprojection: where a source's footprint lies in the target
//! CRS, one source sample's step there, and the north-up grid that covers it.

use crate::crs::Crs;
use anyhow::{Context, bail};

/// An output grid: size and north-up geotransform.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    pub width: u32,
    pub height: u32,
    pub gt: [f64; 6],
}

/// The outer pixel edges of a `w × h` grid with geotransform `gt`, `per_edge` points
/// on each side, as a ring (not closed) counter-clockwise for a north-up grid: west
/// edge down, south edge east, east edge up, north edge west. Straight lines bend
/// under most projections, so corners alone would cut a footprint short.
pub fn border_ring(gt: &[f64; 6], w: f64, h: f64, per_edge: u32) -> Vec<[f64; 3]> {
    let corner = |c: f64, r: f64| [gt[0] + c * gt[1], gt[3] + r * gt[5], 0.0];
    let n = f64::from(per_edge);
    let mut ring = Vec::with_capacity(4 * per_edge as usize);
    for k in 0..per_edge {
        let t = f64::from(k) / n;
        ring.push(corner(0.0, h * t));
    }
    for k in 0..per_edge {
        let t = f64::from(k) / n;
        ring.push(corner(w * t, h));
    }
    for k in 0..per_edge {
        let t = f64::from(k) / n;
        ring.push(corner(w, h * (1.0 - t)));
    }
    for k in 0..per_edge {
        let t = f64::from(k) / n;
        ring.push(corner(w * (1.0 - t), 0.0));
    }
    ring
}

/// `[x0, y0, x1, y1]` around `points` (infinite and inverted when there are none).
pub fn bounds<'a>(points: impl IntoIterator<Item = &'a [f64; 2]>) -> [f64; 4] {
    points.into_iter().fold(
        [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ],
        |b, p| {
            [
                b[0].min(p[0]),
                b[1].min(p[1]),
                b[2].max(p[0]),
                b[3].max(p[1]),
            ]
        },
    )
}

/// The bounding box `[x0, y0, x1, y1]` in `target` of a `w × h` source grid's pixel
/// areas: its border ([`border_ring`], 64 points per edge), carried over.
pub fn footprint(
    source: &Crs,
    target: &Crs,
    gt: &[f64; 6],
    w: usize,
    h: usize,
) -> anyhow::Result<[f64; 4]> {
    let mut border = border_ring(gt, w as f64, h as f64, 64);
    source
        .transform_points(target, &mut border)
        .context("the source's border does not transform")?;
    let flat: Vec<[f64; 2]> = border.iter().map(|p| [p[0], p[1]]).collect();
    Ok(bounds(&flat))
}

/// One source sample's step at the source's centre, carried to the target CRS:
/// `[x, y]` in the target's units.
pub fn source_step(
    source: &Crs,
    target: &Crs,
    gt: &[f64; 6],
    w: usize,
    h: usize,
) -> anyhow::Result<[f64; 2]> {
    let corner = |c: f64, r: f64| [gt[0] + c * gt[1], gt[3] + r * gt[5]];
    let to = |p: [f64; 2]| source.transform_to(target, p[0], p[1]);
    let (c, r) = (w as f64 / 2.0, h as f64 / 2.0);
    let p = to(corner(c, r))?;
    let px = to(corner(c + 1.0, r))?;
    let py = to(corner(c, r + 1.0))?;
    Ok([
        (px[0] - p[0]).hypot(px[1] - p[1]),
        (py[0] - p[0]).hypot(py[1] - p[1]),
    ])
}

/// Footprint and spacing of the source in the target CRS.
pub(super) fn plan_grid(
    source: &Crs,
    target: &Crs,
    gt: &[f64; 6],
    w: usize,
    h: usize,
    spacing: Option<[f64; 2]>,
) -> anyhow::Result<Grid> {
    let [x0, y0, x1, y1] = footprint(source, target, gt, w, h).context("--to")?;
    let [sx, sy] = if let Some(s) = spacing {
        s
    } else {
        source_step(source, target, gt, w, h)?
    };
    if !(sx.is_finite() && sy.is_finite() && sx > 0.0 && sy > 0.0) {
        bail!("--to: output spacing {sx} × {sy} is not positive");
    }
    let width = ((x1 - x0) / sx).ceil();
    let height = ((y1 - y0) / sy).ceil();
    if !(width >= 2.0 && height >= 2.0 && width * height <= 4.0e10) {
        bail!("--to: the output grid would be {width} × {height} samples");
    }
    Ok(Grid {
        width: width as u32,
        height: height as u32,
        gt: [x0, sx, 0.0, y1, 0.0, -sy],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_covers_the_footprint_at_the_source_resolution() {
        // 1000 × 500 samples of 30 m in UTM 11N → WGS 84: ~0.00033° × 0.00027°.
        let src = Crs::from_epsg(32611).unwrap();
        let dst = Crs::from_epsg(4326).unwrap();
        let gt = [400_000.0, 30.0, 0.0, 3_800_000.0, 0.0, -30.0];
        let g = plan_grid(&src, &dst, &gt, 1000, 500, None).unwrap();
        // Every source corner lies inside the output's pixel areas.
        for (c, r) in [(0.0, 0.0), (1000.0, 0.0), (0.0, 500.0), (1000.0, 500.0)] {
            let [x, y] = src
                .transform_to(&dst, gt[0] + c * gt[1], gt[3] + r * gt[5])
                .unwrap();
            assert!(x >= g.gt[0] - 1e-12 && x <= g.gt[0] + f64::from(g.width) * g.gt[1] + 1e-12);
            assert!(y <= g.gt[3] + 1e-12 && y >= g.gt[3] + f64::from(g.height) * g.gt[5] - 1e-12);
        }
        // 30 m is 1/3700° of latitude and 30 / (111.3 km · cos 34.3°) of longitude.
        assert!((g.gt[1] - 30.0 / 92_000.0).abs() < 2e-5, "{}", g.gt[1]);
        assert!((-g.gt[5] - 30.0 / 110_900.0).abs() < 1e-5, "{}", g.gt[5]);
    }
}
