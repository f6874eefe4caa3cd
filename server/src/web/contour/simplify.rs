//! Douglas–Peucker line simplification (Douglas & Peucker 1973): keep a line's ends,
//! then recursively the vertex farthest from the chord between kept vertices while
//! it lies more than `tolerance` away. Every kept vertex is one of the input's, so a
//! contour keeps its exact points on the level, only fewer of them.
//!
//! Written here rather than taken from `geo`: one function, against that crate's
//! compile time.

/// Distance from `p` to the segment `a`–`b` (to `a` when they coincide, as at a
/// ring's closing chord).
fn distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let (x, y) = (a[0] + t * dx, a[1] + t * dy);
    ((p[0] - x).powi(2) + (p[1] - y).powi(2)).sqrt()
}

/// `points` with the vertices that lie within `tolerance` of the simplified line
/// removed; the ends are always kept.
pub fn douglas_peucker(points: &[[f64; 2]], tolerance: f64) -> Vec<[f64; 2]> {
    if points.len() < 3 {
        return points.to_vec();
    }
    let mut keep = vec![false; points.len()];
    keep[0] = true;
    keep[points.len() - 1] = true;
    let mut stack = vec![(0, points.len() - 1)];
    while let Some((i, j)) = stack.pop() {
        let (far, d) = (i + 1..j)
            .map(|k| (k, distance(points[k], points[i], points[j])))
            .fold((i, -1.0), |best, x| if x.1 > best.1 { x } else { best });
        if d > tolerance {
            keep[far] = true;
            stack.push((i, far));
            stack.push((far, j));
        }
    }
    points
        .iter()
        .zip(keep)
        .filter_map(|(p, k)| k.then_some(*p))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Distance from `p` to the polyline `line`.
    fn off(line: &[[f64; 2]], p: [f64; 2]) -> f64 {
        line.windows(2)
            .map(|w| distance(p, w[0], w[1]))
            .fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn straight_runs_collapse_and_corners_stay() {
        let line: Vec<[f64; 2]> = (0..=10)
            .map(|i| [f64::from(i), 0.0])
            .chain((1..=10).map(|i| [10.0, f64::from(i)]))
            .collect();
        assert_eq!(
            douglas_peucker(&line, 0.1),
            vec![[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]
        );
    }

    #[test]
    fn wiggles_within_the_tolerance_go_and_larger_ones_stay() {
        let wiggle = |amp: f64| -> Vec<[f64; 2]> {
            (0..=20)
                .map(|i| [f64::from(i), if i % 2 == 0 { 0.0 } else { amp }])
                .collect()
        };
        assert_eq!(douglas_peucker(&wiggle(0.4), 0.5).len(), 2);
        let kept = douglas_peucker(&wiggle(0.6), 0.5);
        assert!(kept.len() > 10, "{kept:?}");
        // Every kept vertex is an input vertex, in order, and no input vertex lies
        // farther than the tolerance from the result.
        let mut at = wiggle(0.6).into_iter();
        assert!(kept.iter().all(|p| at.any(|q| q == *p)));
        assert!(wiggle(0.6).iter().all(|p| off(&kept, *p) <= 0.5));
    }

    #[test]
    fn a_ring_keeps_its_shape() {
        let mut ring: Vec<[f64; 2]> = (0..64)
            .map(|i| {
                let a = f64::from(i) / 64.0 * std::f64::consts::TAU;
                [10.0 * a.cos(), 10.0 * a.sin()]
            })
            .collect();
        ring.push(ring[0]);
        let kept = douglas_peucker(&ring, 0.25);
        assert_eq!(kept.first(), kept.last());
        assert!(kept.len() > 8 && kept.len() < 40, "{}", kept.len());
        // No input vertex lies farther than the tolerance from the simplified ring.
        for p in &ring {
            assert!(off(&kept, *p) <= 0.25 + 1e-12, "{p:?}");
        }
    }
}
