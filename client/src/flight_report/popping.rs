//! The popping metric (DECISIONS.md "Geomorphing over time"): how much the picture jumps
//! when the selection changes, against how much it moves anyway.
//!
//! Along a slow, settled flight (everything the selection asks for is resident, so
//! only the level of detail changes the picture), each pair of consecutive frames
//! gives a per-pixel change: the absolute difference summed over R, G and B (0–765,
//! reported on the 0–255 scale of one channel, i.e. divided by 3). Pairs are split
//! by whether the selection changed between them (any drawn tile, or any patch's
//! inner or edge LOD as selection chose it; morph factors do not count, they
//! change every frame by design, and neither do the inner LODs a geomorph
//! transition raises for a while, `Selection::chosen`), and each class gets the
//! mean and the 99th percentile of its per-pixel changes. The *popping excess* is
//! the changed class's mean minus the unchanged class's: what LOD changes add to
//! the motion of the camera.
//!
//! That difference of two noisy means is small against the camera's own motion
//! wherever `τ` is small (a pop then moves the surface by about `τ` pixels), and it
//! mixes in how the motion itself varies along the flight. So each frame is also
//! drawn a second time, from the same camera, with the previous frame's patches
//! (and their morph factors): the change between the two is the pop alone, with
//! no camera motion in it (*same-camera* figures; on frames where the selection
//! did not change it is the morph's own drift, 0 without morphing).

use crate::select::Patch;
use tessera_shared::TileId;

/// A patch as far as popping goes: tile, origin, size, inner and edge LODs.
type PatchLod = (TileId, [u32; 2], u32, u32, [u32; 4]);

/// What decides the geometry a frame draws, up to morphing: compared between
/// consecutive frames.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SelectionKey {
    tiles: Vec<TileId>,
    patches: Vec<PatchLod>,
}

impl SelectionKey {
    pub fn new(tiles: &[TileId], patches: &[Patch]) -> Self {
        let mut tiles = tiles.to_vec();
        tiles.sort_unstable();
        let mut patches: Vec<_> = patches
            .iter()
            .map(|p| (p.tile, p.origin, p.size, p.inner, p.edges))
            .collect();
        patches.sort_unstable();
        Self { tiles, patches }
    }

    /// Whether two selections draw the same tiles cut into the same patches, only
    /// at other LODs (the changes morphing makes continuous; a split, a merge or a
    /// tile refinement changes the layout).
    pub fn same_layout(&self, other: &Self) -> bool {
        self.tiles == other.tiles
            && self.patches.len() == other.patches.len()
            && self
                .patches
                .iter()
                .zip(&other.patches)
                .all(|(a, b)| (a.0, a.1, a.2) == (b.0, b.1, b.2))
    }
}

/// Largest per-pixel change: 255 on each of three channels.
const MAX_CHANGE: usize = 3 * 255;

/// Per-pixel changes of a class of frame pairs, as a histogram (exact mean and
/// quantiles in constant memory, whatever the frame size and count).
#[derive(Clone, Debug)]
pub struct ChangeHistogram {
    counts: Vec<u64>,
    pairs: u32,
}

impl Default for ChangeHistogram {
    fn default() -> Self {
        Self {
            counts: vec![0; MAX_CHANGE + 1],
            pairs: 0,
        }
    }
}

/// Two frames compared pixel by pixel that are not the same size.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("frames differ in size ({before} and {after} bytes)")]
pub struct FramesDiffer {
    pub before: usize,
    pub after: usize,
}

impl ChangeHistogram {
    /// Adds the per-pixel changes between two RGBA8 frames of the same size.
    pub fn add(&mut self, before: &[u8], after: &[u8]) -> Result<(), FramesDiffer> {
        if !(before.len() == after.len() && before.len().is_multiple_of(4)) {
            return Err(FramesDiffer {
                before: before.len(),
                after: after.len(),
            });
        }
        for (p, q) in before.chunks_exact(4).zip(after.chunks_exact(4)) {
            let d: usize = (0..3).map(|c| usize::from(p[c].abs_diff(q[c]))).sum();
            self.counts[d] += 1;
        }
        self.pairs += 1;
        Ok(())
    }

    fn pixels(&self) -> u64 {
        self.counts.iter().sum()
    }

    /// Mean per-pixel change, 0–255 scale (`None` without pixels).
    pub fn mean(&self) -> Option<f64> {
        let n = self.pixels();
        (n > 0).then(|| {
            let sum: f64 = self
                .counts
                .iter()
                .enumerate()
                .map(|(d, &c)| d as f64 * c as f64)
                .sum();
            sum / n as f64 / 3.0
        })
    }

    /// The smallest change that at least `q` of the pixels do not exceed (0–255
    /// scale; `None` without pixels).
    pub fn quantile(&self, q: f64) -> Option<f64> {
        let n = self.pixels();
        if n == 0 {
            return None;
        }
        let need = (q.clamp(0.0, 1.0) * n as f64).ceil().max(1.0) as u64;
        let mut seen = 0;
        for (d, &c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= need {
                return Some(d as f64 / 3.0);
            }
        }
        Some(MAX_CHANGE as f64 / 3.0)
    }
}

