//! View-dependent selection (docs/ARCHITECTURE.md#selection): which tiles, which patches,
//! which LODs.
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
//!
//! [`selector`] runs these steps with memory from frame to frame; [`world`] is the
//! terrain in world units, [`tile_tables`] what selection knows of the tiles,
//! [`params`] its settings, [`metric`] the screen-space error, [`patch`] a patch to
//! draw and [`selection`] what a frame's selection gives.

pub mod edge_lod;
pub mod fade;
pub mod metric;
pub mod morph;
pub mod params;
pub mod patch;
pub mod quadtree;
pub mod selection;
pub mod selector;
pub mod tile_tables;
pub mod tiles;
pub mod world;

pub use params::{MORPH_ERROR_LIMIT, MORPH_SECONDS, Policy, SelectParams};
pub use patch::{EAST, NORTH, Patch, SOUTH, WEST};
pub use selection::{FrameStats, Selection, Wanted};
pub use selector::Selector;
pub use tile_tables::{TileTables, all_tables};
pub use world::{BoxDistance, FALLBACK_SPACING, World};
