//! Selection with memory: quadtrees and refinements carried from frame to frame,
//! and what was drawn, for the geomorph transitions and fades of the next frame.

use super::params::SelectParams;
use super::patch::Patch;
use super::selection::{FrameStats, Selection};
use super::tile_tables::TileTables;
use super::world::World;
use super::{edge_lod, fade, metric, morph, quadtree, tiles};
use crate::camera::Camera;
use std::collections::{HashMap, HashSet};
use std::time::Instant;
use tessera_shared::TileId;

/// Selection with memory: quadtrees and refinements carried from frame to frame,
/// and, with time ([`Selector::select_at`]), what was drawn ([`morph::Drawn`]).
#[derive(Clone, Debug)]
pub struct Selector {
    pub world: World,
    pub params: SelectParams,
    quadtrees: HashMap<TileId, quadtree::TileState>,
    refined: HashSet<TileId>,
    /// The last frame before the latest call's time: what transitions start from.
    before: Option<Memory>,
    /// The latest call's selection (becomes `before` when time moves on).
    latest: Option<Memory>,
}

/// What a frame selected with a time drew, for the transitions of the next.
#[derive(Clone, Debug)]
struct Memory {
    drawn: morph::Drawn,
    fades: fade::Fades,
}

impl Selector {
    pub fn new(world: World, params: SelectParams) -> Self {
        Self {
            world,
            params,
            quadtrees: HashMap::new(),
            refined: HashSet::new(),
            before: None,
            latest: None,
        }
    }

    /// Selects what to draw for `camera` from the resident `tables`, without a
    /// clock: as if every call came long after the last, so no geomorph
    /// transition or shading fade is ever in flight and every factor is the
    /// distance factor alone (0 without [`SelectParams::morph_by_distance`];
    /// benchmarks of selection, tools, the prefetch look-ahead). It forgets what
    /// [`Selector::select_at`] drew.
    pub fn select(&mut self, camera: &Camera, tables: &dyn TileTables) -> Selection {
        self.before = None;
        self.latest = None;
        self.select_inner(camera, tables, None)
    }

    /// Selects what to draw at time `t` (seconds on the caller's clock: a
    /// flight's time at a fixed frame rate, or the wall clock), with geomorph
    /// transitions ([`morph::transition`]) from the last frame selected at an
    /// earlier time. Calls at the same `t` (a settled frame selecting again as
    /// tiles arrive) all start from that frame, so they neither advance
    /// transitions nor start any from a selection that was never drawn: the
    /// last call at a time is taken to be the one drawn.
    pub fn select_at(&mut self, camera: &Camera, tables: &dyn TileTables, t: f64) -> Selection {
        if self.latest.as_ref().is_some_and(|m| m.drawn.t != t) {
            self.before = self.latest.take();
        }
        self.select_inner(camera, tables, Some(t))
    }

