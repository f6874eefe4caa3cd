//! A bounded cache of fixed-size blocks of objects, shared by every dataset a
//! server reads from object storage, with its hit and miss counts.
//!
//! Reads are cut into aligned blocks of [`BLOCK`] bytes; the missing blocks of a read
//! are fetched as maximal runs of adjacent blocks, one ranged GET per run, so a
//! cold Morton range (one contiguous byte range, FORMAT.md) costs one GET, and
//! overlapping or repeated reads cost none.

use bytes::{Bytes, BytesMut};
use std::ops::Range;
use std::sync::atomic::{AtomicU64, Ordering};

/// Block size: big enough that a range of tile records is a handful of blocks, small
/// enough that the cache holds the hot spots of many datasets.
pub const BLOCK: u64 = 128 << 10;

/// Which object's block: `object` is unique per opened object (a reload or a
/// changed object gets a new one, and its old blocks age out).
type Key = (u64, u64);

#[derive(Clone)]
struct ByLength;

impl quick_cache::Weighter<Key, Bytes> for ByLength {
    fn weight(&self, _: &Key, v: &Bytes) -> u64 {
        v.len() as u64
    }
}

/// The cache; `capacity` 0 disables it (every read goes to the store).
pub struct BlockCache {
    blocks: Option<quick_cache::sync::Cache<Key, Bytes, ByLength>>,
    capacity: u64,
    next_object: AtomicU64,
}

impl std::fmt::Debug for BlockCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BlockCache")
            .field("capacity", &self.capacity)
            .field("bytes", &self.bytes())
            .finish_non_exhaustive()
    }
}

/// How a read splits between the cache and the store.
#[derive(Debug, PartialEq, Eq)]
pub struct Plan {
    /// Blocks found in the cache, by index.
    pub cached: Vec<(u64, Bytes)>,
    /// Byte ranges to fetch: maximal runs of missing blocks, clipped to the object.
    pub fetch: Vec<Range<u64>>,
}

impl BlockCache {
    pub fn new(capacity: u64) -> Self {
        let blocks = (capacity >= BLOCK).then(|| {
            let items = (capacity / BLOCK).max(1) as usize;
            quick_cache::sync::Cache::with_weighter(items, capacity, ByLength)
        });
        Self {
            blocks,
            capacity,
            next_object: AtomicU64::new(1),
        }
    }

    /// A fresh id for an opened object.
    pub fn object_id(&self) -> u64 {
        self.next_object.fetch_add(1, Ordering::Relaxed)
    }

    /// Bytes held now.
    pub fn bytes(&self) -> u64 {
        self.blocks
            .as_ref()
            .map_or(0, quick_cache::sync::Cache::weight)
    }

    pub fn capacity(&self) -> u64 {
        self.capacity
    }

    /// What reading `range` of an object of `size` bytes needs from the store.
    pub fn plan(&self, object: u64, size: u64, range: &Range<u64>) -> Plan {
        let mut plan = Plan {
            cached: Vec::new(),
            fetch: Vec::new(),
        };
        if range.start >= range.end {
            return plan;
        }
        let Some(blocks) = &self.blocks else {
            plan.fetch.push(range.clone());
            return plan;
        };
        let (first, last) = (range.start / BLOCK, (range.end - 1) / BLOCK);
        let mut run: Option<(u64, u64)> = None;
        for b in first..=last {
            if let Some(bytes) = blocks.get(&(object, b)) {
                if let Some((a, z)) = run.take() {
                    plan.fetch.push(a * BLOCK..((z + 1) * BLOCK).min(size));
                }
                plan.cached.push((b, bytes));
            } else {
                run = Some(run.map_or((b, b), |(a, _)| (a, b)));
            }
        }
        if let Some((a, z)) = run {
            plan.fetch.push(a * BLOCK..((z + 1) * BLOCK).min(size));
        }
        plan
    }

    /// Keeps the whole blocks of `bytes`, fetched at `at` (block-aligned).
    pub fn insert(&self, object: u64, at: u64, bytes: &Bytes) {
        let Some(blocks) = &self.blocks else { return };
        debug_assert_eq!(at % BLOCK, 0);
        let mut off = 0usize;
        while off < bytes.len() {
            let end = (off + BLOCK as usize).min(bytes.len());
            blocks.insert((object, (at + off as u64) / BLOCK), bytes.slice(off..end));
            off = end;
        }
    }
}

