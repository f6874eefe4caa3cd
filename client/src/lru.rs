//! The recency list the CPU tile pool ([`crate::stream::pool`]) and the GPU slots
//! (`render::slots`, with the `render` feature) share: tiles with a value each and the frame each was
//! last used in, least recently used out (docs/ARCHITECTURE.md#streaming).
//!
//! Using a tile uses its ancestors too (selection walks through them), and the root
//! level is pinned: it is never a victim, so there is always an ancestor to draw.
//! Each owner adds what else it protects through [`TileLru::victim`]'s filter.

use std::collections::HashMap;
use tessera_shared::TileId;

#[derive(Debug)]
struct Entry<V> {
    value: V,
    last_used: u64,
}

#[derive(Debug)]
pub struct TileLru<V> {
    entries: HashMap<TileId, Entry<V>>,
    /// The current frame: [`TileLru::touch`] starts a new one.
    clock: u64,
}

impl<V> Default for TileLru<V> {
    fn default() -> Self {
        Self::new()
    }
}

impl<V> TileLru<V> {
    pub fn new() -> Self {
        Self {
            entries: HashMap::new(),
            clock: 0,
        }
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    pub fn contains(&self, tile: TileId) -> bool {
        self.entries.contains_key(&tile)
    }

    pub fn get(&self, tile: TileId) -> Option<&V> {
        self.entries.get(&tile).map(|e| &e.value)
    }

    /// Adds (or replaces) `tile`, used this frame.
    pub fn insert(&mut self, tile: TileId, value: V) {
        self.entries.insert(
            tile,
            Entry {
                value,
                last_used: self.clock,
            },
        );
    }

    pub fn remove(&mut self, tile: TileId) -> Option<V> {
        self.entries.remove(&tile).map(|e| e.value)
    }

    /// Starts a new frame and marks `tiles`, and their ancestors, as used in it.
    pub fn touch(&mut self, tiles: &[TileId]) {
        self.clock += 1;
        for t in tiles {
            let mut cur = Some(*t);
            while let Some(c) = cur {
                if let Some(e) = self.entries.get_mut(&c) {
                    e.last_used = self.clock;
                }
                cur = c.parent();
            }
        }
    }

    /// Whether `tile` is held and was used (touched or inserted) this frame.
    pub fn used_this_frame(&self, tile: TileId) -> bool {
        self.entries
            .get(&tile)
            .is_some_and(|e| e.last_used >= self.clock)
    }

    /// The tile to evict: the least recently used one off the root level that
    /// `evictable` allows, the finest first among those last used in the same
    /// frame. `None` when every tile is pinned or protected.
    pub fn victim(&self, evictable: impl Fn(TileId) -> bool) -> Option<TileId> {
        self.entries
            .iter()
            .filter(|(t, _)| t.level().get() > 0 && evictable(**t))
            .min_by_key(|(t, e)| (e.last_used, std::cmp::Reverse(t.level())))
            .map(|(t, _)| *t)
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
    fn the_least_recently_used_goes_finest_first_and_never_the_root() {
        let mut lru = TileLru::new();
        lru.insert(t(0, 0, 0), 'r');
        lru.insert(t(1, 0, 0), 'a');
        lru.insert(t(2, 0, 0), 'b');
        lru.insert(t(1, 1, 0), 'c');
        assert!(lru.used_this_frame(t(1, 1, 0)));
        // All inserted in one frame: the finest goes first.
        assert_eq!(lru.victim(|_| true), Some(t(2, 0, 0)));
        // Touching a tile uses its ancestors: (1,1) is now the oldest.
        lru.touch(&[t(2, 0, 0)]);
        assert!(lru.used_this_frame(t(1, 0, 0)) && !lru.used_this_frame(t(1, 1, 0)));
        assert_eq!(lru.victim(|_| true), Some(t(1, 1, 0)));
        // The filter protects; the root level is never offered.
        assert_eq!(lru.victim(|x| x.level().get() == 2), Some(t(2, 0, 0)));
        assert_eq!(lru.victim(|x| x.level().get() == 0), None);
        assert_eq!(lru.remove(t(1, 1, 0)), Some('c'));
        assert_eq!((lru.len(), lru.get(t(1, 1, 0))), (3, None));
    }
}
