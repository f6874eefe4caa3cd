//! Edge LODs (Kang §4.3), across patch, tile and pyramid-level boundaries.
//!
//! Every patch is a dyadic square of the global finest grid (side `S = 2^s`,
//! origin a multiple of `S`), whatever its tile and level, so neighbours are found
//! with one hash map over `(s, x/S, y/S)`. A patch side is shared either with one
//! patch at least as large, or with several smaller ones. Along each such *group*
//! the vertices must be evenly spaced at one spacing `D` (in finest samples):
//!
//! - `D` is the coarsest inner spacing `S/n` of the patches in the group (Kang's
//!   "minimum LOD that satisfies the conditions"), so every edge LOD `S/D` is at
//!   most its patch's inner LOD — what the vertex shader's snapping needs;
//! - `D` must divide every side in the group (Kang's "distributable"): `D ≤ S_min`.
//!   When a patch is coarser than that, its inner LOD is raised (more triangles,
//!   never more error) and the groups are re-checked until nothing changes.
//!
//! Every vertex on a shared side then sits at a multiple of `D` from a common
//! corner, and `D` is a multiple of both levels' sample spacings, so both sides
//! read the same DEM sample there: identical positions, bit for bit
//! (docs/ARCHITECTURE.md#crack-free-edges).

use super::patch::{EAST, NORTH, Patch, SOUTH, WEST};
use super::world::World;
use std::collections::HashMap;

type Key = (u32, u64, u64);

struct Index {
    map: HashMap<Key, usize>,
    min_log: u32,
    max_log: u32,
}

/// Global `(log2 S, x0, y0)` of a patch, in finest samples.
pub(super) fn global(world: &World, p: &Patch) -> (u32, u64, u64) {
    let spacing = world.geometry.spacing(p.tile.level());
    let (gx, gy) = world.geometry.origin(p.tile);
    let size = u64::from(p.size) * spacing;
    (
        size.trailing_zeros(),
        gx + u64::from(p.origin[0]) * spacing,
        gy + u64::from(p.origin[1]) * spacing,
    )
}

impl Index {
    fn new(world: &World, patches: &[Patch]) -> Self {
        let mut map = HashMap::with_capacity(patches.len());
        let (mut min_log, mut max_log) = (u32::MAX, 0);
        for (i, p) in patches.iter().enumerate() {
            let (s, x, y) = global(world, p);
            map.insert((s, x >> s, y >> s), i);
            min_log = min_log.min(s);
            max_log = max_log.max(s);
        }
        Self {
            map,
            min_log,
            max_log,
        }
    }

    /// Patches across `side` of the patch at `(s, x0, y0)`.
    fn neighbours(&self, (s, x0, y0): (u32, u64, u64), side: usize, out: &mut Vec<usize>) {
        out.clear();
        let (ix, iy) = (x0 >> s, y0 >> s);
        let cell = match side {
            NORTH if iy > 0 => (ix, iy - 1),
            EAST => (ix + 1, iy),
            SOUTH => (ix, iy + 1),
            WEST if ix > 0 => (ix - 1, iy),
            _ => return,
        };
        if let Some(&i) = self.map.get(&(s, cell.0, cell.1)) {
            out.push(i);
            return;
        }
        for j in 1..=self.max_log.saturating_sub(s) {
            if let Some(&i) = self.map.get(&(s + j, cell.0 >> j, cell.1 >> j)) {
                out.push(i);
                return;
            }
        }
        self.descend(s, cell, side, out);
    }

    /// Smaller patches inside cell `(s, c)` along the edge facing `side`'s opposite.
    fn descend(&self, s: u32, (cx, cy): (u64, u64), side: usize, out: &mut Vec<usize>) {
        if s <= self.min_log {
            return;
        }
        let (x, y) = (cx * 2, cy * 2);
        // The half of the cell that touches the patch we came from.
        let kids = match side {
            NORTH => [(x, y + 1), (x + 1, y + 1)],
            EAST => [(x, y), (x, y + 1)],
            SOUTH => [(x, y), (x + 1, y)],
            _ => [(x + 1, y), (x + 1, y + 1)],
        };
        for c in kids {
            match self.map.get(&(s - 1, c.0, c.1)) {
                Some(&i) => out.push(i),
                None => self.descend(s - 1, c, side, out),
            }
        }
    }
}

const fn opposite(side: usize) -> usize {
    (side + 2) % 4
}

/// Sets every patch's edge LODs (raising inner LODs where a shared edge needs it).
pub fn assign(world: &World, patches: &mut [Patch]) {
    if patches.is_empty() {
        return;
    }
    let index = Index::new(world, patches);
    let keys: Vec<(u32, u64, u64)> = patches.iter().map(|p| global(world, p)).collect();
    let size = |i: usize| 1u64 << keys[i].0;
    let mut nb = Vec::new();
    // Groups are led by their largest patch (either one when equal in size).
    let leads = |i: usize, nb: &[usize]| !nb.is_empty() && nb.iter().all(|&j| size(j) <= size(i));
    for _ in 0..64 {
        let mut changed = false;
        for (i, &key) in keys.iter().enumerate() {
            for side in 0..4 {
                index.neighbours(key, side, &mut nb);
                if !leads(i, &nb) {
                    continue;
                }
                let smallest = nb
                    .iter()
                    .map(|&j| size(j))
                    .min()
                    .unwrap_or(size(i))
                    .min(size(i));
                for &j in nb.iter().chain(std::iter::once(&i)) {
                    let spacing = size(j) / u64::from(patches[j].inner);
                    if spacing > smallest {
                        let n = (size(j) / smallest) as u32;
                        debug_assert!(n <= 64, "balanced tiles keep edges within 64 (got {n})");
                        patches[j].inner = n.min(64);
                        changed = true;
                    }
                }
            }
        }
        if !changed {
            break;
        }
    }
    for p in patches.iter_mut() {
        p.edges = [p.inner; 4];
    }
    for (i, &key) in keys.iter().enumerate() {
        for side in 0..4 {
            index.neighbours(key, side, &mut nb);
            if !leads(i, &nb) {
                continue;
            }
            let d = nb
                .iter()
                .chain(std::iter::once(&i))
                .map(|&j| size(j) / u64::from(patches[j].inner))
                .max()
                .expect("the group holds i");
            patches[i].edges[side] = (size(i) / d) as u32;
            for &j in &nb {
                patches[j].edges[opposite(side)] = (size(j) / d) as u32;
            }
        }
    }
}

/// Calls `f` once for every shared side group (at least once; twice when two
/// equal patches lead it): the members as `(patch, side)`, and every patch's side
/// in finest samples. The groups are those [`assign`] gave one spacing each.
pub fn for_each_group(
    world: &World,
    patches: &mut [Patch],
    mut f: impl FnMut(&mut [Patch], &[(usize, usize)], &[u64]),
) {
    if patches.is_empty() {
        return;
    }
    let index = Index::new(world, patches);
    let keys: Vec<(u32, u64, u64)> = patches.iter().map(|p| global(world, p)).collect();
    let sizes: Vec<u64> = keys.iter().map(|k| 1u64 << k.0).collect();
    let mut nb = Vec::new();
    let mut group = Vec::new();
    for (i, &key) in keys.iter().enumerate() {
        for side in 0..4 {
            index.neighbours(key, side, &mut nb);
            if nb.is_empty() || nb.iter().any(|&j| sizes[j] > sizes[i]) {
                continue;
            }
            group.clear();
            group.push((i, side));
            group.extend(nb.iter().map(|&j| (j, opposite(side))));
            f(patches, &group, &sizes);
        }
    }
}
