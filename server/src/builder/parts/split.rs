//! `--part K/N` and how `N` parts divide a pyramid: the split level, each part's run
//! of its Morton codes, and each part's share of the DEM-wide sample counts.

use super::{EXTENSION, MAX_PARTS};
use crate::ingest::raster::{DepthCounts, Raster, depth};
use anyhow::{Context, ensure};
use std::ops::Range;
use tessera_shared::{Level, Morton, TileGeometry, TileId};

/// Which part of how many (`--part K/N`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PartSpec {
    pub k: u32,
    pub n: u32,
}

impl PartSpec {
    /// Parses `K/N`, or `/N` with `K` from `index` (the `JOB_COMPLETION_INDEX` a
    /// Kubernetes Indexed Job sets in each pod). An explicit `K` wins.
    pub fn parse(spec: &str, index: Option<&str>) -> anyhow::Result<Self> {
        let (k, n) = spec
            .split_once('/')
            .with_context(|| format!("--part {spec}: expected K/N (e.g. 3/16) or /N"))?;
        let n: u32 = n
            .trim()
            .parse()
            .ok()
            .filter(|n| (1..=MAX_PARTS).contains(n))
            .with_context(|| {
                format!("--part {spec}: N must be a whole number from 1 to {MAX_PARTS}")
            })?;
        let k: u32 = if k.trim().is_empty() {
            let index = index.with_context(|| {
                format!(
                    "--part {spec} gives no K: write --part K/{n}, or set JOB_COMPLETION_INDEX \
                     (a Kubernetes Indexed Job sets it in each pod)"
                )
            })?;
            index.trim().parse().with_context(|| {
                format!("JOB_COMPLETION_INDEX={index:?} (for --part {spec}) is not a whole number")
            })?
        } else {
            k.trim()
                .parse()
                .with_context(|| format!("--part {spec}: K is not a whole number"))?
        };
        ensure!(
            k < n,
            "--part {k}/{n}: K counts from 0, so it must be below N (0 to {})",
            n - 1
        );
        Ok(Self { k, n })
    }

    /// The part's file name in the parts folder: `part-KKKK-of-NNNN.tesspart`.
    pub fn file_name(&self) -> String {
        format!("part-{:04}-of-{:04}.{EXTENSION}", self.k, self.n)
    }
}

/// How `N` parts divide a pyramid: the split level and each part's run of its
/// Morton codes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Split {
    pub level: Level,
    /// `cuts[K]..cuts[K + 1]` are part `K`'s codes; `N + 1` entries.
    cuts: Vec<u64>,
}

impl Split {
    /// The split for `n` parts: level `S` is the smallest with `4^S ≥ 4n`, clamped to
    /// `1..=finest` (0 for a one-tile pyramid); the cuts balance the present finest
    /// tiles under each part's codes (their work), a part taking whole subtrees.
    pub fn new(geometry: &TileGeometry, n: u32) -> Self {
        let finest = geometry.finest().get();
        let mut s = 1u8;
        while (1u64 << (2 * u32::from(s))) < 4 * u64::from(n) {
            s += 1;
        }
        let level = Level::new(s.min(finest)).expect("at most the finest level");
        let weights = tile_weights(geometry, level);
        let total: u64 = weights.iter().sum();
        let mut cuts = Vec::with_capacity(n as usize + 1);
        let (mut i, mut prefix) = (0usize, 0u64);
        for k in 0..u64::from(n) {
            // The first code whose prefix holds k/n of the work.
            while u128::from(prefix) * u128::from(n) < u128::from(k) * u128::from(total) {
                prefix += weights[i];
                i += 1;
            }
            cuts.push(i as u64);
        }
        cuts.push(level.tile_slots());
        Self { level, cuts }
    }

    /// Part `k`'s level-`S` Morton codes.
    pub fn tops(&self, k: u32) -> Range<u64> {
        self.cuts[k as usize]..self.cuts[k as usize + 1]
    }
}

/// Present finest tiles under each tile of `level`, in Morton order.
fn tile_weights(g: &TileGeometry, level: Level) -> Vec<u64> {
    let d = u32::from(g.finest().get() - level.get());
    let t = u64::from(g.tile_size());
    // Finest tile x is present iff x·T < W − 1.
    let (nx, ny) = (
        u64::from(g.width() - 1).div_ceil(t),
        u64::from(g.height() - 1).div_ceil(t),
    );
    let span = |i: u32, n: u64| n.min(u64::from(i + 1) << d) - n.min(u64::from(i) << d);
    (0..level.tile_slots())
        .map(|m| {
            let (x, y) = Morton::from_raw(m).decode();
            span(x, nx) * span(y, ny)
        })
        .collect()
}

/// The samples a present level-`level` tile owns: its `span × span` block of the
/// DEM from its origin, to the DEM's edge for the last tile of a row or column
/// (where the next tile would be absent). Every sample has exactly one owner.
fn owned(g: &TileGeometry, tile: TileId) -> Option<(Range<u32>, Range<u32>)> {
    if !g.is_present(tile) {
        return None;
    }
    let span = g.spacing(tile.level()) * u64::from(g.tile_size());
    let (x0, y0) = g.origin(tile);
    let end = |o: u64, size: u32| {
        if o + span >= u64::from(size - 1) {
            size
        } else {
            (o + span) as u32
        }
    };
    Some((
        x0 as u32..end(x0, g.width()),
        y0 as u32..end(y0, g.height()),
    ))
}

