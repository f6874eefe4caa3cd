//! A tile a multi-resolution pyramid does not store, made from its nearest stored
//! ancestor (DECISIONS.md "Multi-resolution pyramids"): the ancestor's surface at the
//! tile's samples, bilinear between the ancestor's, and its cells terrain where the
//! ancestor's cell under them is.

use super::resample::SourceTile;
use tessera_shared::TileId;

/// `a` (tile `ancestor`, `depth` levels above `tile`; tiles of `t` cells) resampled
/// onto `tile`'s samples.
pub fn upsample(a: &SourceTile, t: u32, tile: TileId, ancestor: TileId, depth: u32) -> SourceTile {
    let side = t + 1;
    let scale = 1.0 / f64::from(1u32 << depth);
    // The tile's first sample in the ancestor's sample coordinates.
    let ox = f64::from(tile.x() - (ancestor.x() << depth)) * f64::from(t) * scale;
    let oy = f64::from(tile.y() - (ancestor.y() << depth)) * f64::from(t) * scale;
    let at = |i: u32, j: u32| f64::from(a.heights[(j * side + i) as usize]);
    let mut heights = Vec::with_capacity((side * side) as usize);
    for j in 0..side {
        for i in 0..side {
            let (x, y) = (ox + f64::from(i) * scale, oy + f64::from(j) * scale);
            let (x0, y0) = ((x.floor() as u32).min(t - 1), (y.floor() as u32).min(t - 1));
            let (fx, fy) = (x - f64::from(x0), y - f64::from(y0));
            let v = at(x0, y0) * (1.0 - fx) * (1.0 - fy)
                + at(x0 + 1, y0) * fx * (1.0 - fy)
                + at(x0, y0 + 1) * (1.0 - fx) * fy
                + at(x0 + 1, y0 + 1) * fx * fy;
            heights.push(v.round().clamp(0.0, f64::from(u16::MAX)) as u16);
        }
    }
    let mut mask = tessera_shared::CellMask::none_valid(t);
    for j in 0..t {
        for i in 0..t {
            let x = (ox + (f64::from(i) + 0.5) * scale) as u32;
            let y = (oy + (f64::from(j) + 0.5) * scale) as u32;
            mask.set(i, j, a.mask.is_valid(x.min(t - 1), y.min(t - 1)));
        }
    }
    SourceTile {
        heights,
        mask,
        quantization: a.quantization,
        block_errors: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::{CellMask, Level, Quantization};

    /// A plane `q = 1000 + 3·x + 5·y` over tile `(L, 1, 2)`'s samples (tiles of 8),
    /// `x, y` counted on level L's grid, with one cell not terrain.
    fn ancestor() -> (SourceTile, TileId) {
        let (t, tile) = (8u32, TileId::new(Level::new(2).unwrap(), 1, 2).unwrap());
        let mut heights = Vec::new();
        for j in 0..=t {
            for i in 0..=t {
                let (x, y) = (tile.x() * t + i, tile.y() * t + j);
                heights.push((1000 + 3 * x + 5 * y) as u16);
            }
        }
        let mut mask = CellMask::all_valid(t);
        mask.set(6, 1, false);
        let q = Quantization {
            offset: 0.0,
            scale: 1.0,
            max_error: 0.0,
        };
        (
            SourceTile {
                heights,
                mask,
                quantization: q,
                block_errors: None,
            },
            tile,
        )
    }

    /// Bilinear reproduces a plane: every sample of a descendant two levels down is
    /// the plane at its own place (on the ancestor's grid, a quarter step apart), so a
    /// wrong offset or scale fails; its cells are terrain where the ancestor's cell
    /// under them is.
    #[test]
    fn an_absent_tile_is_its_ancestors_surface() {
        let (a, anc) = ancestor();
        // Level 4 tile (5, 10): ancestor (1, 2) at level 2, quadrant (1, 2) of 4×4.
        let tile = TileId::new(Level::new(4).unwrap(), 5, 10).unwrap();
        let made = upsample(&a, 8, tile, anc, 2);
        for j in 0..=8u32 {
            for i in 0..=8u32 {
                // Level-2 coordinates of the level-4 sample.
                let x = f64::from(5 * 8 + i) / 4.0;
                let y = f64::from(10 * 8 + j) / 4.0;
                let want = (1000.0 + 3.0 * x + 5.0 * y).round() as u16;
                assert_eq!(
                    made.heights[(j * 9 + i) as usize],
                    want,
                    "sample ({i}, {j})"
                );
            }
        }
        // It lies under ancestor cells x 2..4, y 4..6: all terrain.
        assert!(made.mask.is_all_valid());
        // Level-4 tile (7, 8) lies under ancestor cells x 6..8, y 0..2, which include
        // the one that is not terrain.
        let under = TileId::new(Level::new(4).unwrap(), 7, 8).unwrap();
        let m = upsample(&a, 8, under, anc, 2).mask;
        for j in 0..8u32 {
            for i in 0..8u32 {
                let (ax, ay) = ((7 * 8 + i) / 4 - 8, (8 * 8 + j) / 4 - 16);
                assert_eq!(m.is_valid(i, j), (ax, ay) != (6, 1), "cell ({i}, {j})");
            }
        }
    }
}
