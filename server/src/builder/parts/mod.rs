//! The distributed build (docs/ARCHITECTURE.md#scale-out):
//! `build INPUT --part K/N -o PARTS/` builds the subtrees of one slice of the split
//! level's Morton codes into a part file, and `build --assemble PARTS/ -o OUT.tess`
//! writes the levels above the split from the parts' roots and then the pyramid, byte for
//! byte the file a single `build` of the same input and options writes (FORMAT.md "Part
//! files", DECISIONS "Distributed build").
//!
//! - **Split.** The split level `S` is the smallest with `4^S ≥ 4N` (four subtrees
//!   a part at least, so the slices can be balanced), at least 1 and at most the
//!   finest. Part `K` gets a contiguous run of level-`S` Morton codes, cut so the
//!   parts hold about as many present finest tiles each ([`Split`]). A subtree is
//!   one contiguous Morton range at every level below `S`, so the pyramid's levels
//!   `≥ S` are the parts' records concatenated in part order.
//! - **Same numbers everywhere.** A part reads only its share of the input (its
//!   subtrees' samples and the coarse-cell corners around them: `share`), whose
//!   samples and quantization are the single build's, unless its share holds no-data
//!   or its float samples have no `--height-range`: it then reads (spools) the whole
//!   input, as the fill and the quantization need. It cuts and encodes only its own
//!   finest tiles, through the same code as a whole build (the builder's `Tiling`).
//! - **Counts.** A part records its share of the DEM-wide numbers: the samples its
//!   level-`S` tiles own, by depth, valid and filled (`split::share`), and the range of
//!   its finest records' heights. Assembling adds and bounds them exactly as the
//!   whole build counts them.
//! - **Safety.** A part file is written beside its final name and renamed into
//!   place only when complete and re-read, so a part that died leaves nothing under
//!   its name and is simply rerun. Assembling refuses a missing part, a duplicate, a
//!   part of another `N` or of other input or options (a fingerprint of the inputs'
//!   identity, metadata and options), and a truncated or corrupt one (header and
//!   trailer checksum, per-record and per-root checksums), naming the file.
//!
//! Modules: [`split`] (`--part K/N` and how the parts divide the pyramid), [`part`]
//! (building one part), [`layout`] (a part file's header, trailer and frames),
//! [`writer`] and [`reader`] (writing and reading a part file), [`assemble`](mod@assemble) (the
//! pyramid from its parts).

pub mod assemble;
pub mod layout;
pub mod part;
pub mod reader;
pub mod split;
pub mod writer;

pub use assemble::assemble;
pub use part::{PartRead, PartReport, build_part};
pub use reader::PartFile;
pub use split::{PartSpec, Split};

use tessera_shared::format::INDEX_ENTRY_LEN;

/// Part files end in `.tesspart`.
pub const EXTENSION: &str = "tesspart";
/// First bytes of a part file.
pub const MAGIC: [u8; 8] = *b"TESSPART";
/// Part file format version (FORMAT.md "Part files").
pub const VERSION: u32 = 2;
/// Fixed header at the start of a part file.
pub const HEADER_LEN: usize = 64;
/// The frame before each record: Morton code, length and index summary.
pub const FRAME_LEN: usize = INDEX_ENTRY_LEN;
/// Most parts one build may have (a Kubernetes Indexed Job's completions are
/// limited to about this many).
pub const MAX_PARTS: u32 = 100_000;
/// Bound on a trailer (its metadata's CRS texts are the only variable part).
const MAX_TRAILER: u64 = 16 << 20;
/// Write buffer of the split-level roots.
const ROOTS_BUFFER: usize = 256 << 10;
