//! The CPU tile pool: a fixed number of decoded tiles, least-recently-used out,
//! the root level pinned so there is always an ancestor to draw
//! (docs/ARCHITECTURE.md#streaming, [`crate::lru`]).
//!
//! It also knows which tiles cannot be had for now (their fetch failed, or their
//! record was written off as corrupt; the streamer says so): the selection draws
//! their children instead, and those children are pinned as the root is, since
//! they stand in for it (docs/ARCHITECTURE.md#the-client-never-goes-blind).
//!
//! And it remembers which tiles are absent: inside the DEM by the geometry but
//! without a record, because they hold no terrain cell (format v2; the tile stream's
//! trailer lists them among its outside ranges). Nothing is drawn or asked for
//! there again, and selection refines their parents into the siblings that exist.

use crate::lru::TileLru;
use crate::select::{TileTables, World};
use std::collections::HashSet;
use tessera_shared::{CellMask, ErrorTable, TileId};

#[derive(Debug)]
pub struct Resident {
    pub errors: ErrorTable,
    pub heights: Vec<u16>,
    /// Which of the tile's cells are terrain (the renderer draws only those).
    pub mask: CellMask,
}

#[derive(Debug)]
pub struct TilePool {
    tiles: TileLru<Resident>,
    capacity: usize,
    pub evictions: u64,
    /// Tiles that are not resident and cannot be had for now.
    unavailable: HashSet<TileId>,
    /// Tiles known to have no record (no terrain): never resident, never wanted.
    absent: HashSet<TileId>,
}

impl TilePool {
    /// A pool of at most `capacity` tiles (at least the root and its children).
    pub fn new(capacity: usize) -> Self {
        Self {
            tiles: TileLru::new(),
            capacity: capacity.max(5),
            evictions: 0,
            unavailable: HashSet::new(),
            absent: HashSet::new(),
        }
    }

    pub fn len(&self) -> usize {
        self.tiles.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tiles.is_empty()
    }

    pub fn contains(&self, tile: TileId) -> bool {
        self.tiles.contains(tile)
    }

    pub fn get(&self, tile: TileId) -> Option<&Resident> {
        self.tiles.get(tile)
    }

    /// Records that `tile` cannot be had for now (until it is inserted).
    pub fn mark_unavailable(&mut self, tile: TileId) {
        if !self.tiles.contains(tile) {
            self.unavailable.insert(tile);
        }
    }

    /// Whether `tile` is known not to be available now ([`TileTables::unavailable`]).
    pub fn is_unavailable(&self, tile: TileId) -> bool {
        self.unavailable.contains(&tile)
    }

    /// Records that `tile` has no record: it holds no terrain cell (the server
    /// listed it among a tile stream's outside ranges, or answered 404 for it).
    pub fn mark_absent(&mut self, tile: TileId) {
        if !self.tiles.contains(tile) {
            self.unavailable.remove(&tile);
            self.absent.insert(tile);
        }
    }

    /// Whether `tile` is known to have no record ([`TileTables::absent`]).
    pub fn is_absent(&self, tile: TileId) -> bool {
        self.absent.contains(&tile)
    }

    /// Whether `tile` stands in for an unavailable parent at the top of what the
    /// selection can reach: its parent cannot be had and no ancestor is resident.
    /// Such tiles are pinned, as the root is.
    fn stands_in(&self, tile: TileId) -> bool {
        let Some(parent) = tile.parent() else {
            return false;
        };
        if !self.unavailable.contains(&parent) {
            return false;
        }
        let mut cur = Some(parent);
        while let Some(c) = cur {
            if self.tiles.contains(c) {
                return false;
            }
            cur = c.parent();
        }
        true
    }

    /// Marks tiles as used now (the ones drawn this frame).
    /// Their ancestors are used too: selection walks through them.
    pub fn touch(&mut self, tiles: &[TileId]) {
        self.tiles.touch(tiles);
    }

    /// Adds a decoded tile, evicting the least recently used tile that no resident
    /// tile depends on (no resident children), is not on the root level and does
    /// not stand in for an unavailable parent.
    pub fn insert(&mut self, tile: TileId, errors: ErrorTable, heights: Vec<u16>, mask: CellMask) {
        self.unavailable.remove(&tile);
        self.absent.remove(&tile);
        self.tiles.insert(
            tile,
            Resident {
                errors,
                heights,
                mask,
            },
        );
        while self.tiles.len() > self.capacity {
            let victim = self.tiles.victim(|t| {
                t != tile
                    && !self.stands_in(t)
                    && t.children()
                        .is_none_or(|c| c.iter().all(|c| !self.tiles.contains(*c)))
            });
            match victim {
                Some(v) => {
                    self.tiles.remove(v);
                    self.evictions += 1;
                }
                None => break,
            }
        }
    }

    /// Height in metres under world point `(x, z)`, from the finest resident tile there.
    pub fn ground_height(&self, world: &World, x: f64, z: f64) -> Option<f64> {
        let g = &world.geometry;
        let (fx, fy) = ((x / world.spacing.x).round(), (z / world.spacing.y).round());
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
            if let Some(r) = self.tiles.get(tile) {
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
        self.tiles.get(tile).map(|r| &r.errors)
    }

    fn unavailable(&self, tile: TileId) -> bool {
        self.is_unavailable(tile)
    }

    fn absent(&self, tile: TileId) -> bool {
        self.is_absent(tile)
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
        let m = || CellMask::all_valid(64);
        p.insert(t(0, 0, 0), e(), vec![], m());
        for (x, y) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            p.insert(t(1, x, y), e(), vec![], m());
        }
        p.touch(&[t(1, 0, 0), t(1, 1, 0), t(1, 0, 1)]);
        // Over capacity: (1,1) is the least recently used leaf.
        p.insert(t(2, 0, 0), e(), vec![], m());
        assert!(p.contains(t(0, 0, 0)));
        assert!(!p.contains(t(1, 1, 1)));
        assert!(
            p.contains(t(2, 0, 0)) && p.contains(t(1, 0, 0)),
            "the new tile and its parent stay"
        );
        assert_eq!(p.len(), 5);
        assert_eq!(p.evictions, 1);
    }

    #[test]
    fn children_standing_in_for_an_unavailable_root_are_pinned() {
        let mut p = TilePool::new(5);
        let e = || ErrorTable::empty(6);
        let m = || CellMask::all_valid(64);
        let root = t(0, 0, 0);
        p.mark_unavailable(root);
        assert!(p.unavailable(root));
        for (x, y) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            p.insert(t(1, x, y), e(), vec![], m());
        }
        p.touch(&[t(1, 0, 0), t(1, 1, 0), t(1, 0, 1)]);
        // Over capacity, but every level-1 tile stands in for the root: the only
        // tile that may go is a level-2 one, and the new one stays.
        p.insert(t(2, 0, 0), e(), vec![], m());
        p.insert(t(2, 1, 0), e(), vec![], m());
        assert!((0..2).all(|x| (0..2).all(|y| p.contains(t(1, x, y)))));
        assert!(p.contains(t(2, 1, 0)) && !p.contains(t(2, 0, 0)));
        // Once the root arrives it is available again and pins only its own level:
        // over capacity, the least recently used leaf of level 1 goes.
        p.insert(root, e(), vec![], m());
        assert!(!p.unavailable(root));
        assert!(p.contains(root) && !p.contains(t(1, 1, 1)));
    }
}
