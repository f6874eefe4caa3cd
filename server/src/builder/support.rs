//! Which tiles a multi-resolution pyramid stores (DECISIONS.md "Multi-resolution
//! pyramids"): deep levels only where data that fine exists.
//!
//! Each input supports the levels down to the finest whose samples are no finer than
//! its own (an input 10× coarser than the pyramid's finest spacing supports 3 levels
//! above the finest: 8× keeps its data, 16× would lose it). A tile's *support* is the
//! deepest level any input touching it supports. A tile at level `L` is stored iff
//! `L ≤ support(parent)`: siblings are stored together, so a reader refining a tile
//! finds all four children or none (no child's area is left undrawn), and below a
//! tile covered only by coarse data there is nothing: its finer view is its own
//! surface. Supports are balanced so that neighbouring tiles' supports differ by at
//! most one level (a restricted quadtree: the client never has to coarsen fine data
//! beside coarse data to keep drawn neighbours within one level). Tiles not stored
//! are absent from the file exactly as wholly no-data tiles
//! are; their nodes are still built, so every coarser tile's heights and error table
//! are what they would be in a full pyramid (exact against the finest data).

use tessera_shared::{Level, Morton, TileGeometry, TileId};

pub use crate::ingest::Coverage;

/// The support of every tile, level by level: `levels[L][morton]` is the deepest level
/// any input touching tile `(L, morton)` supports (0 where none does).
#[derive(Clone, Debug, PartialEq)]
pub struct Support {
    levels: Vec<Vec<u8>>,
    /// The coarsest input's level: every tile at or above it is stored (so the levels a
    /// distributed build's assembly makes need no support of their own).
    floor: u8,
}

/// The level an input of `metres` spacing supports in a pyramid whose finest level
/// `finest` has samples `pyramid` metres apart.
pub fn supported_level(metres: f64, pyramid: f64, finest: Level) -> u8 {
    let ratio = metres / pyramid;
    let up = if ratio.is_finite() && ratio > 1.0 {
        // A millionth of slack: an input exactly 2^k coarser whose spacing is computed
        // in another CRS must not miss its level to rounding.
        (ratio * (1.0 + 1e-6)).log2().floor().max(0.0) as u8
    } else {
        0
    };
    finest.get().saturating_sub(up)
}

/// Raises supports at one level (`s`, in Morton order) until edge neighbours differ
/// by at most one: `s(n) ≥ s(t) − 1`. Then the stored tiles form a restricted
/// quadtree, in which a tile stored at level `L` has every edge neighbour's area
/// stored at level `L − 1` or finer (the support of its grandparent's neighbour is at
/// least `L − 1`), which is what the client's balancing of drawn tiles needs to draw
/// fine data beside coarse data at full detail instead of coarsening it. A tile
/// raised here is stored one level deeper, as an exact node of the pyramid (its
/// heights are the mosaic's, resampled from what lies there).
fn balance(s: &mut [u8], level: u8) {
    let n = 1i64 << level;
    let Some(&top) = s.iter().max() else { return };
    // Highest value first: a tile raised to `v − 1` is spread in the next pass.
    for v in (2..=top).rev() {
        for m in 0..s.len() {
            if s[m] != v {
                continue;
            }
            let (x, y) = Morton::from_raw(m as u64).decode();
            for (dx, dy) in [(0i64, -1i64), (1, 0), (0, 1), (-1, 0)] {
                let (nx, ny) = (i64::from(x) + dx, i64::from(y) + dy);
                if nx < 0 || ny < 0 || nx >= n || ny >= n {
                    continue;
                }
                let nm = Morton::encode(nx as u32, ny as u32).get() as usize;
                s[nm] = s[nm].max(v - 1);
            }
        }
    }
}

impl Support {
    /// Support for inputs `coverage` over `geometry`, whose finest samples are
    /// `pyramid` metres apart. `None` when every input supports the finest level
    /// (the pyramid is stored whole, as before multi-resolution).
    pub fn new(geometry: &TileGeometry, coverage: &[Coverage], pyramid: f64) -> Option<Self> {
        let finest = geometry.finest();
        let levels_of: Vec<u8> = coverage
            .iter()
            .map(|c| supported_level(c.metres, pyramid, finest))
            .collect();
        if levels_of.iter().all(|&l| l == finest.get()) {
            return None;
        }
        let t = u64::from(geometry.tile_size());
        let n = 1u64 << finest.get();
        let mut fine = vec![0u8; (n * n) as usize];
        for (c, &level) in coverage.iter().zip(&levels_of) {
            let [x0, y0, x1, y1] = c.window.map(u64::from);
            if x1 <= x0 || y1 <= y0 {
                continue;
            }
            // Tiles whose samples (tile x covers samples x·T ..= x·T + T) meet the window.
            let tx0 = x0.saturating_sub(1) / t;
            let ty0 = y0.saturating_sub(1) / t;
            let tx1 = ((x1 - 1) / t).min(n - 1);
            let ty1 = ((y1 - 1) / t).min(n - 1);
            for ty in ty0..=ty1 {
                for tx in tx0..=tx1 {
                    let m = TileId::new(finest, tx as u32, ty as u32)
                        .expect("inside the level")
                        .morton()
                        .get() as usize;
                    fine[m] = fine[m].max(level);
                }
            }
        }
        // Upwards: a tile's support is its children's deepest, then balanced.
        balance(&mut fine, finest.get());
        let mut levels = vec![fine];
        for level in (0..finest.get()).rev() {
            let below = levels.last().expect("at least the finest");
            let mut up: Vec<u8> = below
                .chunks_exact(4)
                .map(|c| c.iter().copied().max().unwrap_or(0))
                .collect();
            balance(&mut up, level);
            levels.push(up);
        }
        levels.reverse();
        let floor = levels_of.iter().copied().min().unwrap_or(0);
        Some(Self { levels, floor })
    }

