//! A patch to draw: a quadtree leaf of a resident tile, with its inner and edge
//! LODs and how far it has morphed towards the next coarser LOD ([`Morph`], see
//! `morph`) and faded into an ancestor's shading ([`Fade`], see `fade`).

use tessera_shared::TileId;

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
    /// How far the patch has morphed towards LOD `inner/2` ([`super::morph`]).
    pub morph: Morph,
    /// How much of an ancestor tile's shading is mixed into the patch's while a
    /// refinement fades in ([`super::fade`]).
    pub fade: Fade,
}

impl Patch {
    /// Triangles drawn (degenerate ones along snapped edges included).
    pub fn triangles(&self) -> u64 {
        2 * u64::from(self.inner) * u64::from(self.inner)
    }
}

/// A factor of 1: the surface is the `n/2` surface. Factors are integers in
/// `0..=FULL`, so that mixing heights is exact integer arithmetic.
pub const FULL: u16 = 256;

/// How far a patch has morphed: its interior, and each side (north, east, south,
/// west), in `1/FULL` steps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Morph {
    pub inner: u16,
    pub edges: [u16; 4],
}

impl Morph {
    /// No morphing: every vertex at its own LOD's height (`--no-morph`).
    pub const NONE: Self = Self {
        inner: 0,
        edges: [0; 4],
    };

    /// A morph with every factor in `0..=FULL`; `None` otherwise.
    pub fn new(inner: u16, edges: [u16; 4]) -> Option<Self> {
        (inner <= FULL && edges.iter().all(|&e| e <= FULL)).then_some(Self { inner, edges })
    }
}

/// How a patch's shading mixes in an ancestor's: `up` levels up (0: none), by
/// `factor` in `0..=`[`FULL`] (`FULL`: wholly the ancestor's).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Fade {
    pub up: u8,
    pub factor: u16,
}

impl Fade {
    /// Shaded as itself.
    pub const NONE: Self = Self { up: 0, factor: 0 };

    /// A fade from the ancestor `up` levels up; `None` unless `1 ≤ up` and the
    /// factor is in `1..=FULL` (a factor of 0 is [`Fade::NONE`]).
    pub fn new(up: u8, factor: u16) -> Option<Self> {
        (up >= 1 && (1..=FULL).contains(&factor)).then_some(Self { up, factor })
    }

    /// The ancestor whose shading is mixed in, and the tile's offset among its
    /// `2^up × 2^up` descendants; `None` without a fade.
    pub fn source(self, tile: TileId) -> Option<(TileId, [u32; 2])> {
        if self.factor == 0 || self.up == 0 {
            return None;
        }
        let mut a = tile;
        for _ in 0..self.up {
            a = a.parent()?;
        }
        let up = u32::from(self.up);
        Some((a, [tile.x() - (a.x() << up), tile.y() - (a.y() << up)]))
    }
}
