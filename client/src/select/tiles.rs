//! Pyramid refinement (docs/ARCHITECTURE.md#selection) and balancing of the drawn tiles.

use super::metric::{TileRho, tile_box};
use super::params::SelectParams;
use super::selection::Wanted;
use super::tile_tables::TileTables;
use super::world::World;
use crate::camera::Frustum;
use glam::DVec3;
use std::collections::{HashMap, HashSet};
use tessera_shared::{Level, TileId};

/// The tiles to draw, what to fetch, and which tiles were refined (for hysteresis).
#[derive(Debug, Default)]
pub struct TileChoice {
    pub drawn: Vec<TileId>,
    pub wanted: Vec<Wanted>,
    pub refined: HashSet<TileId>,
    /// `ρ` tables computed on the way, for reuse when building the drawn quadtrees.
    pub rhos: HashMap<TileId, TileRho>,
    /// Tiles in view with nothing drawn in their place (no resident ancestor).
    pub missing: usize,
}

/// The children of `tile` that may have a record: inside the DEM by the geometry
/// and not known to be absent (wholly no-data, [`TileTables::absent`]).
fn present_children(world: &World, tables: &dyn TileTables, tile: TileId) -> Vec<TileId> {
    if tile.level() >= world.geometry.finest() {
        return Vec::new();
    }
    tile.children()
        .map(|c| {
            c.into_iter()
                .filter(|c| world.geometry.is_present(*c) && !tables.absent(*c))
                .collect()
        })
        .unwrap_or_default()
}

fn all_resident(tables: &dyn TileTables, tiles: &[TileId]) -> bool {
    !tiles.is_empty() && tiles.iter().all(|c| tables.table(*c).is_some())
}

/// Asks for the missing children of `tile` and, when the tile misses `τ` by a
/// factor of `excess`, for as many further levels as that factor implies (errors
/// roughly halve per level): one round trip then fetches what would otherwise take
/// one round trip per level. Deeper tiles come with lower priority.
fn want_descendants(
    world: &World,
    tables: &dyn TileTables,
    tile: TileId,
    excess: f64,
    rho: f64,
    wanted: &mut Vec<Wanted>,
) {
    let mut frontier = vec![tile];
    let mut excess = excess;
    let mut rho = rho;
    for _depth in 0..4 {
        let mut next = Vec::new();
        for t in frontier {
            for c in present_children(world, tables, t) {
                if tables.table(c).is_none() {
                    wanted.push(Wanted { tile: c, rho });
                }
                next.push(c);
            }
        }
        excess /= 2.0;
        rho /= 2.0;
        if excess <= 1.0 || next.len() > 64 {
            break;
        }
        frontier = next;
    }
}

/// Most tiles a fallback below unavailable tiles asks for at once (as in
/// [`want_descendants`]): deep enough for the levels a bad root hides, bounded so that
/// a dataset that is corrupt throughout is not asked for in full.
const MAX_FALLBACK: usize = 64;

/// Whether `tile` may be in view, before its error table is known: its extent with
/// every height the quantization can store (nothing tighter is known of a tile
/// that is not resident).
fn may_be_in_view(world: &World, frustum: &Frustum, tile: TileId) -> bool {
    let (origin, size) = world.tile_extent(tile);
    let (a, b) = (world.quant.height(0), world.quant.height(u16::MAX));
    frustum.intersects_box(
        DVec3::new(origin.x, a.min(b), origin.y),
        DVec3::new(origin.x + size.x, a.max(b), origin.y + size.y),
    )
}

/// Where the walk starts: the root when it is resident. Otherwise the root is
/// wanted, and when it cannot be had (its fetch failed, or its record was written
/// off as corrupt) its children stand in for it, and theirs for any of them that
/// cannot be had either, down to [`MAX_FALLBACK`] tiles: the client draws the
/// healthiest level it has instead of nothing
/// (docs/ARCHITECTURE.md#the-client-never-goes-blind). Tiles in view with no resident
/// stand-in are counted as missing; missing ones are wanted with the highest priority,
/// since nothing is drawn there.
fn tops(
    world: &World,
    frustum: &Frustum,
    tables: &dyn TileTables,
    out: &mut TileChoice,
) -> Vec<TileId> {
    let root = TileId::new(Level::ROOT, 0, 0).expect("the root exists");
    let mut tops = Vec::new();
    let mut frontier = vec![root];
    while !frontier.is_empty() {
        let mut next = Vec::new();
        for tile in frontier {
            if tables.table(tile).is_some() {
                tops.push(tile);
                continue;
            }
            // No record, no terrain: nothing to draw there, and no hole.
            if tables.absent(tile) {
                continue;
            }
            if tile != root && !may_be_in_view(world, frustum, tile) {
                continue;
            }
            out.wanted.push(Wanted {
                tile,
                rho: if tile == root {
                    f64::INFINITY
                } else {
                    f64::MAX
                },
            });
            let children = present_children(world, tables, tile);
            if tables.unavailable(tile)
                && !children.is_empty()
                && next.len() + children.len() <= MAX_FALLBACK
            {
                next.extend(children);
            } else {
                out.missing += 1;
            }
        }
        frontier = next;
    }
    tops
}