/// The figures of one flight.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PoppingSummary {
    /// Frame pairs across which the selection changed, and those across which it
    /// did not.
    pub changed_pairs: u32,
    pub unchanged_pairs: u32,
    /// Mean and 99th percentile of the per-pixel change (0–255), each class.
    pub changed_mean: Option<f64>,
    pub changed_p99: Option<f64>,
    pub unchanged_mean: Option<f64>,
    pub unchanged_p99: Option<f64>,
    /// `changed_mean − unchanged_mean`: what LOD changes add.
    pub excess_mean: Option<f64>,
    /// The same camera drawn with this frame's patches and with the previous
    /// frame's: mean and p99 per-pixel change where the selection changed (the
    /// pop alone) and where it did not (the morph factors' drift).
    pub same_camera_changed_mean: Option<f64>,
    pub same_camera_changed_p99: Option<f64>,
    pub same_camera_unchanged_mean: Option<f64>,
    pub same_camera_unchanged_p99: Option<f64>,
    /// The changed pairs whose layout stayed (only inner or edge LODs changed:
    /// [`SelectionKey::same_layout`]), and their same-camera figures.
    pub lod_only_pairs: u32,
    pub same_camera_lod_only_mean: Option<f64>,
    pub same_camera_lod_only_p99: Option<f64>,
}

/// Consecutive frames of a flight, classified and measured.
#[derive(Clone, Debug, Default)]
pub struct Popping {
    last: Option<(Vec<u8>, SelectionKey)>,
    changed: ChangeHistogram,
    unchanged: ChangeHistogram,
    same_changed: ChangeHistogram,
    same_unchanged: ChangeHistogram,
    same_lod_only: ChangeHistogram,
    /// Whether the last change kept the layout.
    last_lod_only: bool,
}

impl Popping {
    /// Adds the next frame (RGBA8, the same size every frame) and what it drew.
    /// Returns whether its selection differs from the previous frame's (`None` for
    /// the first frame).
    pub fn add(&mut self, rgba: Vec<u8>, key: SelectionKey) -> Result<Option<bool>, FramesDiffer> {
        let changed = match &self.last {
            Some((before, prev)) => {
                let changed = *prev != key;
                self.last_lod_only = changed && prev.same_layout(&key);
                let class = if changed {
                    &mut self.changed
                } else {
                    &mut self.unchanged
                };
                class.add(before, &rgba)?;
                Some(changed)
            }
            None => None,
        };
        self.last = Some((rgba, key));
        Ok(changed)
    }

    /// Adds a same-camera pair: this frame as drawn (`current`) and drawn again
    /// with the previous frame's patches (`previous`); `changed` as [`Popping::add`]
    /// returned it.
    pub fn add_same_camera(
        &mut self,
        current: &[u8],
        previous: &[u8],
        changed: bool,
    ) -> Result<(), FramesDiffer> {
        if changed && self.last_lod_only {
            self.same_lod_only.add(previous, current)?;
        }
        let class = if changed {
            &mut self.same_changed
        } else {
            &mut self.same_unchanged
        };
        class.add(previous, current)
    }