/// Samples per depth in `xs × ys`, all counted valid.
fn rect_depths(xs: &Range<u32>, ys: &Range<u32>) -> DepthCounts {
    // Multiples of 2^d in a range (d = 32 counts 0 alone, as depth() does).
    let on = |r: &Range<u32>, d: u32| {
        let s = 1u64 << d;
        u64::from(r.end).div_ceil(s) - u64::from(r.start).div_ceil(s)
    };
    let mut c = [[0u64; 2]; 33];
    for d in 0..33u32 {
        let here = on(xs, d) * on(ys, d);
        let deeper = if d == 32 {
            0
        } else {
            on(xs, d + 1) * on(ys, d + 1)
        };
        c[d as usize][0] = here - deeper;
    }
    c
}

/// Samples of a row whose validity is read at once.
const VALIDITY_CHUNK: u32 = 1 << 16;

/// A part's share of the DEM's depth counts ([`Raster::depth_counts`]): the
/// samples its level-`level` tiles `tops` own, valid and filled. The parts' shares
/// add up to the whole raster's counts.
pub(super) fn share(
    raster: &dyn Raster,
    g: &TileGeometry,
    level: Level,
    tops: Range<u64>,
) -> anyhow::Result<DepthCounts> {
    let mut counts = [[0u64; 2]; 33];
    let mut valid = Vec::new();
    for m in tops {
        let tile = TileId::from_morton(level, Morton::from_raw(m)).expect("m < 4^S");
        let Some((xs, ys)) = owned(g, tile) else {
            continue;
        };
        for (c, r) in counts.iter_mut().zip(rect_depths(&xs, &ys)) {
            c[0] += r[0];
        }
        if !raster.has_nodata() {
            continue;
        }
        for y in ys.clone() {
            let mut x = xs.start;
            while x < xs.end {
                let w = VALIDITY_CHUNK.min(xs.end - x);
                valid.resize(w as usize, false);
                raster.read_validity(x, y, w, 1, &mut valid)?;
                for (i, _) in valid.iter().enumerate().filter(|(_, v)| !**v) {
                    let d = depth(x + i as u32, y);
                    counts[d][0] -= 1;
                    counts[d][1] += 1;
                }
                x += w;
            }
        }
    }
    Ok(counts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::raster::all_valid_depth_counts;

    #[test]
    fn part_specs_parse_with_and_without_the_job_index() {
        assert_eq!(
            PartSpec::parse("3/16", None).unwrap(),
            PartSpec { k: 3, n: 16 }
        );
        assert_eq!(
            PartSpec::parse("/16", Some("15")).unwrap(),
            PartSpec { k: 15, n: 16 }
        );
        // An explicit K wins over the environment.
        assert_eq!(PartSpec::parse("2/4", Some("3")).unwrap().k, 2);
        let e = PartSpec::parse("/16", None).unwrap_err().to_string();
        assert!(e.contains("JOB_COMPLETION_INDEX"), "{e}");
        assert!(PartSpec::parse("16/16", None).is_err());
        assert!(PartSpec::parse("1/0", None).is_err());
        assert!(PartSpec::parse("/4", Some("x")).is_err());
        assert!(PartSpec::parse("3", None).is_err());
        assert_eq!(
            PartSpec { k: 3, n: 16 }.file_name(),
            "part-0003-of-0016.tesspart"
        );
    }

    #[test]
    fn splits_cover_every_code_once_and_balance_the_work() {
        for (w, h, t, n) in [
            (1025, 1025, 64, 16),
            (1025, 1025, 64, 1),
            (1025, 1025, 64, 5),
            (1201, 700, 64, 4),
            (3000, 200, 64, 7),
            (65, 65, 64, 4),
            (100, 100, 128, 3),
        ] {
            let g = TileGeometry::new(w, h, t).unwrap();
            let s = Split::new(&g, n);
            let wts = tile_weights(&g, s.level);
            assert!(s.level.get() >= 1.min(g.finest().get()));
            assert!(s.level <= g.finest());
            assert_eq!(s.tops(0).start, 0);
            assert_eq!(s.tops(n - 1).end, s.level.tile_slots());
            for k in 1..n {
                assert_eq!(s.tops(k - 1).end, s.tops(k).start);
            }
            let total: u64 = wts.iter().sum();
            assert_eq!(total, g.present_tiles(g.finest()).count() as u64, "{w}×{h}");
            // No part holds more than its share plus one subtree's work.
            let biggest = *wts.iter().max().unwrap();
            for k in 0..n {
                let r = s.tops(k);
                let work: u64 = wts[r.start as usize..r.end as usize].iter().sum();
                assert!(
                    work <= total.div_ceil(u64::from(n)) + biggest,
                    "{w}×{h}/{n}: part {k} has {work} of {total}"
                );
            }
        }
    }

    #[test]
    fn shares_of_the_counts_add_up_to_the_whole() {
        for (w, h, t, n) in [
            (1025, 1025, 64, 16),
            (1201, 700, 64, 4),
            (130, 67, 64, 3),
            (129, 129, 64, 2),
        ] {
            let g = TileGeometry::new(w, h, t).unwrap();
            let split = Split::new(&g, n);
            let mut sum = [[0u64; 2]; 33];
            for k in 0..n {
                for m in split.tops(k) {
                    let tile = TileId::from_morton(split.level, Morton::from_raw(m)).unwrap();
                    if let Some((xs, ys)) = owned(&g, tile) {
                        for (s, r) in sum.iter_mut().zip(rect_depths(&xs, &ys)) {
                            s[0] += r[0];
                        }
                    }
                }
            }
            assert_eq!(sum, all_valid_depth_counts(w, h), "{w}×{h}");
        }
        // A rectangle away from the origin, against counting sample by sample.
        let (xs, ys) = (5..77, 64..130);
        let mut brute = [[0u64; 2]; 33];
        for y in ys.clone() {
            for x in xs.clone() {
                brute[depth(x, y)][0] += 1;
            }
        }
        assert_eq!(rect_depths(&xs, &ys), brute);
    }
}
