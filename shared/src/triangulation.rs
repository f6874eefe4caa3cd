//! How a regular grid of samples is triangulated: the surface that error tables
//! measure and the renderer draws (docs/ARCHITECTURE.md#error-tables,
//! docs/ARCHITECTURE.md#crack-free-edges).
//!
//! A mesh of cell size `s` (in samples of the finest grid) has a vertex at every
//! sample whose coordinates are multiples of `s`. Each cell is split along the
//! diagonal from its north-west corner `(0, 0)` to its south-east corner `(s, s)`
//! (x grows east, y grows south). Inside a cell, at offset `(a, b)` with
//! `0 ≤ a, b ≤ s`, the surface is the plane of the triangle that holds the point:
//!
//! - `a ≥ b` (north-east triangle `(0,0) (s,0) (s,s)`):
//!   `s·z = s·q00 + (q10 − q00)·a + (q11 − q10)·b`
//! - `a < b` (south-west triangle `(0,0) (0,s) (s,s)`):
//!   `s·z = s·q00 + (q11 − q01)·a + (q01 − q00)·b`
//!
//! With integer heights this is exact integer arithmetic, so the builder, the
//! tests and the client all get bit-identical values.

/// Corner heights of one cell: north-west, north-east, south-west, south-east.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Cell {
    pub q00: i64,
    pub q10: i64,
    pub q01: i64,
    pub q11: i64,
}

impl Cell {
    /// `s` times the surface height at offset `(a, b)` inside a cell of size `s`.
    ///
    /// ```
    /// use tessera_shared::triangulation::Cell;
    /// let c = Cell { q00: 0, q10: 4, q01: 8, q11: 12 };
    /// assert_eq!(c.scaled_height(4, 0, 0), 0);      // a corner is exact
    /// assert_eq!(c.scaled_height(4, 2, 2), 4 * 6);  // on the diagonal: the mean of its ends
    /// ```
    pub const fn scaled_height(&self, s: i64, a: i64, b: i64) -> i64 {
        if a >= b {
            s * self.q00 + (self.q10 - self.q00) * a + (self.q11 - self.q10) * b
        } else {
            s * self.q00 + (self.q11 - self.q01) * a + (self.q01 - self.q00) * b
        }
    }

    /// The vertical distance between the surface and a sample of height `q` at `(a, b)`,
    /// in height units.
    pub fn vertical_error(&self, s: i64, a: i64, b: i64, q: i64) -> f64 {
        (self.scaled_height(s, a, b) - s * q).abs() as f64 / s as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn planes_agree_on_the_diagonal_and_edges() {
        let c = Cell {
            q00: 10,
            q10: -3,
            q01: 7,
            q11: 100,
        };
        let s = 8;
        for i in 0..=s {
            // On the diagonal both formulas must agree (it is shared by both triangles).
            let ne = s * c.q00 + (c.q10 - c.q00) * i + (c.q11 - c.q10) * i;
            let sw = s * c.q00 + (c.q11 - c.q01) * i + (c.q01 - c.q00) * i;
            assert_eq!(ne, sw);
            // Edges depend only on their own endpoints, so neighbouring cells agree.
            assert_eq!(c.scaled_height(s, i, 0), s * c.q00 + (c.q10 - c.q00) * i);
            assert_eq!(c.scaled_height(s, s, i), s * c.q10 + (c.q11 - c.q10) * i);
            assert_eq!(c.scaled_height(s, 0, i), s * c.q00 + (c.q01 - c.q00) * i);
            assert_eq!(c.scaled_height(s, i, s), s * c.q01 + (c.q11 - c.q01) * i);
        }
        assert!((c.vertical_error(s, 4, 4, 0) - 55.0).abs() < 1e-12);
    }
}
