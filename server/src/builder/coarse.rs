//! Coarse tiles, assembled bottom-up as their children arrive in Morton order:
//! heights by decimation, errors by pooling the children's exact block maxima, masks
//! by AND-pooling (FORMAT.md "Validity mask").

use super::mesh_error::BlockErrors;
use super::node::{Encoded, Node, encode};
use super::sink::Sink;
use indicatif::ProgressBar;
use tessera_shared::tile::BLOCKS;
use tessera_shared::{CellMask, Level, Morton, TileGeometry};

/// Post-order assembly of coarse tiles as their children arrive in Morton order.
pub(super) struct Aggregator<'a> {
    pub(super) geometry: TileGeometry,
    pub(super) spacings: u32,
    /// The coarsest level assembled: the root for a whole build, the split level for
    /// a part of a distributed build. Its nodes go to [`Sink::top`], not to a parent.
    pub(super) top: Level,
    /// Per level, the up-to-four siblings waiting for their parent.
    pub(super) pending: Vec<[Option<Node>; 4]>,
    /// Range of the finest records' quantized heights (the dataset's).
    pub(super) min_q: u16,
    pub(super) max_q: u16,
    pub(super) bar: &'a ProgressBar,
    /// Which tiles a multi-resolution pyramid stores; `None`: all. A tile not stored
    /// still becomes a node: its parent is assembled from it.
    pub(super) support: Option<&'a super::support::Support>,
}

/// Mesh spacings a node's block errors hold, `0 ..= t + L_max`: from the data itself
/// to the root's single cell.
pub(super) fn spacings(g: &TileGeometry) -> u32 {
    g.tile_log2() + u32::from(g.finest().get()) + 1
}

impl<'a> Aggregator<'a> {
    /// An aggregator with nothing waiting, up to level `top`.
    pub(super) fn new(
        geometry: TileGeometry,
        top: Level,
        bar: &'a ProgressBar,
        support: Option<&'a super::support::Support>,
    ) -> Self {
        Self {
            geometry,
            spacings: spacings(&geometry),
            top,
            pending: (0..=geometry.finest().get())
                .map(|_| [None, None, None, None])
                .collect(),
            min_q: u16::MAX,
            max_q: 0,
            bar,
            support,
        }
    }
}

impl Aggregator<'_> {
    /// A tile (`None`: absent) and its encoded record, which goes to `sink` before the
    /// tile joins its siblings.
    pub(super) fn push(
        &mut self,
        sink: &mut dyn Sink,
        level: Level,
        m: Morton,
        item: Option<(Node, Encoded)>,
    ) -> anyhow::Result<()> {
        let node = match item {
            Some((node, enc)) => {
                if let Some(record) = &enc.record
                    && self.support.is_none_or(|s| s.stores(level, m))
                {
                    sink.record(level, m, record, enc.summary)?;
                    sink.node(level, m, &node)?;
                    // The heights' range is that of the stored records, every level
                    // (in a whole pyramid the finest level's: the others are its
                    // decimations; a multi-resolution one stores coarse-only places
                    // only at coarse levels).
                    self.min_q = self.min_q.min(enc.summary.min);
                    self.max_q = self.max_q.max(enc.summary.max);
                }
                self.bar.inc(1);
                Some(node)
            }
            None => None,
        };
        self.push_node(sink, level, m, node)
    }

    /// A tile whose record is already written (or is written elsewhere: the split
    /// level's tiles, when assembling parts) joins its siblings; the fourth makes
    /// their parent.
    pub(super) fn push_node(
        &mut self,
        sink: &mut dyn Sink,
        level: Level,
        m: Morton,
        node: Option<Node>,
    ) -> anyhow::Result<()> {
        if level == self.top {
            return sink.top(m, node);
        }
        let parent_level = level.coarser().expect("a level below the top has a parent");
        let slot = &mut self.pending[usize::from(level.get())];
        slot[usize::from(m.quadrant())] = node;
        if m.quadrant() == 3 {
            let children = std::mem::take(slot);
            let parent = self.assemble(&children).map(|node| {
                let enc = encode(&node, &self.geometry, parent_level);
                (node, enc)
            });
            // Freed before the parent cascades upward, so each level holds at most
            // three waiting siblings (memory::Plan counts on it).
            drop(children);
            self.push(sink, parent_level, m.parent(), parent)?;
        }
        Ok(())
    }

    /// A parent from its children; `None` when the parent is absent (its first child is).
    fn assemble(&self, children: &[Option<Node>; 4]) -> Option<Node> {
        children[0].as_ref()?;
        let side = self.geometry.tile_samples();
        let half = side / 2;
        let mut heights = vec![0u16; side * side];
        let mut errors = BlockErrors::zeros(self.spacings as usize);
        let (mut min, mut max) = ([u16::MAX; 64], [0u16; 64]);
        for (q, child) in children.iter().enumerate() {
            let Some(c) = child else { continue };
            let (qx, qy) = (q & 1, q >> 1);
            for j in 0..=half {
                let dst = (qy * half + j) * side + qx * half;
                let src = 2 * j * side;
                for i in 0..=half {
                    heights[dst + i] = c.heights[src + 2 * i];
                }
            }
            errors.pool_child(&c.errors, qx as u32, qy as u32);
            for cby in 0..BLOCKS as usize {
                for cbx in 0..BLOCKS as usize {
                    let pi = (qy * 4 + cby / 2) * BLOCKS as usize + qx * 4 + cbx / 2;
                    let ci = cby * BLOCKS as usize + cbx;
                    min[pi] = min[pi].min(c.min[ci]);
                    max[pi] = max[pi].max(c.max[ci]);
                }
            }
        }
        // Absent children lie wholly beyond the DEM's east or south edge, where the
        // padded grid repeats the edge: copy the last present column / row.
        if children[1].is_none() {
            for r in 0..side {
                let edge = heights[r * side + half];
                heights[r * side + half + 1..(r + 1) * side].fill(edge);
            }
        }
        if children[2].is_none() {
            let (top, rest) = heights.split_at_mut((half + 1) * side);
            let edge = &top[half * side..];
            for row in rest.chunks_exact_mut(side) {
                row.copy_from_slice(edge);
            }
        }
        let cells = side as u32 - 1;
        let mask = CellMask::pooled(
            cells,
            [0, 1, 2, 3].map(|q| children[q].as_ref().map(|c| &c.mask)),
        );
        Some(Node {
            heights,
            errors,
            min,
            max,
            mask,
        })
    }
}
