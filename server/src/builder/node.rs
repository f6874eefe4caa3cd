//! A tile in the making: what its parent needs (heights, exact block errors for
//! every spacing, block min/max, validity), and its encoded record and index summary.

use super::mesh_error::BlockErrors;
use tessera_shared::error_table::round_up_f32;
use tessera_shared::format::{FLAG_PARTIAL, IndexEntry};
use tessera_shared::tile::BLOCKS;
use tessera_shared::{CellMask, ErrorTable, Level, Quantization, TileGeometry, codec};

/// A tile with what its parent needs: heights, block errors for every spacing, and
/// block min/max (empty blocks are `min = u16::MAX, max = 0`).
///
/// Errors are in metres as records store them ([`to_metres`]: rounded up to `f32`),
/// converted once, at the finest level: the conversion is non-decreasing, so the
/// maximum of converted errors is the converted maximum, and every table is what
/// pooling exact errors and converting last gives. Held so, a node can be rebuilt
/// from its record and the errors its record does not store (`build --update`).
pub(super) struct Node {
    pub(super) heights: Vec<u16>,
    pub(super) errors: BlockErrors,
    pub(super) min: [u16; 64],
    pub(super) max: [u16; 64],
    /// Which cells are terrain (FORMAT.md "Validity mask").
    pub(super) mask: CellMask,
}

/// An encoded record and its index summary; `None` record for a tile inside the DEM
/// that holds no terrain cell (it is absent from the file, but its node still feeds
/// its parent's heights).
pub(super) struct Encoded {
    pub(super) record: Option<Vec<u8>>,
    pub(super) summary: IndexEntry,
}

/// Errors in quantization steps → metres, rounded up so the bound stays conservative.
pub(super) fn to_metres(steps: f64, q: &Quantization) -> f32 {
    if steps == 0.0 {
        0.0
    } else {
        round_up_f32((steps * q.scale).next_up())
    }
}

pub(super) fn encode(node: &Node, g: &TileGeometry, level: Level) -> Encoded {
    let t = g.tile_log2();
    let mut table = ErrorTable::empty(t);
    let below = u32::from(g.finest().get() - level.get());
    for n in 0..=t {
        let k = t - n + below;
        for by in 0..BLOCKS {
            for bx in 0..BLOCKS {
                table.set_error(n, bx, by, node.errors.get(k, bx, by) as f32);
            }
        }
    }
    for by in 0..BLOCKS {
        for bx in 0..BLOCKS {
            let i = (by * BLOCKS + bx) as usize;
            table.set_block_range(bx, by, node.min[i], node.max[i]);
        }
    }
    let (min, max) = table.tile_range();
    let partial = !node.mask.is_all_valid();
    Encoded {
        record: (!node.mask.is_none_valid())
            .then(|| codec::encode_record(&table, &node.mask, &node.heights)),
        summary: IndexEntry {
            min,
            max,
            full_res_error: table.full_resolution_error(),
            flags: if partial { FLAG_PARTIAL } else { 0 },
            ..IndexEntry::default()
        },
    }
}
