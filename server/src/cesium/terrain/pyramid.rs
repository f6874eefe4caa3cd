//! A pyramid read directly as [`super::LevelData`] (no server): for tests,
//! benchmarks and tools.

use super::LevelData;
use crate::web::resample::SourceTile;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use tessera_shared::reader::ReadError;
use tessera_shared::{Level, TileId};

/// A pyramid read directly (no server): for tests, benchmarks and tools. Decoded
/// tiles are kept, so a caller meshing many tiles decodes each source once.
#[derive(Debug)]
pub struct PyramidLevels<'a, S> {
    pyramid: &'a tessera_shared::Pyramid<S>,
    decoded: Mutex<HashMap<TileId, Option<Arc<SourceTile>>>>,
}

impl<'a, S: tessera_shared::ByteSource> PyramidLevels<'a, S> {
    pub fn new(pyramid: &'a tessera_shared::Pyramid<S>) -> Self {
        Self {
            pyramid,
            decoded: Mutex::new(HashMap::new()),
        }
    }
}

/// A tile of the pyramid that could not be read.
#[derive(Debug, thiserror::Error)]
#[error("{tile}: {source}")]
pub struct TileReadError {
    pub tile: TileId,
    pub source: ReadError,
}

impl<S: tessera_shared::ByteSource> LevelData for PyramidLevels<'_, S> {
    type Error = TileReadError;

    fn tile(&self, tile: TileId) -> Result<Option<Arc<SourceTile>>, TileReadError> {
        let mut map = self
            .decoded
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(t) = map.get(&tile) {
            return Ok(t.clone());
        }
        let rec = self
            .pyramid
            .read_tile(tile)
            .map_err(|source| TileReadError { tile, source })?;
        let t = rec.map(|r| {
            Arc::new(SourceTile {
                block_errors: crate::web::resample::block_errors(&r.errors),
                heights: r.heights,
                mask: r.mask,
                quantization: self.pyramid.metadata().quantization,
            })
        });
        map.insert(tile, t.clone());
        Ok(t)
    }

    fn level_error(&self, level: Level) -> Result<f64, TileReadError> {
        let mut worst = 0.0_f64;
        for tile in self.pyramid.geometry().present_tiles(level) {
            if let Some(t) = self
                .pyramid
                .read_error_table(tile)
                .map_err(|source| TileReadError { tile, source })?
            {
                worst = worst.max(f64::from(t.full_resolution_error()));
            }
        }
        Ok(worst)
    }
}
