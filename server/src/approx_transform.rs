//! Approximate coordinate transforms over rows and grids of points: exact at the
//! ends of spans, linear inside spans whose middle point is within a tolerance of
//! its exact transform, halved where it is not. GDAL's approximate transformer
//! does the same along rows with 1/8 pixel; we default to far less (see callers).
//!
//! A projection is smooth at the scale of a tile or a row, so a few dozen exact
//! transforms stand in for thousands: `build --to` (ingest/reproject.rs) and the
//! web tiles resampled from the pyramid (web/resample.rs) both use this.
//!
//! ```
//! use tessera_server::approx_transform::along_row;
//!
//! // A curved mapping: exact at span ends, linear inside where that is close enough.
//! let exact = |i: usize| Some([(i as f64 / 10.0).sin() * 100.0, i as f64]);
//! let got = along_row(500, 1e-3, &exact);
//! for (i, p) in got.iter().enumerate() {
//!     let want = exact(i).unwrap();
//!     assert!((p[0] - want[0]).abs() <= 2e-3 && (p[1] - want[1]).abs() <= 2e-3);
//! }
//! ```

/// Longest span of points between exact transforms.
pub const STEP: usize = 64;

/// Fills `out[i..=k]` between exact ends `a` (at `i`) and `b` (at `k`), splitting the
/// span while its middle is off the line by more than `tol`. A failed transform
/// (beyond a projection's domain) splits too, down to single points.
fn fill_span(
    exact: &impl Fn(usize) -> Option<[f64; 2]>,
    tol: f64,
    out: &mut [[f64; 2]],
    i: usize,
    a: Option<[f64; 2]>,
    k: usize,
    b: Option<[f64; 2]>,
) {
    if let Some(p) = b {
        out[k] = p;
    }
    if k - i <= 1 {
        return;
    }
    let m = usize::midpoint(i, k);
    let mid = exact(m);
    if let (Some(pa), Some(pb), Some(pm)) = (a, b, mid) {
        let t = (m - i) as f64 / (k - i) as f64;
        let lin = lerp(pa, pb, t);
        if (lin[0] - pm[0]).abs() <= tol && (lin[1] - pm[1]).abs() <= tol {
            for (n, o) in out[i + 1..k].iter_mut().enumerate() {
                *o = lerp(pa, pb, (n + 1) as f64 / (k - i) as f64);
            }
            return;
        }
    }
    fill_span(exact, tol, out, i, a, m, mid);
    fill_span(exact, tol, out, m, mid, k, b);
}

fn lerp(a: [f64; 2], b: [f64; 2], t: f64) -> [f64; 2] {
    [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]
}

/// The transforms of points `0..n` of a row, each within about `tol` of
/// `exact(i)`; `[NaN, NaN]` where the exact transform fails.
pub fn along_row(n: usize, tol: f64, exact: &impl Fn(usize) -> Option<[f64; 2]>) -> Vec<[f64; 2]> {
    let mut out = vec![[f64::NAN; 2]; n];
    if n == 0 {
        return out;
    }
    let mut i = 0;
    let mut a = exact(0);
    if let Some(p) = a {
        out[0] = p;
    }
    while i + 1 < n {
        let k = (i + STEP).min(n - 1);
        let b = exact(k);
        fill_span(exact, tol, &mut out, i, a, k, b);
        i = k;
        a = b;
    }
    out
}

/// The transforms of the points `(i, j)` of a `w × h` grid, row-major: rows at the
/// ends of spans of up to [`STEP`] rows are transformed with [`along_row`]; the rows
/// between are linear in `j` where the middle row's linear estimate is within `tol`
/// of its own [`along_row`] at every point, halved where it is not.
pub fn over_grid(
    w: usize,
    h: usize,
    tol: f64,
    exact: &impl Fn(usize, usize) -> Option<[f64; 2]>,
) -> Vec<[f64; 2]> {
    let mut out = vec![[f64::NAN; 2]; w * h];
    if w == 0 || h == 0 {
        return out;
    }
    let row = |j: usize| along_row(w, tol, &|i| exact(i, j));
    let mut j = 0;
    let mut a = row(0);
    out[..w].copy_from_slice(&a);
    while j + 1 < h {
        let k = (j + STEP).min(h - 1);
        let b = row(k);
        fill_rows(&row, tol, &mut out, w, j, &a, k, &b);
        j = k;
        a = b;
    }
    out
}

