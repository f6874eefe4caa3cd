//! Contour lines of a tile's heights, as Mapbox Vector Tiles (DECISIONS.md "Contour
//! tiles"): the levels to draw at a zoom ([`interval`]), the lines through a grid of
//! heights ([`march`]), fewer vertices where the screen cannot tell
//! ([`simplify`]), and the tile ([`vector_tile`]).
//!
//! A contour tile's work is bounded before any line is traced: [`march::Contouring::segments`]
//! counts the line segments the tile would hold in one pass over its cells, and a
//! count above [`march::MAX_SEGMENTS`] is refused (a hostile `interval=` costs one
//! sampled grid and one count, like any tile, never an unbounded trace).

pub mod interval;
pub mod march;
pub mod simplify;
pub mod vector_tile;
