//! GPU slots: a fixed number of texture-array layers holding resident tiles,
//! least-recently-used out, the root level pinned (DESIGN §5).
//!
//! Selection only draws tiles that have a slot ([`OnGpu`]), so a tile that has
//! been decoded but not yet uploaded is drawn through its ancestor, never as a hole.

use crate::select::TileTables;
use crate::stream::pool::TilePool;
use std::collections::HashMap;
use tessera_shared::{ErrorTable, TileId};

#[derive(Debug)]
struct Entry {
    slot: u32,
    last_used: u64,
}

#[derive(Debug)]
pub struct SlotTable {
    tiles: HashMap<TileId, Entry>,
    free: Vec<u32>,
    clock: u64,
    pub evictions: u64,
}

impl SlotTable {
    /// `capacity` slots, numbered `0..capacity`.
    pub fn new(capacity: u32) -> Self {
        Self {
            tiles: HashMap::new(),
            free: (0..capacity).rev().collect(),
            clock: 1,
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
        self.tiles.get(&tile).map(|e| e.slot)
    }

    /// Marks the tiles drawn this frame, and their ancestors, as used now; starts
    /// a new frame.
    pub fn touch(&mut self, tiles: &[TileId]) {
        self.clock += 1;
        for t in tiles {
            let mut cur = Some(*t);
            while let Some(c) = cur {
                if let Some(e) = self.tiles.get_mut(&c) {
                    e.last_used = self.clock;
                }
                cur = c.parent();
            }
        }
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
            let (&victim, _) = self
                .tiles
                .iter()
                .filter(|(t, e)| t.level().get() > 0 && e.last_used < self.clock)
                .min_by_key(|(t, e)| (e.last_used, std::cmp::Reverse(t.level().get())))?;
            self.evictions += 1;
            self.tiles.remove(&victim)?.slot
        };
        self.tiles.insert(
            tile,
            Entry {
                slot,
                last_used: self.clock,
            },
        );
        Some(slot)
    }

    /// Forgets a tile (its slot becomes free).
    pub fn release(&mut self, tile: TileId) {
        if let Some(e) = self.tiles.remove(&tile) {
            self.free.push(e.slot);
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
