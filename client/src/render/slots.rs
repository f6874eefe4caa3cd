//! GPU slots: a fixed number of texture-array layers holding resident tiles,
//! least-recently-used out, the root level pinned (docs/ARCHITECTURE.md#rendering,
//! [`crate::lru`]).
//!
//! Selection only draws tiles that have a slot ([`OnGpu`]), so a tile that has
//! been decoded but not yet uploaded is drawn through its ancestor, never as a hole.

use crate::lru::TileLru;
use crate::select::TileTables;
use crate::stream::pool::TilePool;
use tessera_shared::{ErrorTable, TileId};

#[derive(Debug)]
pub struct SlotTable {
    /// Each resident tile's slot.
    tiles: TileLru<u32>,
    free: Vec<u32>,
    pub evictions: u64,
}

impl SlotTable {
    /// `capacity` slots, numbered `0..capacity`.
    pub fn new(capacity: u32) -> Self {
        Self {
            tiles: TileLru::new(),
            free: (0..capacity).rev().collect(),
            evictions: 0,
        }
    }

    pub fn len(&self) -> usize {
        self.tiles.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tiles.is_empty()
    }

    pub fn get(&self, tile: TileId) -> Option<u32> {
        self.tiles.get(tile).copied()
    }

    /// Marks the tiles drawn this frame, and their ancestors, as used now; starts
    /// a new frame.
    pub fn touch(&mut self, tiles: &[TileId]) {
        self.tiles.touch(tiles);
    }

    /// A slot for `tile`: a free one, else the least recently used one not used
    /// this frame and not on the root level. `None` when every slot is in use.
    pub fn allocate(&mut self, tile: TileId) -> Option<u32> {
        if let Some(s) = self.get(tile) {
            return Some(s);
        }
        let slot = if let Some(s) = self.free.pop() {
            s
        } else {
            let victim = self.tiles.victim(|t| !self.tiles.used_this_frame(t))?;
            self.evictions += 1;
            self.tiles.remove(victim)?
        };
        self.tiles.insert(tile, slot);
        Some(slot)
    }

    /// Forgets a tile (its slot becomes free).
    pub fn release(&mut self, tile: TileId) {
        if let Some(slot) = self.tiles.remove(tile) {
            self.free.push(slot);
        }
    }
}

/// The tiles selection may draw when rendering: decoded *and* uploaded.
#[derive(Debug)]
pub struct OnGpu<'a> {
    pub pool: &'a TilePool,
    pub slots: &'a SlotTable,
}

impl TileTables for OnGpu<'_> {
    fn table(&self, tile: TileId) -> Option<&ErrorTable> {
        self.slots.get(tile)?;
        self.pool.table(tile)
    }

    fn unavailable(&self, tile: TileId) -> bool {
        self.pool.unavailable(tile)
    }

    fn absent(&self, tile: TileId) -> bool {
        self.pool.absent(tile)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::Level;

    fn tile(level: u8, x: u32, y: u32) -> TileId {
        TileId::new(Level::new(level).unwrap(), x, y).unwrap()
    }

    #[test]
    fn evicts_the_least_recently_used_and_never_the_root_or_this_frame() {
        let mut s = SlotTable::new(3);
        let root = tile(0, 0, 0);
        let (a, b, c) = (tile(1, 0, 0), tile(1, 1, 0), tile(1, 0, 1));
        assert_eq!(s.allocate(root), Some(0));
        assert_eq!(s.allocate(a), Some(1));
        assert_eq!(s.allocate(b), Some(2));
        // All three were allocated this frame: nothing can go.
        assert_eq!(s.allocate(c), None);
        s.touch(&[a]);
        // b was not used this frame: it goes, not the pinned root, not a.
        assert_eq!(s.allocate(c), Some(2));
        assert_eq!(s.get(b), None);
        assert_eq!(s.get(root), Some(0));
        assert_eq!(s.evictions, 1);
        // Touching a child keeps its ancestors: next frame a (touched via its
        // child's ancestry) outlives c.
        s.touch(&[tile(2, 0, 0)]);
        assert_eq!(s.allocate(b), Some(2));
        assert_eq!(s.get(c), None);
        assert_eq!(s.get(a), Some(1));
        s.release(a);
        assert_eq!(s.allocate(c), Some(1));
    }
}
