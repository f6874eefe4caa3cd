//! Which pyramid level, square size and threshold each zoom meshes with (the
//! bound in the module doc of [`super`]), from the error tables.

use super::{LevelData, Terrain};
use crate::cesium::mesh::Truth;
use crate::cesium::tiling::{CesiumTile, geometric_error};
use std::collections::HashMap;
use tessera_shared::Level;

/// How one zoom is meshed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ZoomPlan {
    pub level: Level,
    /// RTIN square size, in cells of the level.
    pub square: u32,
    /// RTIN threshold (metres).
    pub tau: f64,
    /// The error CesiumJS assumes at this zoom, which every tile keeps within.
    pub geometric_error: f64,
    pub(super) truth: Truth,
}

impl ZoomPlan {
    /// The same plan at another threshold (for benchmarks at equal error).
    pub fn with_tau(self, tau: f64) -> Self {
        Self { tau, ..self }
    }
}

impl Terrain {
    /// The level, square size and threshold of zoom `z` (see the module doc).
    pub fn plan<D: LevelData>(&self, z: u8, data: &D) -> Result<ZoomPlan, D::Error> {
        let eps = geometric_error(self.level_zero_error, z);
        let finest = self.geometry.finest();
        let mut chosen = (finest, 0.0, Truth::Samples);
        for level in self.geometry.levels() {
            if level == finest {
                break;
            }
            let e = self.level_error(level, data)?;
            if e > eps / 2.0 {
                continue;
            }
            let twist = self.level_twist(level, data)?;
            if e + twist <= eps / 2.0 {
                chosen = (level, e, Truth::NorthWestDiagonal);
                break;
            }
        }
        let (level, e, truth) = chosen;
        let n = CesiumTile::span(z) / self.level_spacing_deg(level);
        let cells = (1u32 << level.get()) * self.geometry.tile_size();
        let quarter = (n / 4.0).clamp(2.0, f64::from(cells));
        let square = 1u32 << (quarter.log2().floor() as u32);
        Ok(ZoomPlan {
            level,
            square: square.clamp(2, cells),
            tau: 0.95 * eps - e - self.quantization_margin,
            geometric_error: eps,
            truth,
        })
    }

    fn level_error<D: LevelData>(&self, level: Level, data: &D) -> Result<f64, D::Error> {
        if let Some((e, _)) = self.lock().get(&level.get()) {
            return Ok(*e);
        }
        let e = data.level_error(level)?;
        self.lock().insert(level.get(), (e, None));
        Ok(e)
    }

    /// The largest half-twist of any cell of `level` (`cesium/mesh.rs`: the leaves' error).
    fn level_twist<D: LevelData>(&self, level: Level, data: &D) -> Result<f64, D::Error> {
        if let Some((_, Some(t))) = self.lock().get(&level.get()) {
            return Ok(*t);
        }
        let t_samples = self.geometry.tile_samples();
        let step = self.quantization.scale;
        let mut worst = 0_u32;
        for tile in self.geometry.present_tiles(level) {
            let Some(src) = data.tile(tile)? else {
                continue;
            };
            let h = &src.heights;
            for r in 0..t_samples - 1 {
                for c in 0..t_samples - 1 {
                    let q = |dc: usize, dr: usize| i64::from(h[(r + dr) * t_samples + c + dc]);
                    let twist = (q(0, 0) + q(1, 1) - q(1, 0) - q(0, 1)).unsigned_abs() as u32;
                    worst = worst.max(twist);
                }
            }
        }
        let t = 0.5 * f64::from(worst) * step;
        let e = self.level_error(level, data)?;
        self.lock().insert(level.get(), (e, Some(t)));
        Ok(t)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<u8, (f64, Option<f64>)>> {
        self.level_bounds
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}
