//! The interpolation kernels of the elevation API: which samples of a grid a point
//! reads, and with what weight. Separable (a weight per column times a weight per
//! row), as GDAL's kernels are, so one [`Stencil`] serves any grid: a pyramid level's
//! samples, or the finest samples the error bound is measured against
//! (elevation/bound.rs).

/// How a height is interpolated between samples (`interpolation=`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Interpolation {
    /// The nearest sample's height.
    Nearest,
    /// Bilinear between the four samples around the point (the default, as in
    /// opentopodata; GDAL's `-r bilinear`).
    Bilinear,
    /// Cubic convolution over the 4 × 4 samples around the point, Keys' kernel with
    /// a = −0.5 (GDAL's `-r cubic`).
    Cubic,
}

impl Interpolation {
    pub const ALL: [Interpolation; 3] = [Self::Nearest, Self::Bilinear, Self::Cubic];

    pub const fn name(self) -> &'static str {
        match self {
            Self::Nearest => "nearest",
            Self::Bilinear => "bilinear",
            Self::Cubic => "cubic",
        }
    }

    /// The method a query names, or `None`.
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == s)
    }
}

/// The samples a point reads along one axis: `n` consecutive indices from `first`
/// (each clamped to the grid: an edge sample repeats), with their weights.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Taps {
    first: i64,
    n: usize,
    weights: [f64; 4],
    last: i64,
}

impl Taps {
    /// The taps of `method` at coordinate `v` (in samples, `0 ≤ v ≤ last`) of an
    /// axis whose samples are `0..=last`.
    pub fn new(method: Interpolation, v: f64, last: i64) -> Self {
        let v = v.clamp(0.0, last as f64);
        match method {
            Interpolation::Nearest => Self {
                first: ((v + 0.5).floor() as i64).min(last),
                n: 1,
                weights: [1.0, 0.0, 0.0, 0.0],
                last,
            },
            Interpolation::Bilinear => {
                if last == 0 {
                    return Self::new(Interpolation::Nearest, v, last);
                }
                let i = (v.floor() as i64).min(last - 1);
                let t = v - i as f64;
                Self {
                    first: i,
                    n: 2,
                    weights: [1.0 - t, t, 0.0, 0.0],
                    last,
                }
            }
            Interpolation::Cubic => {
                let i = (v.floor() as i64).min(last);
                let t = v - i as f64;
                let (t2, t3) = (t * t, t * t * t);
                // Keys (1981) with a = −0.5: exact for quadratics, weights sum to 1.
                Self {
                    first: i - 1,
                    n: 4,
                    weights: [
                        -0.5 * t3 + t2 - 0.5 * t,
                        1.5 * t3 - 2.5 * t2 + 1.0,
                        -1.5 * t3 + 2.0 * t2 + 0.5 * t,
                        0.5 * t3 - 0.5 * t2,
                    ],
                    last,
                }
            }
        }
    }

    /// `(index, weight)` of each tap, indices clamped to the axis.
    pub fn iter(&self) -> impl Iterator<Item = (i64, f64)> + '_ {
        (0..self.n).map(|k| ((self.first + k as i64).clamp(0, self.last), self.weights[k]))
    }

    /// The lowest and highest index read.
    pub fn span(&self) -> (i64, i64) {
        (
            self.first.clamp(0, self.last),
            (self.first + self.n as i64 - 1).clamp(0, self.last),
        )
    }
}

/// A point's taps on both axes of a grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stencil {
    pub cols: Taps,
    pub rows: Taps,
}

impl Stencil {
    /// `method` at `(x, y)` of a grid of samples `0..=last[0]` × `0..=last[1]`.
    pub fn new(method: Interpolation, [x, y]: [f64; 2], last: [i64; 2]) -> Self {
        Self {
            cols: Taps::new(method, x, last[0]),
            rows: Taps::new(method, y, last[1]),
        }
    }

