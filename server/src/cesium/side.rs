//! The vertices on one side of a tile's mesh, chosen by a rule that reads only the
//! samples along that side, so two tiles that share the side choose the same
//! vertices with the same bits (DECISIONS.md "Cesium terrain").
//!
//! A side is an axis-parallel segment of the level's sample space (a tile's edge, or
//! the data's). Along it `F` ([`super::surface`]) is linear between its *breaks*,
//! where the side crosses a grid line or a north-west diagonal. The side keeps its
//! two ends and then, Douglas–Peucker style (vertical distance), the break farthest
//! from the chord between the points kept so far, until every break is within `tau`
//! of the kept polyline. That is exact along the side: the polyline and `F` are both
//! linear between breaks.

use super::surface::HeightGrid;

/// A point on a side: its position (global sample coordinates) and `F` there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SidePoint {
    pub x: f64,
    pub y: f64,
    pub h: f64,
}

/// The points of the side from `a` to `b` (axis-parallel, global sample
/// coordinates, inside `grid`) kept at threshold `tau`, from `a` to `b`.
///
/// The choice is made walking the side west to east or north to south whichever
/// way it is asked for, so both tiles along it make the same one.
pub fn simplify(grid: &HeightGrid, a: [f64; 2], b: [f64; 2], tau: f64) -> Vec<SidePoint> {
    if (b[0], b[1]) < (a[0], a[1]) {
        let mut pts = simplify(grid, b, a, tau);
        pts.reverse();
        return pts;
    }
    let breaks = profile(grid, a, b);
    let n = breaks.len();
    let mut keep = vec![false; n];
    keep[0] = true;
    keep[n - 1] = true;
    let mut stack = vec![(0, n - 1)];
    while let Some((i, j)) = stack.pop() {
        if j <= i + 1 {
            continue;
        }
        let (p, q) = (breaks[i], breaks[j]);
        let span = q.0 - p.0;
        let mut worst = (0.0_f64, 0);
        for (k, &(t, h)) in breaks.iter().enumerate().take(j).skip(i + 1) {
            let line = p.1 + (q.1 - p.1) * ((t - p.0) / span);
            let e = (line - h).abs();
            if e > worst.0 {
                worst = (e, k);
            }
        }
        if worst.0 > tau {
            keep[worst.1] = true;
            stack.push((i, worst.1));
            stack.push((worst.1, j));
        }
    }
    let vertical = a[0] == b[0];
    breaks
        .into_iter()
        .zip(keep)
        .filter(|&(_, k)| k)
        .map(|((t, h), _)| {
            let (x, y) = if vertical { (a[0], t) } else { (t, a[1]) };
            SidePoint { x, y, h }
        })
        .collect()
}

/// `F`'s breaks along the side from `a` to `b` (`a` first in both coordinates), as
/// `(coordinate along the side, F)`, ends included, in order from `a`.
fn profile(grid: &HeightGrid, a: [f64; 2], b: [f64; 2]) -> Vec<(f64, f64)> {
    let vertical = a[0] == b[0];
    // The side is `fixed = const`, `t` running from `t0` to `t1`.
    let (fixed, t0, t1) = if vertical {
        (a[0], a[1], b[1])
    } else {
        (a[1], a[0], b[0])
    };
    let (lo, hi) = (t0, t1);
    let mut ts = vec![lo];
    // Grid lines cross at integers; north-west diagonals (x − y integer) at the
    // fixed coordinate's fraction plus integers.
    let frac = fixed - fixed.floor();
    let mut k = lo.floor();
    while k < hi {
        for t in [k, k + frac] {
            if t > lo && t < hi {
                ts.push(t);
            }
        }
        k += 1.0;
    }
    ts.push(hi);
    ts.sort_by(f64::total_cmp);
    ts.dedup();
    ts.into_iter()
        .map(|t| {
            let h = if vertical {
                grid.surface(fixed, t)
            } else {
                grid.surface(t, fixed)
            };
            (t, h)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rough(x: u32, y: u32) -> f64 {
        let s = (u64::from(x) * 7919 + u64::from(y) * 104_729) % 1000;
        s as f64 / 10.0 + f64::from(x)
    }

    fn grid() -> HeightGrid {
        HeightGrid::new([0, 0, 40, 40], rough).unwrap()
    }

    /// The kept polyline's largest distance from `F` along the side (dense check).
    fn worst(grid: &HeightGrid, pts: &[SidePoint]) -> f64 {
        pts.windows(2)
            .map(|w| {
                grid.segment_error([w[0].x, w[0].y], w[0].h, [w[1].x, w[1].y], w[1].h)
                    .0
            })
            .fold(0.0, f64::max)
    }

    #[test]
    fn a_side_is_within_tau_of_the_surface() {
        let g = grid();
        for tau in [0.5, 5.0, 30.0] {
            let pts = simplify(&g, [3.25, 1.0], [3.25, 38.5], tau);
            assert!(worst(&g, &pts) <= tau, "tau {tau}");
            let pts = simplify(&g, [0.0, 17.6], [40.0, 17.6], tau);
            assert!(worst(&g, &pts) <= tau, "tau {tau}");
        }
        // Loose thresholds keep few points; zero keeps every break.
        let all = simplify(&g, [3.25, 1.0], [3.25, 38.5], 0.0).len();
        let few = simplify(&g, [3.25, 1.0], [3.25, 38.5], 80.0).len();
        assert!(few * 3 < all, "{few} of {all}");
    }

    #[test]
    fn both_directions_keep_the_same_points_and_ends() {
        let g = grid();
        let ab = simplify(&g, [0.0, 9.5], [40.0, 9.5], 3.0);
        let mut ba = simplify(&g, [40.0, 9.5], [0.0, 9.5], 3.0);
        ba.reverse();
        assert_eq!(ab, ba);
        assert!(ab.len() > 2);
    }

    #[test]
    fn a_side_reads_only_the_samples_along_it() {
        // Two grids that agree on the cells along x = 12.5 and differ elsewhere keep
        // the same side, bit for bit: what two neighbouring tiles rely on.
        let a = HeightGrid::new([0, 0, 30, 30], rough).unwrap();
        let b = HeightGrid::new([5, 0, 20, 30], |x, y| {
            if (12..=13).contains(&x) {
                rough(x, y)
            } else {
                -1.0
            }
        })
        .unwrap();
        assert_eq!(
            simplify(&a, [12.5, 0.0], [12.5, 30.0], 2.0),
            simplify(&b, [12.5, 0.0], [12.5, 30.0], 2.0)
        );
    }
}
