//! The tiler: finest tiles cut, measured and encoded in parallel batches in Morton
//! order, coarse tiles assembled as soon as their four children exist, records
//! handed to a [`Sink`](super::sink::Sink) (a pyramid file or a part).

use super::coarse::Aggregator;
use super::finest::finest_node;
use super::node::{Encoded, Node, encode};
use super::sink::Sink;
use super::{BuildOptions, memory};
use crate::ingest::raster::Raster;
use indicatif::ProgressBar;
use rayon::prelude::*;
use tessera_shared::{Level, Morton, Quantization, TileGeometry, TileId};

/// What the tiler reads and how: shared by a whole build and a part.
pub(super) struct Tiling<'a> {
    pub(super) raster: &'a dyn Raster,
    pub(super) geometry: TileGeometry,
    pub(super) quant: Quantization,
    pub(super) plan: memory::Plan,
    pub(super) opts: &'a BuildOptions,
    pub(super) bar: &'a ProgressBar,
    /// Which tiles a multi-resolution pyramid stores ([`super::support`]); `None`: all.
    pub(super) support: Option<&'a super::support::Support>,
}

impl Tiling<'_> {
    /// Builds the subtrees of the level-`top` tiles with Morton codes `tops`: cuts,
    /// measures and encodes their finest tiles in parallel batches, in Morton order,
    /// and assembles every tile up to level `top` as soon as its four children exist.
    /// Records go to `sink` (each level in Morton order), level-`top` nodes to
    /// [`Sink::top`]. A whole build is the root's subtree (`top` 0, `tops` 0..1).
    /// Returns the range of the finest records' quantized heights (`u16::MAX, 0`
    /// when there is none).
    pub(super) fn subtrees(
        &self,
        sink: &mut dyn Sink,
        top: Level,
        tops: std::ops::Range<u64>,
    ) -> anyhow::Result<(u16, u16)> {
        let Tiling {
            raster,
            geometry,
            quant,
            plan,
            opts,
            bar,
            support,
        } = *self;
        let finest = geometry.finest();
        let mut agg = Aggregator::new(geometry, top, bar, support);
        let spacings = agg.spacings;
        let batch = plan.batch;
        let depth = 2 * u32::from(finest.get() - top.get());
        let (first, end) = (tops.start << depth, tops.end << depth);
        std::thread::scope(|scope| -> anyhow::Result<()> {
            let (tx, rx) =
                std::sync::mpsc::sync_channel::<anyhow::Result<Vec<Option<(Node, Encoded)>>>>(1);
            let producer = scope.spawn(move || {
                let mut start = first;
                while start < end {
                    let stop = (start + batch as u64).min(end);
                    let result: anyhow::Result<Vec<_>> = (start..stop)
                        .into_par_iter()
                        .map(|m| {
                            let tile =
                                TileId::from_morton(finest, Morton::from_raw(m)).expect("m < 4^L");
                            if !geometry.is_present(tile) {
                                return Ok(None);
                            }
                            let node = finest_node(raster, &geometry, tile, spacings, &quant)?;
                            let enc = encode(&node, &geometry, finest);
                            Ok(Some((node, enc)))
                        })
                        .collect();
                    let failed = result.is_err();
                    if tx.send(result).is_err() || failed {
                        return;
                    }
                    start = stop;
                }
            });
            let mut m = first;
            for batch in rx {
                opts.interrupt.check()?;
                for item in batch? {
                    agg.push(sink, finest, Morton::from_raw(m), item)?;
                    m += 1;
                }
            }
            producer.join().expect("tile producer panicked");
            anyhow::ensure!(m == end, "tile production stopped early");
            Ok(())
        })?;
        Ok((agg.min_q, agg.max_q))
    }
}
