//! View-dependent selection (DESIGN §5): which tiles, which patches, which LODs.
//!
//! Each frame:
//! 1. [`tiles`]: walk the pyramid from the root; refine a tile into its children
//!    when its within-tile level `t − 1` misses `τ` (DECISIONS.md: drawing a coarse
//!    tile at full density costs more than its children) and they are resident,
//!    otherwise draw it and ask for the children. Then balance, so that drawn
//!    tiles sharing an edge are at most one level apart.
//! 2. [`quadtree`]: inside each drawn tile, Kang's quadtree (depth ≤ t − 6): the
//!    smallest power-of-two inner LOD ≤ 64 that meets `τ`, split where 64 is not
//!    enough, with hysteresis from the previous frame (Kang §4.4, Alg. 1–2).
//! 3. [`edge_lod`]: edge LODs so that both sides of every shared edge produce the
//!    same vertices (Kang §4.3), across tiles and pyramid levels too.
//! 4. [`morph`]: how far each patch, and each shared side, has morphed towards
//!    the next coarser LOD (CDLOD's morph, run over time from what the last frame
//!    drew), so that LOD changes do not pop; [`fade`]: a refined tile's shading
//!    mixed with its parent's while it comes in.

pub mod edge_lod;
pub mod fade;
pub mod metric;
pub mod morph;
pub mod quadtree;
pub mod tiles;

use crate::camera::Camera;
use anyhow::Context;
use glam::DVec2;
use std::collections::{HashMap, HashSet};
use std::time::Instant;
use tessera_shared::api::DatasetInfo;
use tessera_shared::{
    ByteSource, ErrorTable, GroundSpacing, Pyramid, Quantization, TileGeometry, TileId,
};

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
    /// The body and grid when the dataset is drawn on the globe (issue 17 item 4):
    /// boxes are then curved shells ([`crate::globe::volume`]).
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
    pub fn from_dataset(info: &DatasetInfo, stated: Option<f64>) -> anyhow::Result<Self> {
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
    ) -> anyhow::Result<Self> {
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

/// Error tables of the tiles that are resident (decoded and available).
pub trait TileTables {
    fn table(&self, tile: TileId) -> Option<&ErrorTable>;

    /// Whether a tile that is not resident cannot be had for now: its last fetch
    /// failed (it is backing off) or its record was written off as corrupt. The
    /// selection then draws that tile's resident children in its place, so that
    /// a bad root does not blind the client (DESIGN §8: the client draws the
    /// healthiest level it has).
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
) -> anyhow::Result<HashMap<TileId, ErrorTable>> {
    let g = *pyramid.geometry();
    let mut tables = HashMap::new();
    for level in g.levels() {
        for tile in g.present_tiles(level) {
            if let Some(t) = pyramid
                .read_error_table(tile)
                .with_context(|| format!("reading the error table of {tile}"))?
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

/// How detail is chosen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Policy {
    /// Screen-space error from the error tables: `ρ = ε·λ/d ≤ τ` (DESIGN §5).
    #[default]
    ScreenError,
    /// Distance only (the brute-force policy Kang compares against): a cell's own
    /// size stands in for its error, so `τ` bounds the on-screen size of a cell
    /// whatever the terrain's roughness.
    Distance,
}

/// Selection settings.
#[derive(Clone, Copy, Debug)]
pub struct SelectParams {
    /// Screen-space error threshold `τ` in pixels.
    pub tau: f64,
    /// Hysteresis: a finer choice is only given up once the coarser one is below
    /// `τ·(1 − hysteresis)`.
    pub hysteresis: f64,
    pub policy: Policy,
    /// Seconds a geomorph transition takes ([`morph::transition`]): a patch that
    /// replaces a coarser surface starts as that surface and morphs to its own
    /// LOD in this time (of the clock given to [`Selector::select_at`]); 0 for
    /// none.
    pub morph_seconds: f64,
    /// Whether patches also slide towards `n/2` across a band of distance (CDLOD,
    /// [`morph::patch_factor`]) rather than only over time. Off by default: on
    /// the moon descent it changed the popping figures by nothing measurable
    /// once transitions run over time, and it cost 1 dB of PSNR at `τ = 1`, since
    /// it draws every patch in its band coarser than its LOD (DECISIONS.md
    /// "Geomorphing over time").
    pub morph_by_distance: bool,
    /// The most error a transition may draw, as a multiple of `τ` (at least 1):
    /// a refined patch starts as the old surface only as far as its `ρ` there
    /// stays within `morph_error_limit·τ`, and jumps the rest of the way
    /// ([`morph::transition`]). Without a limit, transitions lagged fast flight
    /// (moon `canyon` at 150 ms: 37% of frames within τ as drawn and 90% within
    /// 2τ, against 96% and 100% as selected).
    pub morph_error_limit: f64,
}

/// [`SelectParams::morph_seconds`] unless told otherwise.
pub const MORPH_SECONDS: f64 = 0.25;

/// [`SelectParams::morph_error_limit`] unless told otherwise: `τ` itself, so that
/// the surface as drawn keeps `τ` wherever the selected LODs do. On the moon
/// descent of `bench/popping.sh` it popped as little as no limit (same-camera
/// excess 0.012 both ways: a refinement starts where `ρ_{n/2}` has only just
/// passed `τ`, nearly at the old surface), and it cut only the transitions that
/// lagged fast flight (DECISIONS.md "Geomorphing over time").
pub const MORPH_ERROR_LIMIT: f64 = 1.0;

impl Default for SelectParams {
    fn default() -> Self {
        Self {
            tau: 1.0,
            hysteresis: 0.15,
            policy: Policy::ScreenError,
            morph_seconds: MORPH_SECONDS,
            morph_by_distance: false,
            morph_error_limit: MORPH_ERROR_LIMIT,
        }
    }
}

impl SelectParams {
    /// Whether geomorph transitions run over time (a positive, finite duration).
    pub fn transitions(&self) -> bool {
        self.morph_seconds > 0.0 && self.morph_seconds.is_finite()
    }
}

/// Sides of a patch: north (`y` = origin), east, south, west.
pub const NORTH: usize = 0;
pub const EAST: usize = 1;
pub const SOUTH: usize = 2;
pub const WEST: usize = 3;

/// One quad patch to draw: a quadtree leaf of a resident tile.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Patch {
    pub tile: TileId,
    /// First sample of the patch, in the tile's samples.
    pub origin: [u32; 2],
    /// Side in tile cells (a power of two, ≥ 64).
    pub size: u32,
    /// Inner LOD `n`: the patch is an `n × n` grid (1, 2, 4, …, 64).
    pub inner: u32,
    /// Edge LODs (north, east, south, west), each a power of two `≤ inner`.
    pub edges: [u32; 4],
    /// How far the patch has morphed towards LOD `inner/2` ([`morph`]).
    pub morph: morph::Morph,
    /// How much of an ancestor tile's shading is mixed into the patch's while a
    /// refinement fades in ([`fade`]).
    pub fade: fade::Fade,
}

impl Patch {
    /// Triangles drawn (degenerate ones along snapped edges included).
    pub fn triangles(&self) -> u64 {
        2 * u64::from(self.inner) * u64::from(self.inner)
    }
}

/// A tile the selection wants and does not have, with how much it is wanted (the
/// screen-space error of what is drawn in its place).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wanted {
    pub tile: TileId,
    pub rho: f64,
}

/// Per-frame statistics (DESIGN §6 invariant 4: the deficit is reported, never hidden;
/// §8: what could not be had is reported as missing, not as a huge number).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrameStats {
    pub tiles: usize,
    pub patches: usize,
    pub triangles: u64,
    /// Coarsest pyramid level drawn (`None` when nothing is drawn): 0 once the
    /// root is resident, 1 or finer while a bad root is drawn through its children.
    #[serde(default)]
    pub coarsest_level: Option<u8>,
    /// Largest screen-space error of anything drawn, in pixels. `None` ("missing")
    /// when it has no bound: part of the view has nothing drawn at all
    /// (`missing > 0`), or the eye is inside the error box of a coarse tile drawn in
    /// place of missing children (`ρ = ε·λ/d` with `d = 0`).
    pub max_rho: Option<f64>,
    /// `max_rho / τ`: above 1 while what is needed is still streaming; `None` with
    /// `max_rho`.
    pub deficit: Option<f64>,
    /// [`FrameStats::max_rho`] of the surface as drawn, geomorph transitions
    /// included (DESIGN §6 invariant 4: the deficit is never hidden): while a
    /// patch's transition runs it is drawn part-way to the next coarser grid, and
    /// its bound is the mix of the two grids' ([`morph::drawn_rho`]). Equal to
    /// `max_rho` when no transition is in flight; `None` with it.
    #[serde(default)]
    pub drawn_max_rho: Option<f64>,
    /// `drawn_max_rho / τ`.
    #[serde(default)]
    pub drawn_deficit: Option<f64>,
    /// Tiles in view with nothing drawn in their place (no resident ancestor): the
    /// root before it arrives, or the parts of a bad root's children that have not
    /// arrived or cannot be had.
    #[serde(default)]
    pub missing: usize,
    pub select_us: f64,
}