    /// `(column, row, weight)` of every sample read.
    pub fn samples(&self) -> impl Iterator<Item = (i64, i64, f64)> + '_ {
        self.rows
            .iter()
            .flat_map(move |(r, wr)| self.cols.iter().map(move |(c, wc)| (c, r, wc * wr)))
    }

    /// Σ |weight|: how much an error of each sample can move the result.
    pub fn abs_weight(&self) -> f64 {
        let sum = |t: &Taps| t.weights[..t.n].iter().map(|w| w.abs()).sum::<f64>();
        sum(&self.cols) * sum(&self.rows)
    }

    /// The interpolated value of `height(column, row)`.
    pub fn apply(&self, mut height: impl FnMut(i64, i64) -> f64) -> f64 {
        let mut sum = 0.0;
        for (r, wr) in self.rows.iter() {
            let mut row = 0.0;
            for (c, wc) in self.cols.iter() {
                row += wc * height(c, r);
            }
            sum += wr * row;
        }
        sum
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn value(method: Interpolation, p: [f64; 2], f: impl Fn(f64, f64) -> f64) -> f64 {
        Stencil::new(method, p, [20, 20]).apply(|c, r| f(c as f64, r as f64))
    }

    /// Each kernel reproduces what it should: nearest the sample, bilinear any
    /// bilinear function, cubic any quadratic (Keys' a = −0.5), away from the edges.
    #[test]
    fn kernels_reproduce_their_polynomials() {
        let bilinear = |x: f64, y: f64| 3.0 + 2.0 * x - 5.0 * y + 0.25 * x * y;
        let quadratic = |x: f64, y: f64| 1.0 + x * x - 0.5 * y * y + 0.3 * x * y - y;
        for p in [[3.25, 7.5], [10.0, 10.0], [4.9, 2.01], [17.999, 1.5]] {
            let b = value(Interpolation::Bilinear, p, bilinear);
            assert!((b - bilinear(p[0], p[1])).abs() < 1e-9, "{p:?}: {b}");
            let c = value(Interpolation::Cubic, p, quadratic);
            assert!((c - quadratic(p[0], p[1])).abs() < 1e-9, "{p:?}: {c}");
            let n = value(Interpolation::Nearest, p, bilinear);
            let (i, j) = ((p[0] + 0.5).floor(), (p[1] + 0.5).floor());
            assert_eq!(n, bilinear(i, j));
        }
        // Bilinear is not exact for a quadratic: the kernels differ.
        let b = value(Interpolation::Bilinear, [3.5, 3.5], quadratic);
        assert!((b - quadratic(3.5, 3.5)).abs() > 0.1);
    }

    /// At a sample every kernel gives the sample; weights always sum to 1; at the
    /// grid's edges taps repeat the edge sample instead of reading beyond it.
    #[test]
    fn samples_are_exact_and_edges_clamp() {
        let f = |x: f64, y: f64| (x * 1.7).sin() * 100.0 + y * y;
        for m in Interpolation::ALL {
            assert_eq!(value(m, [6.0, 9.0], f), f(6.0, 9.0), "{m:?}");
            for p in [[0.0, 0.0], [20.0, 20.0], [0.3, 19.8], [13.37, 0.61]] {
                let s = Stencil::new(m, p, [20, 20]);
                let w: f64 = s.samples().map(|(_, _, w)| w).sum();
                assert!((w - 1.0).abs() < 1e-12, "{m:?} {p:?}: {w}");
                assert!(
                    s.samples()
                        .all(|(c, r, _)| (0..=20).contains(&c) && (0..=20).contains(&r))
                );
                assert!(s.abs_weight() >= 1.0 - 1e-12);
            }
        }
        // One sample wide: bilinear falls back to the sample.
        let one = Stencil::new(Interpolation::Bilinear, [0.0, 0.0], [0, 0]);
        assert_eq!(one.samples().count(), 1);
        assert_eq!(Interpolation::parse("cubic"), Some(Interpolation::Cubic));
        assert_eq!(Interpolation::parse("spline"), None);
    }
}
