//! Typed tile coordinates and the geometry of a pyramid
//! (docs/ARCHITECTURE.md#tiles-and-levels).
//!
//! A tile is `T = 2^t` cells wide (`T + 1` samples; neighbours share border
//! samples). Level `L` covers the padded DEM with `2^L × 2^L` tiles; the finest
//! level `L_max` holds the DEM's own samples, and sample `(i, j)` of level `L`
//! is sample `(2i, 2j)` of level `L + 1` (decimation, not filtering).

use crate::morton::Morton;
use std::fmt;

/// Deepest level the format allows: Morton codes of `2^24 × 2^24` tiles fit a `u64` easily,
/// and `2^24 · 2^12` finest samples per side is far beyond any DEM.
pub const MAX_LEVEL: u8 = 24;
/// Smallest tile: Kang's per-tile quadtree needs depth `t − 6 ≥ 0`
/// (docs/ARCHITECTURE.md#selection).
pub const MIN_TILE_SIZE: u32 = 64;
/// Largest tile: keeps a decoded tile (`(T+1)² · 2` bytes) near 32 MiB.
pub const MAX_TILE_SIZE: u32 = 4096;
/// Error tables hold `BLOCKS × BLOCKS` blocks per within-tile level (Kang §4.1).
pub const BLOCKS: u32 = 8;

/// A pyramid level, `0` = the root (one tile).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Level(u8);

impl Level {
    pub const ROOT: Level = Level(0);

    /// A checked level (`≤ MAX_LEVEL`).
    pub fn new(level: u8) -> Option<Self> {
        (level <= MAX_LEVEL).then_some(Self(level))
    }

    pub const fn get(self) -> u8 {
        self.0
    }

    /// Tiles per side at this level: `2^L`.
    pub const fn tiles_per_side(self) -> u32 {
        1 << self.0
    }

    /// Number of Morton codes at this level: `4^L`.
    pub const fn tile_slots(self) -> u64 {
        1 << (2 * self.0 as u32)
    }

    pub fn finer(self) -> Option<Level> {
        Level::new(self.0 + 1)
    }

    pub fn coarser(self) -> Option<Level> {
        self.0.checked_sub(1).map(Level)
    }
}

impl fmt::Display for Level {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// One tile: a level and `(x, y)` within it (`x` east, `y` south).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct TileId {
    level: Level,
    x: u32,
    y: u32,
}

impl TileId {
    /// A checked tile id: `x, y < 2^level`.
    pub fn new(level: Level, x: u32, y: u32) -> Option<Self> {
        let n = level.tiles_per_side();
        (x < n && y < n).then_some(Self { level, x, y })
    }

    pub fn from_morton(level: Level, m: Morton) -> Option<Self> {
        if m.get() >= level.tile_slots() {
            return None;
        }
        let (x, y) = m.decode();
        Some(Self { level, x, y })
    }

    pub const fn level(self) -> Level {
        self.level
    }

    pub const fn x(self) -> u32 {
        self.x
    }

    pub const fn y(self) -> u32 {
        self.y
    }

    pub const fn morton(self) -> Morton {
        Morton::encode(self.x, self.y)
    }

    pub fn parent(self) -> Option<TileId> {
        Some(Self {
            level: self.level.coarser()?,
            x: self.x / 2,
            y: self.y / 2,
        })
    }

    /// The four children in Morton order, or `None` at the deepest allowed level.
    pub fn children(self) -> Option<[TileId; 4]> {
        let level = self.level.finer()?;
        let (x, y) = (self.x * 2, self.y * 2);
        Some([(x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1)].map(|(x, y)| TileId { level, x, y }))
    }
}

impl fmt::Display for TileId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "level {} tile ({}, {}) morton {}",
            self.level,
            self.x,
            self.y,
            self.morton()
        )
    }
}

/// Why a pyramid geometry was rejected.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GeometryError {
    #[error(
        "tile size {0} is not a power of two between {MIN_TILE_SIZE} and {MAX_TILE_SIZE} cells"
    )]
    TileSize(u32),
    #[error("DEM of {0}×{1} samples is too small: it needs at least 2×2 samples")]
    TooSmall(u32, u32),
    #[error("DEM of {0}×{1} samples needs more than {MAX_LEVEL} levels")]
    TooLarge(u32, u32),
}

/// The shape of a pyramid: DEM size, tile size and number of levels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileGeometry {
    width: u32,
    height: u32,
    tile_size: u32,
    finest: Level,
}

impl TileGeometry {
    /// The geometry for a `width × height`-sample DEM cut into tiles of `tile_size` cells:
    /// the fewest levels whose finest level covers every cell.
    ///
    /// ```
    /// use tessera_shared::TileGeometry;
    /// let g = TileGeometry::new(8192, 8192, 512).unwrap();
    /// assert_eq!(g.finest().get(), 4); // 8191 cells need 16 tiles of 512
    /// assert_eq!(g.padded_samples(), 8193);
    /// ```
    pub fn new(width: u32, height: u32, tile_size: u32) -> Result<Self, GeometryError> {
        if !tile_size.is_power_of_two() || !(MIN_TILE_SIZE..=MAX_TILE_SIZE).contains(&tile_size) {
            return Err(GeometryError::TileSize(tile_size));
        }
        if width < 2 || height < 2 {
            return Err(GeometryError::TooSmall(width, height));
        }
        let cells = u64::from(width.max(height) - 1);
        let tiles = cells.div_ceil(u64::from(tile_size));
        let levels = tiles.next_power_of_two().trailing_zeros();
        let finest = u8::try_from(levels)
            .ok()
            .and_then(Level::new)
            .ok_or(GeometryError::TooLarge(width, height))?;
        Ok(Self {
            width,
            height,
            tile_size,
            finest,
        })
    }