#[allow(clippy::too_many_arguments)]
fn fill_rows(
    row: &impl Fn(usize) -> Vec<[f64; 2]>,
    tol: f64,
    out: &mut [[f64; 2]],
    w: usize,
    j: usize,
    a: &[[f64; 2]],
    k: usize,
    b: &[[f64; 2]],
) {
    out[k * w..(k + 1) * w].copy_from_slice(b);
    if k - j <= 1 {
        return;
    }
    let m = usize::midpoint(j, k);
    let mid = row(m);
    let t = (m - j) as f64 / (k - j) as f64;
    let linear = (0..w).all(|i| {
        let lin = lerp(a[i], b[i], t);
        (lin[0] - mid[i][0]).abs() <= tol && (lin[1] - mid[i][1]).abs() <= tol
    });
    if linear {
        for r in j + 1..k {
            let t = (r - j) as f64 / (k - j) as f64;
            for i in 0..w {
                out[r * w + i] = lerp(a[i], b[i], t);
            }
        }
        return;
    }
    fill_rows(row, tol, out, w, j, a, m, &mid);
    fill_rows(row, tol, out, w, m, &mid, k, b);
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cell::Cell;

    #[test]
    fn an_affine_grid_needs_few_exact_transforms_and_is_exact() {
        let calls = Cell::new(0usize);
        let affine =
            |i: usize, j: usize| [3.0 + 0.5 * i as f64 - 0.25 * j as f64, 7.0 + 2.0 * j as f64];
        let counted = |i: usize, j: usize| {
            calls.set(calls.get() + 1);
            Some(affine(i, j))
        };
        let got = over_grid(512, 512, 1e-6, &counted);
        for j in 0..512 {
            for i in 0..512 {
                let (want, p) = (affine(i, j), got[j * 512 + i]);
                assert!((p[0] - want[0]).abs() < 1e-9 && (p[1] - want[1]).abs() < 1e-9);
            }
        }
        assert!(calls.get() < 512 * 512 / 100, "{} exact calls", calls.get());
    }

    #[test]
    fn a_curved_grid_stays_within_the_tolerance() {
        let exact = |i: usize, j: usize| {
            let (x, y) = (i as f64 / 300.0, j as f64 / 300.0);
            Some([x.exp() * 1000.0, (y * 1.3).sinh() * 800.0 + x * x * 50.0])
        };
        let tol = 1e-4;
        let got = over_grid(300, 257, tol, &exact);
        let mut worst = 0f64;
        for j in 0..257 {
            for i in 0..300 {
                let want = exact(i, j).unwrap();
                let p = got[j * 300 + i];
                worst = worst
                    .max((p[0] - want[0]).abs())
                    .max((p[1] - want[1]).abs());
            }
        }
        // Halving stops once the middle is within `tol`; the quarter points of a
        // quadratic are within 3/4 of that, so twice `tol` bounds every point.
        assert!(worst <= 2.0 * tol, "worst error {worst}");
        assert!(
            worst > 0.0,
            "the mapping is curved, so some points are interpolated"
        );
    }

    #[test]
    fn failed_transforms_are_nan_and_do_not_poison_neighbours() {
        // Beyond a projection's domain from point 10 on.
        let exact = |i: usize| (i < 10).then_some([i as f64, 0.0]);
        let got = along_row(100, 1e-3, &exact);
        for (i, p) in got.iter().enumerate() {
            if i < 10 {
                assert_eq!(p[0], i as f64);
            } else {
                assert!(p[0].is_nan() && p[1].is_nan(), "{i}: {p:?}");
            }
        }
    }
}