/// Walks the pyramid from the root (or what stands in for it) and balances the result.
pub fn choose(
    world: &World,
    params: &SelectParams,
    eye: DVec3,
    lambda: f64,
    frustum: &Frustum,
    tables: &dyn TileTables,
    prev_refined: &HashSet<TileId>,
) -> TileChoice {
    let mut out = TileChoice::default();
    let t = world.geometry.tile_log2();
    let mut stack = tops(world, frustum, tables, &mut out);
    while let Some(tile) = stack.pop() {
        let table = tables.table(tile).expect("visited tiles are resident");
        let Some((min, max)) = tile_box(world, tile, table) else {
            continue;
        };
        if !frustum.intersects_box(min, max) {
            continue;
        }
        let rho = TileRho::new(
            world,
            tile,
            table,
            eye,
            lambda,
            world.max_depth(),
            params.policy,
        );
        let children = present_children(world, tables, tile);
        // Refine once the tile would need its finest within-tile level somewhere
        // (level t − 1 misses τ): there its children do the same job with blocks a
        // quarter the size. Waiting until level t itself misses τ draws coarse tiles
        // at full density, which costs more triangles than their children would.
        let need = rho.rho(t - 1, 0, 0, 0);
        out.rhos.insert(tile, rho);
        if children.is_empty() {
            out.drawn.push(tile);
            continue;
        }
        let limit = if prev_refined.contains(&tile) {
            params.tau * (1.0 - params.hysteresis)
        } else {
            params.tau
        };
        if need <= limit {
            out.drawn.push(tile);
        } else if all_resident(tables, &children) {
            out.refined.insert(tile);
            stack.extend(children);
        } else {
            out.drawn.push(tile);
            want_descendants(
                world,
                tables,
                tile,
                need / params.tau,
                need,
                &mut out.wanted,
            );
        }
    }
    balance(world, tables, &mut out);
    out.drawn.sort();
    out
}

/// Makes drawn tiles that share an edge differ by at most one level, so that edge
/// LODs can always bridge them (a patch edge spans at most 64 of its neighbour's).
/// A coarse tile next to much finer ones is refined when its children are resident;
/// otherwise the finer side is coarsened (the deficit shows in the statistics) and
/// the coarse tile's children are requested first.
fn balance(world: &World, tables: &dyn TileTables, choice: &mut TileChoice) {
    let mut drawn: HashSet<TileId> = choice.drawn.iter().copied().collect();
    let mut frozen: HashSet<TileId> = HashSet::new();
    for _round in 0..64 {
        let mut changed = false;
        let tiles: Vec<TileId> = drawn.iter().copied().collect();
        for fine in tiles {
            if !drawn.contains(&fine) {
                continue;
            }
            let Some(coarse) = coarser_neighbour(&drawn, fine) else {
                continue;
            };
            if coarse.level().get() + 1 >= fine.level().get() {
                continue;
            }
            let children = present_children(world, tables, coarse);
            if !frozen.contains(&coarse) && all_resident(tables, &children) {
                drawn.remove(&coarse);
                choice.refined.insert(coarse);
                drawn.extend(children);
            } else {
                // Coarsening costs detail next to `coarse`: its children are what
                // would restore it, so fetch them first.
                for c in children.iter().filter(|c| tables.table(**c).is_none()) {
                    if !choice.wanted.iter().any(|w| w.tile == *c) {
                        choice.wanted.push(Wanted {
                            tile: *c,
                            rho: f64::MAX,
                        });
                    }
                }
                let keep = Level::new(coarse.level().get() + 1).expect("finer than coarse");
                let mut a = fine;
                while a.level() > keep {
                    a = a.parent().expect("level > 0");
                }
                drawn.retain(|t| !is_descendant(*t, a));
                drawn.insert(a);
                frozen.insert(a);
            }
            changed = true;
        }
        if !changed {
            break;
        }
    }
    choice.drawn = drawn.into_iter().collect();
}

fn is_descendant(t: TileId, ancestor: TileId) -> bool {
    if t.level() < ancestor.level() {
        return false;
    }
    let shift = t.level().get() - ancestor.level().get();
    (t.x() >> shift, t.y() >> shift) == (ancestor.x(), ancestor.y())
}

/// The coarsest drawn tile sharing an edge with `tile` and strictly coarser than it.
fn coarser_neighbour(drawn: &HashSet<TileId>, tile: TileId) -> Option<TileId> {
    let n = i64::from(tile.level().tiles_per_side());
    let mut best: Option<TileId> = None;
    for (dx, dy) in [(0i64, -1i64), (1, 0), (0, 1), (-1, 0)] {
        let (x, y) = (i64::from(tile.x()) + dx, i64::from(tile.y()) + dy);
        if x < 0 || y < 0 || x >= n || y >= n {
            continue;
        }
        let mut cell = TileId::new(tile.level(), x as u32, y as u32).expect("inside the level");
        while let Some(p) = cell.parent() {
            cell = p;
            if drawn.contains(&cell) {
                if best.is_none_or(|b| cell.level() < b.level()) {
                    best = Some(cell);
                }
                break;
            }
        }
    }
    best
}