/// Assembles `range` from pieces `(start, bytes)` that together cover it (cached
/// blocks and fetched runs, in any order). Zero-copy when one piece covers it.
pub fn assemble(range: &Range<u64>, mut pieces: Vec<(u64, Bytes)>) -> Option<Bytes> {
    pieces.sort_by_key(|(at, _)| *at);
    let len = usize::try_from(range.end - range.start).ok()?;
    if let Some((at, b)) = pieces
        .iter()
        .find(|(at, b)| *at <= range.start && at + b.len() as u64 >= range.end)
    {
        let from = (range.start - at) as usize;
        return Some(b.slice(from..from + len));
    }
    let mut out = BytesMut::with_capacity(len);
    let mut pos = range.start;
    for (at, b) in pieces {
        let end = at + b.len() as u64;
        if end <= pos {
            continue;
        }
        if at > pos {
            return None;
        }
        let take_to = end.min(range.end);
        out.extend_from_slice(&b[(pos - at) as usize..(take_to - at) as usize]);
        pos = take_to;
        if pos == range.end {
            break;
        }
    }
    (pos == range.end).then(|| out.freeze())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn object(n: u64) -> Bytes {
        (0..n)
            .map(|i| (i * 7 % 251) as u8)
            .collect::<Vec<_>>()
            .into()
    }

    /// Reads through the cache from `data` as a store would, counting GETs.
    fn read(
        cache: &BlockCache,
        id: u64,
        data: &Bytes,
        range: Range<u64>,
        gets: &mut usize,
    ) -> Bytes {
        let plan = cache.plan(id, data.len() as u64, &range);
        let mut pieces: Vec<(u64, Bytes)> = plan
            .cached
            .into_iter()
            .map(|(b, bytes)| (b * BLOCK, bytes))
            .collect();
        for r in plan.fetch {
            *gets += 1;
            let got = data.slice(r.start as usize..r.end as usize);
            cache.insert(id, r.start, &got);
            pieces.push((r.start, got));
        }
        assemble(&range, pieces).expect("pieces cover the range")
    }

    #[test]
    fn a_cold_range_is_one_get_and_a_warm_one_none() {
        let data = object(10 * BLOCK + 123);
        let cache = BlockCache::new(64 * BLOCK);
        let id = cache.object_id();
        let mut gets = 0;
        let r = 3 * BLOCK - 5..7 * BLOCK + 9;
        assert_eq!(
            read(&cache, id, &data, r.clone(), &mut gets),
            data.slice(r.start as usize..r.end as usize)
        );
        assert_eq!(gets, 1);
        assert_eq!(
            read(&cache, id, &data, r.clone(), &mut gets),
            data.slice(r.start as usize..r.end as usize)
        );
        assert_eq!(gets, 1, "everything was cached");
        // A range overlapping the cached blocks on both sides: two GETs, one per gap.
        let wide = BLOCK..9 * BLOCK + 50;
        assert_eq!(
            read(&cache, id, &data, wide.clone(), &mut gets),
            data.slice(wide.start as usize..wide.end as usize)
        );
        assert_eq!(gets, 3);
        // The object's last, short block.
        let tail = 10 * BLOCK..10 * BLOCK + 123;
        assert_eq!(
            read(&cache, id, &data, tail.clone(), &mut gets),
            data.slice(tail.start as usize..tail.end as usize)
        );
        assert_eq!(
            cache.plan(id, data.len() as u64, &tail).fetch,
            Vec::<Range<u64>>::new()
        );
    }

    #[test]
    fn the_cache_stays_within_its_capacity_and_objects_do_not_mix() {
        let data = object(40 * BLOCK);
        let cache = BlockCache::new(8 * BLOCK);
        let (a, b) = (cache.object_id(), cache.object_id());
        let mut gets = 0;
        for i in 0..40 {
            read(&cache, a, &data, i * BLOCK..(i + 1) * BLOCK, &mut gets);
        }
        assert!(cache.bytes() <= 8 * BLOCK, "{} bytes held", cache.bytes());
        let before = gets;
        read(&cache, b, &data, 39 * BLOCK..40 * BLOCK, &mut gets);
        assert_eq!(gets, before + 1, "another object's block is never a hit");
    }

    #[test]
    fn a_disabled_cache_fetches_exactly_the_range() {
        let cache = BlockCache::new(0);
        let plan = cache.plan(1, 1000, &(10..20));
        assert_eq!(plan.fetch, vec![10..20]);
        assert!(plan.cached.is_empty());
    }

    #[test]
    fn assembly_refuses_a_gap() {
        let pieces = vec![
            (0, Bytes::from_static(b"abcd")),
            (6, Bytes::from_static(b"gh")),
        ];
        assert_eq!(
            assemble(&(1..4), pieces.clone()),
            Some(Bytes::from_static(b"bcd"))
        );
        assert_eq!(assemble(&(2..8), pieces), None);
    }
}
