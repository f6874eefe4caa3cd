//! What an update must redo (DECISIONS.md "Updates"): the changed area from the old
//! and new input lists, the finest tiles whose samples it holds, and the finest tiles
//! to measure again because a coarse cell around them has a corner in it.

use super::state::InputRecord;
use std::collections::HashMap;
use tessera_shared::{Level, TileGeometry, TileId};

/// Rectangles of samples `[x0, y0, x1, y1)` whose samples may differ: the old and new
/// windows of every input added, removed or changed.
pub(super) fn changed_area(
    old: &[InputRecord],
    new: &[InputRecord],
    resampled: bool,
) -> Vec<[u32; 4]> {
    let margin = if resampled { 2 } else { 0 };
    let rect = |[x, y, w, h]: [u32; 4]| {
        [
            x.saturating_sub(margin),
            y.saturating_sub(margin),
            x + w + margin,
            y + h + margin,
        ]
    };
    let before: HashMap<&str, &InputRecord> = old.iter().map(|r| (r.path.as_str(), r)).collect();
    let after: HashMap<&str, &InputRecord> = new.iter().map(|r| (r.path.as_str(), r)).collect();
    let mut out = Vec::new();
    for r in new {
        match before.get(r.path.as_str()) {
            Some(o) if *o == r => {}
            Some(o) => {
                out.push(rect(o.window));
                out.push(rect(r.window));
            }
            None => out.push(rect(r.window)),
        }
    }
    for r in old {
        if !after.contains_key(r.path.as_str()) {
            out.push(rect(r.window));
        }
    }
    out
}

/// Morton codes (sorted) of the present finest tiles whose closed footprint `[x0, x0 +
/// T] × [y0, y0 + T]` meets a changed rectangle.
pub(super) fn changed_tiles(g: &TileGeometry, area: &[[u32; 4]]) -> Vec<u64> {
    let t = g.tile_size();
    let finest = g.finest();
    let side = 1u32 << finest.get();
    let mut codes = Vec::new();
    for &[x0, y0, x1, y1] in area {
        let (x1, y1) = (x1.min(g.width()), y1.min(g.height()));
        if x0 >= x1 || y0 >= y1 {
            continue;
        }
        let span = |a: u32, b: u32| (a.saturating_sub(t).div_ceil(t))..=((b - 1) / t).min(side - 1);
        for ty in span(y0, y1) {
            for tx in span(x0, x1) {
                let tile = TileId::new(finest, tx, ty).expect("inside the level");
                if g.is_present(tile) {
                    codes.push(tile.morton().get());
                }
            }
        }
    }
    codes.sort_unstable();
    codes.dedup();
    codes
}

