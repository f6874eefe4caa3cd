//! The terrain in world units: a dataset's tile geometry, quantization and
//! ground spacing (and its globe), where tiles and samples lie, and how far boxes
//! are from an eye.

use crate::camera::Camera;
use crate::globe::NotAGlobe;
use glam::DVec2;
use tessera_shared::api::DatasetInfo;
use tessera_shared::tile::GeometryError;
use tessera_shared::{GroundSpacing, Quantization, TileGeometry, TileId};

/// The terrain in world units.
///
/// World coordinates are metres (`x` east, `y` up, `z` south, [`crate::camera`]):
/// finest sample `(X, Y)` sits at `(X·spacing.x, h, Y·spacing.y)`. The two spacings
/// differ where cells are not square on the ground (a geographic DEM: N46E008's
/// cells are 63.97 m east–west and 92.63 m north–south).
#[derive(Clone, Copy, Debug)]
pub struct World {
    pub geometry: TileGeometry,
    pub quant: Quantization,
    /// Metres between neighbouring finest samples: `x` east–west (between columns),
    /// `y` north–south (between rows, along world `z`).
    pub spacing: DVec2,
    /// The body and grid when the dataset is drawn on the globe
    /// (DECISIONS.md "The globe"): boxes are then curved shells
    /// ([`crate::globe::volume`]).
    pub globe: Option<crate::globe::Globe>,
}

/// Distances from one eye to flat-world boxes ([`World::distances_from`]).
#[derive(Clone, Copy, Debug)]
pub enum BoxDistance {
    Flat(glam::DVec3),
    Globe(crate::globe::Globe, crate::globe::frame::EyeFrame),
}

impl BoxDistance {
    /// The distance to the box `min..max` (0 with the eye inside it).
    pub fn to(&self, min: glam::DVec3, max: glam::DVec3) -> f64 {
        match self {
            Self::Flat(eye) => crate::camera::distance_to_box(*eye, min, max),
            Self::Globe(g, eye) => crate::globe::volume::distance(g, eye, min, max),
        }
    }
}

/// Metres between samples when neither the command line nor the dataset says.
pub const FALLBACK_SPACING: f64 = 100.0;

impl World {
    /// The world of a dataset document (API.md): its geometry and quantization,
    /// and the spacing from [`World::spacing_from`].
    pub fn from_dataset(info: &DatasetInfo, stated: Option<f64>) -> Result<Self, GeometryError> {
        Ok(Self {
            geometry: TileGeometry::new(info.width, info.height, info.tile_size)?,
            quant: info.quantization,
            spacing: Self::spacing_from(stated, info.ground_spacing),
            globe: None,
        })
    }

    /// The same world drawn on the globe of `mode` (`tessera fly --globe`).
    pub fn with_globe(
        self,
        mode: crate::globe::GlobeMode,
        info: &DatasetInfo,
    ) -> Result<Self, NotAGlobe> {
        Ok(Self {
            globe: crate::globe::Globe::choose(mode, info, self.spacing)?,
            ..self
        })
    }

    /// The camera's frustum: flat, or on the globe (eye-local planes, curved
    /// boxes, horizon culling).
    pub fn frustum(&self, camera: &Camera) -> crate::camera::Frustum {
        match self.globe {
            None => camera.frustum(),
            Some(globe) => camera.frustum_on_globe(crate::globe::volume::GlobeView {
                globe,
                eye: crate::globe::frame::EyeFrame::of_world(&globe, camera.position),
            }),
        }
    }

    /// Distances from the eye (a map pose) to flat-world boxes: to the box itself
    /// when flat, a lower bound on the distance to its curved shell on the globe
    /// ([`crate::globe::volume::distance`]). The eye's frame on the globe is worked
    /// out here once, for all the boxes measured from it.
    pub fn distances_from(&self, eye: glam::DVec3) -> BoxDistance {
        match self.globe {
            None => BoxDistance::Flat(eye),
            Some(g) => BoxDistance::Globe(g, crate::globe::frame::EyeFrame::of_world(&g, eye)),
        }
    }

