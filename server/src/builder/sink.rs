//! Where the tiler's records go: a pyramid file or a part of a distributed build.

use super::node::Node;
use super::writer;
use tessera_shared::format::IndexEntry;
use tessera_shared::{Level, Morton};

/// Where the tiler's output goes: a pyramid file ([`writer::PyramidWriter`]) or a
/// part of a distributed build ([`parts`]).
pub(super) trait Sink {
    /// A tile's record and its index summary; each level's arrive in Morton order.
    fn record(
        &mut self,
        level: Level,
        m: Morton,
        record: &[u8],
        summary: IndexEntry,
    ) -> anyhow::Result<()>;

    /// A tile of the top level the tiler assembles (`None`: absent), in Morton order.
    fn top(&mut self, m: Morton, node: Option<Node>) -> anyhow::Result<()>;

    /// The node of a tile whose record was just stored, for what its record does not
    /// keep (`build --state`). Most sinks need nothing.
    fn node(&mut self, _level: Level, _m: Morton, _node: &Node) -> anyhow::Result<()> {
        Ok(())
    }
}

impl Sink for writer::PyramidWriter {
    fn record(
        &mut self,
        level: Level,
        m: Morton,
        record: &[u8],
        summary: IndexEntry,
    ) -> anyhow::Result<()> {
        self.push(level, m, record, summary)
    }

    /// A pyramid's top is its root: nothing waits for it.
    fn top(&mut self, _m: Morton, _node: Option<Node>) -> anyhow::Result<()> {
        Ok(())
    }
}