    /// DEM width in samples.
    pub const fn width(&self) -> u32 {
        self.width
    }

    /// DEM height in samples.
    pub const fn height(&self) -> u32 {
        self.height
    }

    /// Tile size `T` in cells (`T + 1` samples per side).
    pub const fn tile_size(&self) -> u32 {
        self.tile_size
    }

    /// `t = log2(T)`.
    pub const fn tile_log2(&self) -> u32 {
        self.tile_size.trailing_zeros()
    }

    /// Samples per tile side, `T + 1`.
    pub const fn tile_samples(&self) -> usize {
        self.tile_size as usize + 1
    }

    pub const fn finest(&self) -> Level {
        self.finest
    }

    /// Number of levels, `L_max + 1`.
    pub const fn level_count(&self) -> u8 {
        self.finest.get() + 1
    }

    pub fn levels(&self) -> impl DoubleEndedIterator<Item = Level> + use<> {
        (0..=self.finest.get()).map(Level)
    }

    /// Samples per side of the padded finest grid: `2^L_max · T + 1`.
    pub const fn padded_samples(&self) -> u64 {
        ((1u64 << self.finest.get()) * self.tile_size as u64) + 1
    }

    /// Distance between neighbouring samples of `level`, in finest samples: `2^(L_max − L)`.
    pub const fn spacing(&self, level: Level) -> u64 {
        1 << (self.finest.get() - level.get())
    }

    /// Finest-grid coordinates of a tile's first sample.
    pub const fn origin(&self, tile: TileId) -> (u64, u64) {
        let span = self.spacing(tile.level) * self.tile_size as u64;
        (tile.x as u64 * span, tile.y as u64 * span)
    }

    /// Whether the tile covers any cell of the DEM (tiles wholly outside are absent).
    pub fn is_present(&self, tile: TileId) -> bool {
        let (x0, y0) = self.origin(tile);
        x0 < u64::from(self.width - 1) && y0 < u64::from(self.height - 1)
    }

    /// All present tiles of a level, in Morton order.
    pub fn present_tiles(&self, level: Level) -> impl Iterator<Item = TileId> + '_ {
        (0..level.tile_slots())
            .filter_map(move |m| TileId::from_morton(level, Morton::from_raw(m)))
            .filter(|t| self.is_present(*t))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_cover_the_dem_with_the_fewest_tiles() {
        // 513 samples = exactly one tile; 514 need two.
        assert_eq!(TileGeometry::new(513, 513, 512).unwrap().finest().get(), 0);
        assert_eq!(TileGeometry::new(514, 100, 512).unwrap().finest().get(), 1);
        assert_eq!(
            TileGeometry::new(65537, 65537, 512).unwrap().finest().get(),
            7
        );
        assert_eq!(TileGeometry::new(1201, 1201, 64).unwrap().finest().get(), 5);
    }

    #[test]
    fn bad_geometries_are_rejected() {
        assert_eq!(
            TileGeometry::new(100, 100, 500),
            Err(GeometryError::TileSize(500))
        );
        assert_eq!(
            TileGeometry::new(100, 100, 32),
            Err(GeometryError::TileSize(32))
        );
        assert_eq!(
            TileGeometry::new(1, 100, 64),
            Err(GeometryError::TooSmall(1, 100))
        );
    }

    #[test]
    fn presence_follows_the_dem_extent() {
        // 1000 × 300 samples, T = 256: finest level 2 (4 × 4 tiles), 4 × 2 present.
        let g = TileGeometry::new(1000, 300, 256).unwrap();
        let finest = g.finest();
        assert_eq!(finest.get(), 2);
        let present: Vec<(u32, u32)> = g.present_tiles(finest).map(|t| (t.x(), t.y())).collect();
        assert_eq!(present.len(), 8);
        assert!(present.iter().all(|&(x, y)| x < 4 && y < 2));
        // The root is always present; the parent of a present tile is present.
        for t in g.present_tiles(finest) {
            assert!(g.is_present(t.parent().unwrap()));
        }
    }

    #[test]
    fn tile_ids_are_checked() {
        let l2 = Level::new(2).unwrap();
        assert!(TileId::new(l2, 3, 3).is_some());
        assert!(TileId::new(l2, 4, 0).is_none());
        assert!(TileId::from_morton(l2, Morton::from_raw(16)).is_none());
        assert!(Level::new(MAX_LEVEL + 1).is_none());
        let t = TileId::new(l2, 2, 3).unwrap();
        assert_eq!(t.children().unwrap()[3].parent(), Some(t));
        assert_eq!(t.to_string(), "level 2 tile (2, 3) morton 14");
    }
}
