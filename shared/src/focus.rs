//! A bootstrap's focus (API.md "Bootstrap"; DECISIONS.md "The first view in one
//! round trip"): the point of the dataset a client's first view is over, so that
//! the one response of its open carries the records that view needs at every
//! level, not only the coarsest.
//!
//! Why: a bootstrap that is the same for every client carries the coarsest levels.
//! A camera near the ground needs the finest tiles under it from its first frame,
//! and each level it lacks costs a round trip (150 ms is 9 frames at 60 fps) before
//! the view meets `τ`. With a focus, the server adds the tiles around the point at
//! every finer level: for level `L`, the children of the 2 × 2 tiles of level
//! `L − 1` whose centres are nearest the point. That is 4 × 4 tiles (fewer at the
//! DEM's edges), in whole sibling groups (selection refines a tile only when all
//! its children are resident, docs/ARCHITECTURE.md#selection), with at least one
//! tile of level `L` between the point and the block's border on every side.
//!
//! The choice is geometric (the server runs no camera model) and depends on the
//! point alone, so a focused bootstrap is as cacheable as any URL; the query keeps
//! four decimals ([`Focus::to_query`]) so that starts a few metres apart share one.

use crate::tile::{Level, TileGeometry, TileId};
use std::fmt;

/// A point of a dataset as fractions of its extent: `u` from the first column
/// (west) to the last, `v` from the first row (north) to the last, both in
/// `0..=1`, the units of a fly path's waypoints.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Focus {
    u: f64,
    v: f64,
}

/// Why a `?focus=` value is refused ([`Focus::parse`]); each names the query as sent.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FocusError {
    #[error("focus {query:?} is not two numbers U,V")]
    NotTwoNumbers { query: String },
    #[error("focus {query:?}: {part:?} is not a number")]
    NotANumber { query: String, part: String },
    #[error("focus {query:?} is outside the dataset (U and V run from 0 to 1)")]
    Outside { query: String },
}

impl Focus {
    /// A focus at `(u, v)`; `None` unless both are finite and within `0..=1`.
    ///
    /// ```
    /// use tessera_shared::focus::Focus;
    /// assert!(Focus::new(0.25, 1.0).is_some());
    /// assert!(Focus::new(1.5, 0.0).is_none());
    /// assert!(Focus::new(f64::NAN, 0.0).is_none());
    /// ```
    pub fn new(u: f64, v: f64) -> Option<Self> {
        let ok = |x: f64| x.is_finite() && (0.0..=1.0).contains(&x);
        (ok(u) && ok(v)).then_some(Self { u, v })
    }

    /// A focus from the query value `U,V` (`?focus=0.15,0.2`), or why not. It is
    /// kept to the query's four decimals ([`Focus::to_query`]), so that everything
    /// a server derives from it (its tiles, an ETag, a cache key) follows the
    /// point the query names, however many digits it was sent with.
    ///
    /// ```
    /// use tessera_shared::focus::Focus;
    /// assert_eq!(Focus::parse("0.5,0.25"), Ok(Focus::new(0.5, 0.25).unwrap()));
    /// assert_eq!(Focus::parse("0.12346,0.5"), Ok(Focus::new(0.1235, 0.5).unwrap()));
    /// assert!(Focus::parse("0.5").unwrap_err().to_string().contains("two numbers"));
    /// assert!(Focus::parse("2,0").unwrap_err().to_string().contains("0 to 1"));
    /// ```
    pub fn parse(s: &str) -> Result<Self, FocusError> {
        let mut parts = s.split(',');
        let (Some(a), Some(b), None) = (parts.next(), parts.next(), parts.next()) else {
            return Err(FocusError::NotTwoNumbers { query: s.into() });
        };
        let num = |p: &str| {
            p.trim().parse::<f64>().map_err(|_| FocusError::NotANumber {
                query: s.into(),
                part: p.into(),
            })
        };
        let (u, v) = (num(a)?, num(b)?);
        let f = Self::new(u, v).ok_or_else(|| FocusError::Outside { query: s.into() })?;
        // Within 0..=1 still: rounding moves neither past an end.
        let round = |x: f64| (x * 1e4).round() / 1e4;
        Ok(Self {
            u: round(f.u),
            v: round(f.v),
        })
    }

    /// The query value, rounded to four decimals (a ten-thousandth of the extent).
    pub fn to_query(&self) -> String {
        format!("{:.4},{:.4}", self.u, self.v)
    }