    /// Whether tile `(level, m)` is stored: at or above the coarsest input's level, or
    /// at most its parent's support.
    pub fn stores(&self, level: Level, m: Morton) -> bool {
        if level.get() <= self.floor {
            return true;
        }
        let parent = level.get() - 1;
        self.levels[usize::from(parent)][(m.get() >> 2) as usize] >= level.get()
    }

    /// The coarsest input's level (see [`Support::stores`]).
    pub fn floor(&self) -> u8 {
        self.floor
    }

    /// The deepest level stored over tile `(level, m)`'s area.
    pub fn at(&self, level: Level, m: Morton) -> u8 {
        self.levels[usize::from(level.get())][m.get() as usize].max(self.floor)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_input_supports_the_levels_its_spacing_keeps() {
        let f = Level::new(6).unwrap();
        assert_eq!(supported_level(90.0, 90.0, f), 6);
        assert_eq!(supported_level(90.0 * 1.000_000_1, 90.0, f), 6);
        assert_eq!(supported_level(180.0 * 0.999_999_9, 90.0, f), 5);
        assert_eq!(supported_level(179.0, 90.0, f), 6);
        assert_eq!(supported_level(180.0, 90.0, f), 5);
        // 10× coarser: 8× keeps it (3 levels up), 16× would not.
        assert_eq!(supported_level(900.0, 90.0, f), 3);
        assert_eq!(supported_level(1e9, 90.0, f), 0);
        assert_eq!(supported_level(30.0, 90.0, f), 6);
    }

    /// A 1024² pyramid (tiles of 64: finest level 4) with a coarse base over all of it
    /// (16× coarser: level 0) and a fine patch over samples 100..300 × 600..700.
    #[test]
    fn deep_tiles_only_where_fine_data_is_and_siblings_together() {
        let g = TileGeometry::new(1025, 1025, 64).unwrap();
        let base = Coverage {
            window: [0, 0, 1025, 1025],
            metres: 16.0 * 30.0,
        };
        let patch = Coverage {
            window: [100, 600, 300, 700],
            metres: 30.0,
        };
        let s = Support::new(&g, &[base, patch], 30.0).unwrap();
        assert_eq!(s.floor(), 0);
        let stored = |l: u8| {
            let level = Level::new(l).unwrap();
            g.present_tiles(level)
                .filter(|t| s.stores(level, t.morton()))
                .map(|t| (t.x(), t.y()))
                .collect::<Vec<_>>()
        };
        assert_eq!(stored(0), [(0, 0)]);
        assert_eq!(stored(1).len(), 4, "the root's children, all four");
        // The patch's finest tiles: x 1..=4 (samples 64..320), y 9..=10 (576..704),
        // and, with their siblings, x 0..=5, y 8..=11.
        let finest = stored(4);
        for x in 1..=4 {
            for y in 9..=10 {
                assert!(finest.contains(&(x, y)), "({x}, {y}) {finest:?}");
            }
        }
        assert!(
            finest.iter().all(|&(x, y)| x <= 5 && (8..=11).contains(&y)),
            "{finest:?}"
        );
        // Far from the patch, nothing below level 2.
        assert!(!stored(3).contains(&(7, 0)));
        assert!(!stored(4).contains(&(15, 15)));
        // Every stored tile's parent is stored.
        for l in 1..=4u8 {
            let level = Level::new(l).unwrap();
            for t in g
                .present_tiles(level)
                .filter(|t| s.stores(level, t.morton()))
            {
                let p = t.parent().unwrap();
                assert!(s.stores(p.level(), p.morton()), "{t} stored, {p} not");
            }
        }
        // Restricted: beside every stored tile, the area of each edge neighbour is
        // stored one level up or finer (the client can keep drawn neighbours within
        // one level without coarsening the patch).
        for l in 2..=4u8 {
            let level = Level::new(l).unwrap();
            for t in g
                .present_tiles(level)
                .filter(|t| s.stores(level, t.morton()))
            {
                for (dx, dy) in [(0i64, -1i64), (1, 0), (0, 1), (-1, 0)] {
                    let (x, y) = (i64::from(t.x()) + dx, i64::from(t.y()) + dy);
                    let Some(n) = u32::try_from(x)
                        .ok()
                        .zip(u32::try_from(y).ok())
                        .and_then(|(x, y)| TileId::new(level, x, y))
                    else {
                        continue;
                    };
                    let p = n.parent().unwrap();
                    assert!(s.stores(p.level(), p.morton()), "{t} stored, {p} not");
                }
            }
        }
        // Without balancing, the fine patch's level-4 tiles would sit beside level-1
        // ground: level 2 is stored a tile beyond the patch's level-2 footprint.
        assert!(stored(2).contains(&(2, 2)), "{:?}", stored(2));
        // One resolution everywhere: no support map at all.
        assert!(Support::new(&g, &[patch], 30.0).is_none());
    }
}