    /// Metres between samples: a stated spacing (`--spacing M`, for DEMs without
    /// georeferencing) for both axes; else the dataset's measured ground spacing
    /// (the server measures it with a projection library); else
    /// [`FALLBACK_SPACING`] for both.
    pub fn spacing_from(stated: Option<f64>, measured: Option<GroundSpacing>) -> DVec2 {
        match (stated, measured) {
            (Some(s), _) => DVec2::splat(s),
            (None, Some(g)) if g.is_plausible() => DVec2::new(g.x, g.y),
            _ => DVec2::splat(FALLBACK_SPACING),
        }
    }

    /// World `(x, z)` in metres of finest-grid point `(X, Y)` (samples, fractional
    /// allowed).
    pub fn metres(&self, x: f64, y: f64) -> DVec2 {
        DVec2::new(x, y) * self.spacing
    }

    /// The DEM's size in metres: `width·spacing.x × height·spacing.y` (what paths
    /// are sized to).
    pub fn size_m(&self) -> DVec2 {
        self.metres(
            f64::from(self.geometry.width()),
            f64::from(self.geometry.height()),
        )
    }

    /// A tile's north-west corner `(x, z)` and its size (east–west, north–south),
    /// in metres.
    pub fn tile_extent(&self, tile: TileId) -> (DVec2, DVec2) {
        let (gx, gy) = self.geometry.origin(tile);
        let span =
            (self.geometry.spacing(tile.level()) * u64::from(self.geometry.tile_size())) as f64;
        (self.metres(gx as f64, gy as f64), self.metres(span, span))
    }

    /// The finest-level tile holding the sample nearest to `(x, z)` metres (clamped
    /// to the DEM): where the ground under a camera is read from.
    pub fn finest_tile_at(&self, x: f64, z: f64) -> TileId {
        let g = &self.geometry;
        let sample = |v: f64, s: f64, len: u32| ((v / s).round().max(0.0) as u32).min(len - 1);
        let (fx, fy) = (
            sample(x, self.spacing.x, g.width()),
            sample(z, self.spacing.y, g.height()),
        );
        let finest = g.finest();
        let n = finest.tiles_per_side() - 1;
        TileId::new(
            finest,
            (fx / g.tile_size()).min(n),
            (fy / g.tile_size()).min(n),
        )
        .expect("clamped to the finest level's tiles")
    }

    /// Deepest quadtree level inside a tile: nodes of 64 cells (Kang §4.2), at most 5
    /// so that neighbouring patches never differ by more than the 64 an edge can bridge.
    pub fn max_depth(&self) -> u32 {
        (self.geometry.tile_log2() - 6).min(5)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::select::selector::tests::{tile, world};

    #[test]
    fn spacings_come_from_the_command_line_then_the_dataset_then_the_fallback() {
        let measured = Some(GroundSpacing { x: 63.97, y: 92.63 });
        assert_eq!(
            World::spacing_from(Some(30.0), measured),
            DVec2::splat(30.0),
            "--spacing overrides both axes"
        );
        assert_eq!(
            World::spacing_from(None, measured),
            DVec2::new(63.97, 92.63)
        );
        assert_eq!(
            World::spacing_from(None, None),
            DVec2::splat(FALLBACK_SPACING)
        );
        let nonsense = Some(GroundSpacing {
            x: 0.0,
            y: f64::NAN,
        });
        assert_eq!(
            World::spacing_from(None, nonsense),
            DVec2::splat(FALLBACK_SPACING)
        );
    }

    #[test]
    fn tiles_and_samples_are_placed_with_each_axis_spacing() {
        let w = World {
            spacing: DVec2::new(60.0, 90.0),
            ..world()
        };
        let (origin, size) = w.tile_extent(tile(1, 1, 1));
        assert_eq!(origin, DVec2::new(512.0 * 60.0, 512.0 * 90.0));
        assert_eq!(size, DVec2::new(512.0 * 60.0, 512.0 * 90.0));
        assert_eq!(w.size_m(), DVec2::new(1025.0 * 60.0, 1025.0 * 90.0));
        // 600 m east and 600 m south: sample (10, 7) of the finest grid, tile (1, 0)
        // only east of sample 512.
        assert_eq!(w.finest_tile_at(600.0, 600.0), tile(1, 0, 0));
        assert_eq!(w.finest_tile_at(512.0 * 60.0, 511.0 * 90.0), tile(1, 1, 0));
        assert_eq!(w.finest_tile_at(511.0 * 60.0, 512.0 * 90.0), tile(1, 0, 1));
    }
}
