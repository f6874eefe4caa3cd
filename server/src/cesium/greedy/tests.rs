//! The greedy mesher's tests: samples within the threshold, between samples too,
//! and the outline kept.

use super::*;
use crate::cesium::side::simplify;

fn rough(x: u32, y: u32) -> f64 {
    let mut s = (u64::from(x) * 0x9E37_79B9) ^ (u64::from(y) * 0x85EB_CA6B) ^ 0x1234_5678;
    s ^= s << 13;
    s ^= s >> 7;
    s ^= s << 17;
    let ridge = 200.0 - (f64::from(x) - f64::from(y)).abs() * 3.0;
    (s % 1000) as f64 / 100.0 + ridge.max(0.0) + f64::from(x) * 0.5
}

fn outline(grid: &HeightGrid, r: [f64; 4], tau: f64) -> Vec<SidePoint> {
    let [x0, y0, x1, y1] = r;
    let mut pts = Vec::new();
    for (a, b) in [
        ([x0, y0], [x1, y0]),
        ([x1, y0], [x1, y1]),
        ([x1, y1], [x0, y1]),
        ([x0, y1], [x0, y0]),
    ] {
        let side = simplify(grid, a, b, tau);
        pts.extend_from_slice(&side[..side.len() - 1]);
    }
    pts
}

fn plane_at(m: &GreedyMesh, t: &[u32; 3], p: [f64; 2]) -> Option<f64> {
    let [a, b, c] = t.map(|i| m.points[i as usize]);
    let det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
    let l1 = ((p[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (p[1] - a[1])) / det;
    let l2 = ((b[0] - a[0]) * (p[1] - a[1]) - (p[0] - a[0]) * (b[1] - a[1])) / det;
    let l0 = 1.0 - l1 - l2;
    let eps = -1e-9;
    (l0 >= eps && l1 >= eps && l2 >= eps).then(|| {
        let h = t.map(|i| m.heights[i as usize]);
        l0 * h[0] + l1 * h[1] + l2 * h[2]
    })
}

fn check(grid: &HeightGrid, r: [f64; 4], tau: f64) -> GreedyMesh {
    let m = mesh(grid, r, &outline(grid, r, tau), tau);
    // Positively oriented, non-degenerate, covering the rectangle's area.
    let mut area = 0.0;
    for t in &m.triangles {
        let [a, b, c] = t.map(|i| m.points[i as usize]);
        let o = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
        assert!(o > 0.0, "triangle {t:?} orientation {o}");
        area += o / 2.0;
    }
    let want = (r[2] - r[0]) * (r[3] - r[1]);
    assert!((area - want).abs() < 1e-6 * want, "area {area} of {want}");
    // Every sample in the rectangle within tau of the mesh (those on its sides
    // by the side rule).
    let [gx, gy, gw, gh] = grid.frame();
    for y in gy..gy + gh {
        for x in gx..gx + gw {
            let p = [f64::from(x), f64::from(y)];
            if p[0] < r[0] || p[0] > r[2] || p[1] < r[1] || p[1] > r[3] {
                continue;
            }
            let z = m
                .triangles
                .iter()
                .find_map(|t| plane_at(&m, t, p))
                .expect("covered");
            let err = (z - grid.at(x, y)).abs();
            assert!(err <= tau + 1e-9, "tau {tau}: {err} at ({x}, {y})");
        }
    }
    // Between samples too, on a lattice of quarter cells in every cell whose four
    // corners are candidates (cells a side cuts or touches are left out: see
    // `mesh`): within `tau` of the north-west-diagonal surface, so within
    // `tau + twist / 4` of the bilinear one; where all four corners are vertices
    // and the mesh took the other diagonal, within `twist / 4` of the bilinear.
    let (x0, y0) = (r[0].floor() + 1.0, r[1].floor() + 1.0);
    let (x1, y1) = (r[2].ceil() - 1.0, r[3].ceil() - 1.0);
    let mut y = y0;
    while y <= y1 {
        let mut x = x0;
        while x <= x1 {
            let (i, j) = (x.floor().min(x1 - 1.0), y.floor().min(y1 - 1.0));
            let q = |a: f64, b: f64| grid.at((i + a) as u32, (j + b) as u32);
            let (fx, fy) = (x - i, y - j);
            let bilinear = (1.0 - fy) * ((1.0 - fx) * q(0.0, 0.0) + fx * q(1.0, 0.0))
                + fy * ((1.0 - fx) * q(0.0, 1.0) + fx * q(1.0, 1.0));
            let twist = (q(0.0, 0.0) + q(1.0, 1.0) - q(1.0, 0.0) - q(0.0, 1.0)).abs();
            let z = m
                .triangles
                .iter()
                .find_map(|t| plane_at(&m, t, [x, y]))
                .expect("covered");
            let err = (z - bilinear).abs();
            assert!(
                err <= tau + twist / 4.0 + 1e-9,
                "tau {tau}: {err} at ({x}, {y}) between samples (twist {twist})"
            );
            x += 0.25;
        }
        y += 0.25;
    }
    m
}

#[test]
fn every_sample_is_within_tau_and_few_triangles_suffice() {
    let grid = HeightGrid::new([0, 0, 64, 64], rough).unwrap();
    let r = [0.0, 0.0, 64.0, 64.0];
    let fine = check(&grid, r, 0.5).triangles.len();
    let coarse = check(&grid, r, 20.0).triangles.len();
    assert!(coarse * 4 < fine, "{coarse} vs {fine}");
    assert!(coarse < 2 * 64 * 64 / 8, "{coarse}");
}

#[test]
fn a_fractional_rectangle_is_meshed_within_tau_at_and_between_its_samples() {
    let grid = HeightGrid::new([3, 2, 40, 37], rough).unwrap();
    for tau in [1.0, 6.0, 25.0] {
        let m = check(&grid, [3.3, 2.75, 39.5, 36.1], tau);
        assert_eq!(m.tau, tau);
    }
}

#[test]
fn the_outline_is_kept_as_given() {
    let grid = HeightGrid::new([0, 0, 32, 32], rough).unwrap();
    let r = [0.5, 0.25, 31.5, 30.0];
    let o = outline(&grid, r, 3.0);
    let m = mesh(&grid, r, &o, 3.0);
    // The outline's points are the mesh's first points, unchanged, and every
    // hull edge joins two consecutive outline points.
    for (k, p) in o.iter().enumerate() {
        assert_eq!(m.points[k], [p.x, p.y]);
        assert_eq!(m.heights[k], p.h);
    }
    let n = o.len() as u32;
    let mut hull = 0;
    let mut uses = std::collections::HashMap::new();
    for t in &m.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *uses.entry((a.min(b), a.max(b))).or_insert(0) += 1;
        }
    }
    for ((a, b), u) in uses {
        if u == 1 {
            hull += 1;
            assert!(a < n && b < n, "hull edge {a}-{b} leaves the outline");
            assert!(b == a + 1 || (a == 0 && b == n - 1), "hull edge {a}-{b}");
        }
    }
    assert_eq!(hull, n);
}
