//! What selection knows of the tiles: the error tables of the resident ones, and
//! which of the others cannot be had for now or have no record.

use std::collections::HashMap;
use tessera_shared::reader::ReadError;
use tessera_shared::{ByteSource, ErrorTable, Pyramid, TileId};

/// An error table of a local pyramid that could not be read.
#[derive(Debug, thiserror::Error)]
#[error("reading the error table of {tile}")]
pub struct TableError {
    pub tile: TileId,
    #[source]
    pub source: ReadError,
}

/// Error tables of the tiles that are resident (decoded and available).
pub trait TileTables {
    fn table(&self, tile: TileId) -> Option<&ErrorTable>;

    /// Whether a tile that is not resident cannot be had for now: its last fetch
    /// failed (it is backing off) or its record was written off as corrupt. The
    /// selection then draws that tile's resident children in its place, so that
    /// a bad root does not blind the client (the client draws the healthiest level it
    /// has: docs/ARCHITECTURE.md#the-client-never-goes-blind).
    fn unavailable(&self, _tile: TileId) -> bool {
        false
    }

    /// Whether a tile the geometry places inside the DEM is known to have no
    /// record: it holds no terrain cell (format v2: wholly no-data tiles are absent;
    /// the tile stream's trailer lists them among its outside ranges). Selection
    /// neither waits for such a tile nor counts it as a hole, and refines its
    /// parent into the siblings that are present.
    fn absent(&self, _tile: TileId) -> bool {
        false
    }
}

/// Every error table of a local pyramid (benchmarks and tools: selection with
/// everything resident). Tiles the geometry places inside the DEM but that have no
/// record (wholly no-data, format v2) are left out: the map calls them absent.
pub fn all_tables<S: ByteSource>(
    pyramid: &Pyramid<S>,
) -> Result<HashMap<TileId, ErrorTable>, TableError> {
    let g = *pyramid.geometry();
    let mut tables = HashMap::new();
    for level in g.levels() {
        for tile in g.present_tiles(level) {
            if let Some(t) = pyramid
                .read_error_table(tile)
                .map_err(|source| TableError { tile, source })?
            {
                tables.insert(tile, t);
            }
        }
    }
    Ok(tables)
}

/// A map of error tables is a whole local pyramid ([`all_tables`]): a tile it
/// lacks has no record, i.e. is absent.
impl TileTables for HashMap<TileId, ErrorTable> {
    fn table(&self, tile: TileId) -> Option<&ErrorTable> {
        self.get(&tile)
    }

    fn absent(&self, tile: TileId) -> bool {
        !self.contains_key(&tile)
    }
}