/// The finest tiles to measure again, as sorted disjoint Morton ranges: the changed
/// ones, and every tile inside a coarse cell (spacing `2T … 2^(t + L)`) with a corner
/// in the changed area: a tile's errors against such a cell feed its ancestors, and
/// the cell's corner moved. (A cell of spacing `2^k` aligned on its lattice is one
/// tile of level `L − (k − t)`.)
pub(super) fn dirty_ranges(
    g: &TileGeometry,
    area: &[[u32; 4]],
    changed: &[u64],
) -> Vec<std::ops::Range<u64>> {
    let t = g.tile_log2();
    let finest = u32::from(g.finest().get());
    let (w, h) = (g.width(), g.height());
    let mut ranges: Vec<std::ops::Range<u64>> = changed.iter().map(|&c| c..c + 1).collect();
    for &[x0, y0, x1, y1] in area {
        let (x1, y1) = (x1.min(w), y1.min(h));
        if x0 >= x1 || y0 >= y1 {
            continue;
        }
        for k in t + 1..=t + finest {
            let s = 1u64 << k;
            // Lattice positions whose sample (clamped to the last one, as the tiler
            // clamps corners) lies in [a, b).
            let lattice = |a: u32, b: u32, last: u32| -> Vec<u64> {
                let mut v: Vec<u64> = (u64::from(a).div_ceil(s)..=(u64::from(b) - 1) / s)
                    .map(|i| i * s)
                    .collect();
                if (a..b).contains(&last) {
                    let beyond = u64::from(last).div_ceil(s) * s;
                    v.extend([beyond, beyond + s]);
                }
                v
            };
            let level = Level::new((finest + t - k) as u8).expect("a level of the pyramid");
            let d = 2 * (k - t);
            for cy in lattice(y0, y1, h - 1) {
                for cx in lattice(x0, x1, w - 1) {
                    // The up-to-four cells with this corner.
                    for (ox, oy) in [
                        (cx, cy),
                        (cx.wrapping_sub(s), cy),
                        (cx, cy.wrapping_sub(s)),
                        (cx.wrapping_sub(s), cy.wrapping_sub(s)),
                    ] {
                        if ox >= u64::from(w) || oy >= u64::from(h) {
                            continue;
                        }
                        let Some(tile) = TileId::new(level, (ox / s) as u32, (oy / s) as u32)
                        else {
                            continue;
                        };
                        let m = tile.morton().get();
                        ranges.push(m << d..(m + 1) << d);
                    }
                }
            }
        }
    }
    ranges.sort_unstable_by_key(|r| r.start);
    let mut merged: Vec<std::ops::Range<u64>> = Vec::new();
    for r in ranges {
        match merged.last_mut() {
            Some(last) if r.start <= last.end => last.end = last.end.max(r.end),
            _ => merged.push(r),
        }
    }
    merged
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input(path: &str, size: u64, window: [u32; 4]) -> InputRecord {
        InputRecord {
            path: path.into(),
            size,
            tag: "mtime 1".into(),
            window,
        }
    }

    #[test]
    fn the_changed_area_is_what_was_added_removed_or_changed() {
        let old = [
            input("a.tif", 10, [0, 0, 100, 100]),
            input("b.tif", 10, [100, 0, 100, 100]),
            input("c.tif", 10, [0, 100, 100, 100]),
        ];
        let new = [
            input("a.tif", 10, [0, 0, 100, 100]),
            input("b.tif", 11, [100, 0, 100, 100]),
            input("d.tif", 10, [100, 100, 100, 100]),
        ];
        assert_eq!(
            changed_area(&old, &new, false),
            vec![
                [100, 0, 200, 100],
                [100, 0, 200, 100],
                [100, 100, 200, 200],
                [0, 100, 100, 200]
            ]
        );
        // Resampled inputs reach two samples past their window.
        assert_eq!(changed_area(&old[..1], &[], true), vec![[0, 0, 102, 102]]);
        assert!(changed_area(&old, &old, false).is_empty());
    }

    #[test]
    fn changed_tiles_meet_the_area_with_their_closed_footprint() {
        // 257² at tile 64: 4 × 4 finest tiles, sample 64 shared by tiles 0 and 1.
        let g = TileGeometry::new(257, 257, 64).unwrap();
        let code = |x, y| TileId::new(g.finest(), x, y).unwrap().morton().get();
        let mut want = vec![code(0, 0), code(1, 0)];
        want.sort_unstable();
        assert_eq!(changed_tiles(&g, &[[64, 0, 65, 1]]), want);
        assert_eq!(changed_tiles(&g, &[[65, 0, 127, 1]]), vec![code(1, 0)]);
        // Beyond the DEM: clipped.
        assert_eq!(changed_tiles(&g, &[[256, 256, 400, 400]]), vec![code(3, 3)]);
    }

    #[test]
    fn tiles_under_a_changed_coarse_corner_are_dirty() {
        // 257² at tile 64 (L = 2): the sample (128, 128) is a corner of the four
        // level-1 cells (spacing 128) and of nothing coarser but the root's clamp.
        let g = TileGeometry::new(257, 257, 64).unwrap();
        let area = [[128, 128, 129, 129]];
        let changed = changed_tiles(&g, &area);
        assert_eq!(changed.len(), 4, "the four tiles sharing the sample");
        let dirty = dirty_ranges(&g, &area, &changed);
        // Every finest tile lies in a level-1 cell with that corner.
        assert_eq!(dirty, vec![0..16]);
        // A change in one tile's inside, off every coarse lattice: that tile only.
        let area = [[10, 10, 20, 20]];
        let changed = changed_tiles(&g, &area);
        assert_eq!(dirty_ranges(&g, &area, &changed), vec![0..1]);
    }
}