    pub fn summary(&self) -> PoppingSummary {
        let (c, u) = (&self.changed, &self.unchanged);
        let (sc, su) = (&self.same_changed, &self.same_unchanged);
        let (changed_mean, unchanged_mean) = (c.mean(), u.mean());
        PoppingSummary {
            changed_pairs: c.pairs,
            unchanged_pairs: u.pairs,
            changed_mean,
            changed_p99: c.quantile(0.99),
            unchanged_mean,
            unchanged_p99: u.quantile(0.99),
            excess_mean: changed_mean.zip(unchanged_mean).map(|(a, b)| a - b),
            same_camera_changed_mean: sc.mean(),
            same_camera_changed_p99: sc.quantile(0.99),
            same_camera_unchanged_mean: su.mean(),
            same_camera_unchanged_p99: su.quantile(0.99),
            lod_only_pairs: self.same_lod_only.pairs,
            same_camera_lod_only_mean: self.same_lod_only.mean(),
            same_camera_lod_only_p99: self.same_lod_only.quantile(0.99),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::Level;

    fn frame(w: usize, h: usize, f: impl Fn(usize, usize) -> [u8; 3]) -> Vec<u8> {
        (0..w * h)
            .flat_map(|i| {
                let [r, g, b] = f(i % w, i / w);
                [r, g, b, 255]
            })
            .collect()
    }

    fn key(inner: u32) -> SelectionKey {
        let tile = TileId::new(Level::ROOT, 0, 0).unwrap();
        let p = Patch {
            tile,
            origin: [0, 0],
            size: 64,
            inner,
            edges: [inner; 4],
            morph: crate::select::morph::Morph::NONE,
            fade: crate::select::fade::Fade::NONE,
        };
        SelectionKey::new(&[tile], &[p])
    }

    #[test]
    fn figures_are_the_hand_computed_ones_and_a_changed_region_shows() {
        // 10×10 frames. Frame 1: every pixel's red +3 (camera motion, selection
        // unchanged). Frame 2: as frame 1, and a 2×5 region (10 pixels) changes by
        // (30, 60, 90) with the LOD (selection changed).
        let base = frame(10, 10, |x, y| [(x * 10) as u8, (y * 10) as u8, 100]);
        let moved = frame(10, 10, |x, y| [(x * 10 + 3) as u8, (y * 10) as u8, 100]);
        let popped = frame(10, 10, |x, y| {
            let [r, g, b] = [(x * 10 + 3) as u8, (y * 10) as u8, 100u8];
            if (4..6).contains(&x) && y < 5 {
                [r + 30, g + 60, b + 90]
            } else {
                [r, g, b]
            }
        });
        let mut p = Popping::default();
        assert_eq!(p.add(base, key(8)).unwrap(), None);
        assert_eq!(p.add(moved, key(8)).unwrap(), Some(false));
        assert_eq!(p.add(popped, key(16)).unwrap(), Some(true));
        let s = p.summary();
        assert_eq!((s.changed_pairs, s.unchanged_pairs), (1, 1));
        // Unchanged: every pixel changes by 3 summed, 1 on the 0–255 scale.
        assert_eq!(s.unchanged_mean, Some(1.0));
        assert_eq!(s.unchanged_p99, Some(1.0));
        // Changed: 10 of 100 pixels by 180 (60 per channel), the rest by 0.
        assert_eq!(s.changed_mean, Some(6.0));
        assert_eq!(s.changed_p99, Some(60.0));
        assert_eq!(s.excess_mean, Some(5.0));
        assert_eq!(s.same_camera_changed_mean, None);
        // Same camera: the pop alone (the 10-pixel region), and no drift.
        let (moved, popped) = (
            frame(10, 10, |x, y| [(x * 10 + 3) as u8, (y * 10) as u8, 100]),
            frame(10, 10, |x, y| {
                let [r, g, b] = [(x * 10 + 3) as u8, (y * 10) as u8, 100u8];
                if (4..6).contains(&x) && y < 5 {
                    [r + 30, g + 60, b + 90]
                } else {
                    [r, g, b]
                }
            }),
        );
        p.add_same_camera(&popped, &moved, true).unwrap();
        p.add_same_camera(&moved, &moved, false).unwrap();
        let s = p.summary();
        assert_eq!(s.same_camera_changed_mean, Some(6.0));
        assert_eq!(s.same_camera_changed_p99, Some(60.0));
        assert_eq!(s.same_camera_unchanged_mean, Some(0.0));
        // The region is what makes it: 1 pixel in 100 would leave p99 at 0.
        let mut h = ChangeHistogram::default();
        let one = frame(
            10,
            10,
            |x, y| if (x, y) == (0, 0) { [9, 0, 0] } else { [0; 3] },
        );
        h.add(&frame(10, 10, |_, _| [0; 3]), &one).unwrap();
        assert_eq!(h.quantile(0.99), Some(0.0));
        assert_eq!(h.quantile(1.0), Some(3.0));
        assert!(h.add(&[0; 8], &[0; 12]).is_err());
    }

    #[test]
    fn selections_differ_by_lod_or_tiles_but_not_by_morph_or_order() {
        let tile = TileId::new(Level::ROOT, 0, 0).unwrap();
        let p = |inner, m| Patch {
            tile,
            origin: [0, 0],
            size: 64,
            inner,
            edges: [inner; 4],
            morph: crate::select::morph::Morph::new(m, [m; 4]).unwrap(),
            fade: crate::select::fade::Fade::NONE,
        };
        let q = |inner| Patch {
            origin: [64, 0],
            ..p(inner, 0)
        };
        let a = SelectionKey::new(&[tile], &[p(8, 0), q(4)]);
        assert_eq!(a, SelectionKey::new(&[tile], &[q(4), p(8, 200)]));
        assert_ne!(a, SelectionKey::new(&[tile], &[p(8, 0), q(8)]));
        assert_ne!(a, SelectionKey::new(&[], &[p(8, 0), q(4)]));
        let mut snapped = q(4);
        snapped.edges[1] = 2;
        assert_ne!(a, SelectionKey::new(&[tile], &[p(8, 0), snapped]));
        // LODs alone keep the layout; another patch or tile does not.
        assert!(a.same_layout(&SelectionKey::new(&[tile], &[p(16, 0), snapped])));
        assert!(!a.same_layout(&SelectionKey::new(&[tile], &[p(8, 0)])));
        assert!(!a.same_layout(&SelectionKey::new(&[], &[p(8, 0), q(4)])));
    }
}