    /// The tiles of `level` the focus brings (see the module documentation), in
    /// Morton order: the root for level 0; else the children of the 2 × 2 tiles of
    /// the level above nearest the point, those inside the DEM.
    ///
    /// ```
    /// use tessera_shared::{Level, TileGeometry, focus::Focus};
    /// let g = TileGeometry::new(8192, 8192, 512).unwrap(); // 16 × 16 finest tiles
    /// let f = Focus::new(0.5, 0.5).unwrap();
    /// let tiles = f.tiles(&g, Level::new(4).unwrap());
    /// assert_eq!(tiles.len(), 16);
    /// assert!(tiles.iter().all(|t| (6..10).contains(&t.x()) && (6..10).contains(&t.y())));
    /// ```
    pub fn tiles(&self, g: &TileGeometry, level: Level) -> Vec<TileId> {
        let Some(parent) = level.coarser() else {
            return TileId::new(level, 0, 0).into_iter().collect();
        };
        // The point in finest samples, and the parent level's tile side in them.
        let x = self.u * f64::from(g.width() - 1);
        let y = self.v * f64::from(g.height() - 1);
        let side = (g.spacing(parent) * u64::from(g.tile_size())) as f64;
        let n = parent.tiles_per_side();
        // The pair of parent columns (rows) whose centres are nearest: the point
        // lies in the middle half of the pair, unless the DEM ends.
        let first = |p: f64| ((p / side - 0.5).floor().max(0.0) as u32).min(n.saturating_sub(2));
        let (px, py) = (first(x), first(y));
        let mut tiles: Vec<TileId> = (2 * py..2 * (py + 2))
            .flat_map(|ty| (2 * px..2 * (px + 2)).map(move |tx| (tx, ty)))
            .filter_map(|(tx, ty)| TileId::new(level, tx, ty))
            .filter(|t| g.is_present(*t))
            .collect();
        tiles.sort_by_key(|t| t.morton());
        tiles
    }
}

impl fmt::Display for Focus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.to_query())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn level(n: u8) -> Level {
        Level::new(n).unwrap()
    }

    /// Finest-sample extent of a tile: `(x0, y0, x1, y1)`.
    fn extent(g: &TileGeometry, t: TileId) -> (f64, f64, f64, f64) {
        let (x0, y0) = g.origin(t);
        let s = (g.spacing(t.level()) * u64::from(g.tile_size())) as f64;
        (x0 as f64, y0 as f64, x0 as f64 + s, y0 as f64 + s)
    }

    #[test]
    fn every_level_keeps_a_tile_of_margin_around_the_point_in_whole_sibling_groups() {
        let g = TileGeometry::new(8192, 8192, 512).unwrap();
        let mut seen_margin = 0;
        for k in 0..=40 {
            for j in 0..=40 {
                let (u, v) = (f64::from(k) / 40.0, f64::from(j) / 40.0);
                let f = Focus::new(u, v).unwrap();
                let (x, y) = (u * 8191.0, v * 8191.0);
                assert_eq!(f.tiles(&g, level(0)).len(), 1);
                for l in 1..=4 {
                    let tiles = f.tiles(&g, level(l));
                    // Whole sibling groups: every parent's four children, or none.
                    for t in &tiles {
                        for c in t.parent().unwrap().children().unwrap() {
                            assert!(!g.is_present(c) || tiles.contains(&c), "{f} {t}");
                        }
                    }
                    // The point is inside the block, with a whole tile of margin
                    // wherever the DEM goes on.
                    let s = (g.spacing(level(l)) * 512) as f64;
                    let x0 = tiles
                        .iter()
                        .map(|t| extent(&g, *t).0)
                        .fold(f64::MAX, f64::min);
                    let y0 = tiles
                        .iter()
                        .map(|t| extent(&g, *t).1)
                        .fold(f64::MAX, f64::min);
                    let x1 = tiles.iter().map(|t| extent(&g, *t).2).fold(0.0, f64::max);
                    let y1 = tiles.iter().map(|t| extent(&g, *t).3).fold(0.0, f64::max);
                    assert!(x0 <= x && x <= x1 && y0 <= y && y <= y1, "{f} level {l}");
                    for (gap, edge) in [(x - x0, x0), (y - y0, y0)] {
                        assert!(gap >= s || edge == 0.0, "{f} level {l}: {gap}");
                    }
                    for (gap, edge) in [(x1 - x, x1), (y1 - y, y1)] {
                        assert!(gap >= s || edge >= 8191.0, "{f} level {l}: {gap}");
                        seen_margin += usize::from(gap >= s);
                    }
                    assert!(
                        tiles.len() <= 16
                            && tiles.windows(2).all(|w| w[0].morton() < w[1].morton())
                    );
                }
            }
        }
        assert!(seen_margin > 1000);
    }

    #[test]
    fn a_dem_that_is_not_square_brings_only_present_tiles() {
        // 3000 × 700 samples in 256-cell tiles: 12 × 3 finest tiles of 16 × 16.
        let g = TileGeometry::new(3000, 700, 256).unwrap();
        let f = Focus::new(0.9, 0.9).unwrap();
        let tiles = f.tiles(&g, g.finest());
        assert!(!tiles.is_empty());
        assert!(
            tiles
                .iter()
                .all(|t| g.is_present(*t) && t.x() >= 8 && t.y() <= 2)
        );
    }

    #[test]
    fn bad_queries_are_named() {
        assert!(Focus::parse("").is_err());
        assert!(
            Focus::parse("0.1,0.2,0.3")
                .unwrap_err()
                .to_string()
                .contains("two numbers")
        );
        assert!(
            Focus::parse("0.1,x")
                .unwrap_err()
                .to_string()
                .contains("\"x\" is not a number")
        );
        assert!(
            Focus::parse("-0.1,0.5")
                .unwrap_err()
                .to_string()
                .contains("outside")
        );
        assert!(
            Focus::parse("NaN,0.5")
                .unwrap_err()
                .to_string()
                .contains("outside")
        );
        assert_eq!(
            Focus::parse(" 0.1, 0.2").unwrap().to_query(),
            "0.1000,0.2000"
        );
    }
}
