//! The CPU tile pool: a fixed number of decoded tiles, least-recently-used out,
//! the root level pinned so there is always an ancestor to draw (DESIGN §5).

use crate::select::{TileTables, World};
use std::collections::HashMap;
use tessera_shared::{ErrorTable, TileId};

#[derive(Debug)]
pub struct Resident {
    pub errors: ErrorTable,
    pub heights: Vec<u16>,
    last_used: u64,
}

#[derive(Debug)]
pub struct TilePool {
    tiles: HashMap<TileId, Resident>,
    capacity: usize,
    clock: u64,
    pub evictions: u64,
}

impl TilePool {
    /// A pool of at most `capacity` tiles (at least the root and its children).
    pub fn new(capacity: usize) -> Self {
        Self {
            tiles: HashMap::new(),
            capacity: capacity.max(5),
            clock: 0,
            evictions: 0,
        }
    }

    pub fn len(&self) -> usize {
        self.tiles.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tiles.is_empty()
    }

    pub fn contains(&self, tile: TileId) -> bool {
        self.tiles.contains_key(&tile)
    }

    pub fn get(&self, tile: TileId) -> Option<&Resident> {
        self.tiles.get(&tile)
    }

    /// Marks tiles as used now (the ones drawn this frame).
    pub fn touch(&mut self, tiles: &[TileId]) {
        self.clock += 1;
        for t in tiles {
            // Ancestors are used too: selection walks through them.
            let mut cur = Some(*t);
            while let Some(c) = cur {
                if let Some(r) = self.tiles.get_mut(&c) {
                    r.last_used = self.clock;
                }
                cur = c.parent();
            }
        }
    }

    /// Adds a decoded tile, evicting the least recently used tile that no resident
    /// tile depends on (no resident children) and is not on the root level.
    pub fn insert(&mut self, tile: TileId, errors: ErrorTable, heights: Vec<u16>) {
        self.tiles.insert(
            tile,
            Resident {
                errors,
                heights,
                last_used: self.clock,
            },
        );
        while self.tiles.len() > self.capacity {
            let victim = self
                .tiles
                .iter()
                .filter(|(t, _)| t.level().get() > 0 && **t != tile)
                .filter(|(t, _)| {
                    t.children()
                        .is_none_or(|c| c.iter().all(|c| !self.tiles.contains_key(c)))
                })
                .min_by_key(|(t, r)| (r.last_used, std::cmp::Reverse(t.level())))
                .map(|(t, _)| *t);
            match victim {
                Some(v) => {
                    self.tiles.remove(&v);
                    self.evictions += 1;
                }
                None => break,
            }
        }
    }

    /// Height in metres under world point `(x, z)`, from the finest resident tile there.
    pub fn ground_height(&self, world: &World, x: f64, z: f64) -> Option<f64> {
        let g = &world.geometry;
        let (fx, fy) = ((x / world.spacing).round(), (z / world.spacing).round());
        if fx < 0.0 || fy < 0.0 {
            return None;
        }
        let (fx, fy) = (
            (fx as u64).min(u64::from(g.width() - 1)),
            (fy as u64).min(u64::from(g.height() - 1)),
        );
        for level in g.levels().rev() {
            let span = g.spacing(level) * u64::from(g.tile_size());
            let n = u64::from(level.tiles_per_side());
            let (tx, ty) = ((fx / span).min(n - 1), (fy / span).min(n - 1));
            let tile = TileId::new(level, tx as u32, ty as u32)?;
            if let Some(r) = self.tiles.get(&tile) {
                let s = g.spacing(level);
                let (gx, gy) = g.origin(tile);
                let (u, v) = (((fx - gx) / s) as usize, ((fy - gy) / s) as usize);
                return Some(world.quant.height(r.heights[v * g.tile_samples() + u]));
            }
        }
        None
    }
}

impl TileTables for TilePool {
    fn table(&self, tile: TileId) -> Option<&ErrorTable> {
        self.tiles.get(&tile).map(|r| &r.errors)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::Level;

    fn t(l: u8, x: u32, y: u32) -> TileId {
        TileId::new(Level::new(l).unwrap(), x, y).unwrap()
    }

    #[test]
    fn evicts_least_recently_used_leaves_and_never_the_root() {
        let mut p = TilePool::new(5);
        let e = || ErrorTable::empty(6);
        p.insert(t(0, 0, 0), e(), vec![]);
        for (x, y) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            p.insert(t(1, x, y), e(), vec![]);
        }
        p.touch(&[t(1, 0, 0), t(1, 1, 0), t(1, 0, 1)]);
        // Over capacity: (1,1) is the least recently used leaf.
        p.insert(t(2, 0, 0), e(), vec![]);
        assert!(p.contains(t(0, 0, 0)));
        assert!(!p.contains(t(1, 1, 1)));
        assert!(
            p.contains(t(2, 0, 0)) && p.contains(t(1, 0, 0)),
            "the new tile and its parent stay"
        );
        assert_eq!(p.len(), 5);
        assert_eq!(p.evictions, 1);
    }
}