impl FrameStats {
    /// Whether the frame drew something and every drawn error is within `limit·τ`.
    pub fn within(&self, limit: f64) -> bool {
        self.tiles > 0 && self.deficit.is_some_and(|d| d <= limit)
    }

    /// [`FrameStats::within`] for the surface as drawn, transitions included.
    pub fn drawn_within(&self, limit: f64) -> bool {
        self.tiles > 0 && self.drawn_deficit.is_some_and(|d| d <= limit)
    }
}

/// What to draw this frame.
#[derive(Clone, Debug, Default)]
pub struct Selection {
    pub tiles: Vec<TileId>,
    /// The patches as drawn: at the inner LODs and factors of geomorphing.
    pub patches: Vec<Patch>,
    /// The same patches at the inner and edge LODs selection chose, before
    /// geomorph transitions raised any ([`morph::transition`]): what selection
    /// decided, which the popping metric compares from frame to frame.
    pub chosen: Vec<Patch>,
    pub wanted: Vec<Wanted>,
    pub stats: FrameStats,
}

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
mod tests {
    use super::*;
    use glam::DVec3;
    use tessera_shared::Level;

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

    fn tile(l: u8, x: u32, y: u32) -> TileId {
        TileId::new(Level::new(l).unwrap(), x, y).unwrap()
    }

    /// Two levels of 512-cell tiles over 10 km, heights 100–200 m.
    fn world() -> World {
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