    fn select_inner(
        &mut self,
        camera: &Camera,
        tables: &dyn TileTables,
        t: Option<f64>,
    ) -> Selection {
        let started = Instant::now();
        let eye = camera.position;
        let lambda = camera.lambda();
        let frustum = self.world.frustum(camera);
        let mut choice = tiles::choose(
            &self.world,
            &self.params,
            eye,
            lambda,
            &frustum,
            tables,
            &self.refined,
        );
        self.refined = std::mem::take(&mut choice.refined);
        let mut patches = Vec::new();
        let mut max_rho = 0f64;
        let mut next_state = HashMap::with_capacity(choice.drawn.len());
        let mut rhos = HashMap::with_capacity(choice.drawn.len());
        for &tile in &choice.drawn {
            let rho = choice.rhos.remove(&tile).unwrap_or_else(|| {
                let table = tables.table(tile).expect("drawn tiles are resident");
                metric::TileRho::new(
                    &self.world,
                    tile,
                    table,
                    eye,
                    lambda,
                    self.world.max_depth(),
                    self.params.policy,
                )
            });
            let prev = self.quadtrees.remove(&tile);
            let (state, r) = quadtree::build(
                &self.world,
                &self.params,
                tile,
                &rho,
                prev.as_ref(),
                &mut patches,
            );
            max_rho = max_rho.max(r);
            next_state.insert(tile, state);
            rhos.insert(tile, rho);
        }
        self.quadtrees = next_state;
        edge_lod::assign(&self.world, &mut patches);
        let chosen = patches.clone();
        let drawn = morph::assign(
            &self.world,
            &self.params,
            &mut patches,
            &rhos,
            self.before.as_ref().map(|m| &m.drawn),
            t,
        );
        self.latest = drawn.zip(t).map(|(drawn, t)| {
            let fades = match &self.before {
                Some(before) => fade::Fades::next(&before.fades, &choice.drawn, t),
                None => fade::Fades::settled(&choice.drawn),
            };
            for p in &mut patches {
                p.fade = fades.at(&self.params, p.tile, t);
            }
            Memory { drawn, fades }
        });
        // A hole has no bound on its error, and neither has a stand-in whose error
        // box holds the eye: say "missing" rather than print a number.
        let bounded = choice.missing == 0 && max_rho.is_finite();
        let max_rho = bounded.then_some(max_rho);
        let drawn_max_rho = max_rho.map(|r| r.max(morph::drawn_rho(&self.world, &patches, &rhos)));
        let stats = FrameStats {
            tiles: choice.drawn.len(),
            patches: patches.len(),
            triangles: patches.iter().map(Patch::triangles).sum(),
            coarsest_level: choice.drawn.iter().map(|t| t.level().get()).min(),
            max_rho,
            deficit: max_rho.map(|r| r / self.params.tau),
            drawn_max_rho,
            drawn_deficit: drawn_max_rho.map(|r| r / self.params.tau),
            missing: choice.missing,
            select_us: started.elapsed().as_secs_f64() * 1e6,
        };
        Selection {
            tiles: choice.drawn,
            patches,
            chosen,
            wanted: choice.wanted,
            stats,
        }
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use glam::DVec2;
    use glam::DVec3;
    use tessera_shared::Level;
    use tessera_shared::{ErrorTable, Quantization, TileGeometry};

    /// Resident tables, and tiles that cannot be had (the pool's view of both).
    #[derive(Default)]
    struct Tables {
        resident: HashMap<TileId, ErrorTable>,
        unavailable: HashSet<TileId>,
        absent: HashSet<TileId>,
    }

    impl TileTables for Tables {
        fn table(&self, tile: TileId) -> Option<&ErrorTable> {
            self.resident.get(&tile)
        }
        fn unavailable(&self, tile: TileId) -> bool {
            self.unavailable.contains(&tile)
        }
        fn absent(&self, tile: TileId) -> bool {
            self.absent.contains(&tile)
        }
    }

    pub(in crate::select) fn tile(l: u8, x: u32, y: u32) -> TileId {
        TileId::new(Level::new(l).unwrap(), x, y).unwrap()
    }

    /// Two levels of 512-cell tiles over 10 km, heights 100–200 m.
    pub(in crate::select) fn world() -> World {
        World {
            geometry: TileGeometry::new(1025, 1025, 512).unwrap(),
            quant: Quantization {
                offset: 0.0,
                scale: 1.0,
                max_error: 0.0,
            },
            spacing: DVec2::splat(10.0),
            globe: None,
        }
    }

    /// Every mesh off by 20 m except, on the finest level, full resolution (the
    /// DEM itself); a coarser tile's full resolution is still 10 m off.
    fn table(level: u8) -> ErrorTable {
        let mut t = ErrorTable::empty(9);
        let full = if level == 1 { 0.0 } else { 10.0 };
        for n in 0..=9 {
            for b in 0..64 {
                t.set_error(n, b % 8, b / 8, if n == 9 { full } else { 20.0 });
                t.set_block_range(b % 8, b / 8, 100, 200);
            }
        }
        t
    }

    fn level_one() -> Vec<TileId> {
        vec![tile(1, 0, 0), tile(1, 1, 0), tile(1, 0, 1), tile(1, 1, 1)]
    }

    /// Over the middle of the terrain at `height`, looking down steeply.
    fn camera(height: f64) -> Camera {
        Camera {
            position: DVec3::new(5120.0, height, 5120.0),
            yaw: 0.0,
            pitch: -1.2,
            fovy: 60f64.to_radians(),
            width: 960,
            height: 540,
            near: 1.0,
            far: 100_000.0,
        }
    }

    fn select(tables: &Tables, height: f64) -> Selection {
        Selector::new(world(), SelectParams::default()).select(&camera(height), tables)
    }

    #[test]
    fn without_the_root_nothing_is_drawn_and_the_deficit_is_missing() {
        let s = select(&Tables::default(), 3000.0);
        assert!(s.tiles.is_empty());
        assert_eq!(s.wanted.len(), 1, "only the root is asked for at first");
        assert_eq!(s.wanted[0].tile, tile(0, 0, 0));
        assert_eq!(s.stats.missing, 1);
        assert_eq!((s.stats.max_rho, s.stats.deficit), (None, None));
        assert!(!s.stats.within(1.0));
    }

    #[test]
    fn an_unavailable_root_is_drawn_through_its_children() {
        let mut tables = Tables::default();
        tables.unavailable.insert(tile(0, 0, 0));
        tables
            .resident
            .extend(level_one().into_iter().map(|t| (t, table(1))));
        let s = select(&tables, 3000.0);
        let mut drawn = s.tiles.clone();
        drawn.sort_by_key(|t| t.morton());
        assert_eq!(drawn, level_one(), "the root's children stand in for it");
        assert_eq!(s.stats.coarsest_level, Some(1));
        assert_eq!(s.stats.missing, 0);
        assert!(s.stats.max_rho.is_some_and(f64::is_finite));
        assert!(
            s.wanted.iter().any(|w| w.tile == tile(0, 0, 0)),
            "the root is still asked for (the streamer decides when)"
        );

        // One child cannot be had either: the other three are drawn, the hole is
        // missing, and so is the deficit.
        tables.resident.remove(&tile(1, 1, 1));
        tables.unavailable.insert(tile(1, 1, 1));
        let s = select(&tables, 3000.0);
        assert_eq!(s.tiles.len(), 3);
        assert_eq!(s.stats.missing, 1);
        assert_eq!(s.stats.max_rho, None);
        assert!(s.wanted.iter().any(|w| w.tile == tile(1, 1, 1)));
    }

    #[test]
    fn the_error_of_a_stand_in_around_the_eye_is_missing_not_huge() {
        // The eye at 150 m is inside the root's box (100–200 m widened by 20 m).
        let mut tables = Tables::default();
        tables.resident.insert(tile(0, 0, 0), table(0));
        let s = select(&tables, 150.0);
        assert_eq!(s.tiles, [tile(0, 0, 0)]);
        assert_eq!(s.stats.missing, 0);
        assert_eq!(s.stats.max_rho, None, "{:?}", s.stats);
        assert!(!s.wanted.is_empty());
        // Everything resident: full resolution around the eye, a bounded error.
        tables
            .resident
            .extend(level_one().into_iter().map(|t| (t, table(1))));
        let s = select(&tables, 150.0);
        assert_eq!(s.stats.coarsest_level, Some(1));
        assert!(s.wanted.is_empty());
        let rho = s.stats.max_rho.expect("bounded with everything resident");
        assert!(rho <= SelectParams::default().tau, "{rho}");
    }

    #[test]
    fn absent_tiles_are_neither_waited_for_nor_holes() {
        // The root misses τ from 3 km; three children are resident and the fourth
        // has no record (wholly no-data): the root is refined into the three, the
        // fourth is not asked for, and nothing is missing.
        let mut tables = Tables::default();
        tables.resident.insert(tile(0, 0, 0), table(0));
        let [a, b, c, d] = level_one().try_into().unwrap();
        tables.resident.extend([a, b, c].map(|t| (t, table(1))));
        tables.absent.insert(d);
        let s = select(&tables, 3000.0);
        let mut drawn = s.tiles.clone();
        drawn.sort_by_key(|t| t.morton());
        assert_eq!(drawn, [a, b, c], "refined into the present children");
        assert!(s.wanted.is_empty(), "{:?}", s.wanted);
        assert_eq!(s.stats.missing, 0);
        assert!(s.stats.max_rho.is_some_and(f64::is_finite));

        // Standing in for an unavailable root, an absent child is no hole either.
        tables.resident.remove(&tile(0, 0, 0));
        tables.unavailable.insert(tile(0, 0, 0));
        let s = select(&tables, 3000.0);
        assert_eq!(s.tiles.len(), 3);
        assert_eq!(s.stats.missing, 0);
        assert!(s.wanted.iter().all(|w| w.tile != d));
        assert!(s.stats.max_rho.is_some());
    }
}
