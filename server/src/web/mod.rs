//! Standard web-map tiles derived on the fly from a pyramid
//! (docs/ARCHITECTURE.md#derived-outputs, DECISIONS.md "Standard-grid web tiles"): the
//! OGC grids ([`tile_matrix`]), where a dataset lies in them ([`footprint`]), one output
//! tile's heights ([`resample`]), their colours ([`encoding`]), and terrain drawn
//! from them for 2-D maps ([`render`]).

pub mod contour;
pub mod encoding;
pub mod footprint;
pub mod render;
pub mod resample;
pub mod tile_matrix;
pub mod upsample;
