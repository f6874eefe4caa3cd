//! Fixtures shared by the end-to-end tests in `tests/`: the moon pyramids built and
//! decoded here, plus [`module_circles`] (the module-circle finder), [`nginx`] (a real nginx serving files on loopback, for the
//! serverless reads), [`quantized_mesh`] (an independent quantized-mesh decoder the
//! Cesium tests check the server's tiles with) and [`terrain_check`] (brute-force
//! checks of Cesium terrain tiles against a DEM's finest samples).

#![allow(clippy::unwrap_used)] // test fixtures: a failed unwrap is a failed test

pub mod module_circles;
pub mod nginx;
pub mod quantized_mesh;
pub mod terrain_check;

use std::collections::HashMap;
use tessera_client::select::World;
use tessera_client::stream::pool::TilePool;
use tessera_server::builder::{BuildOptions, build};
use tessera_shared::{CellMask, ErrorTable, FileSource, Pyramid, TileId, testdata};

/// Metres between samples of the moon mosaics (the data README).
pub const MOON_SPACING: f64 = 118.45;

/// The moon 4096² mosaic built into a pyramid, every tile decoded.
#[derive(Debug)]
pub struct Moon {
    pub pyramid: Pyramid<FileSource>,
    pub tables: HashMap<TileId, ErrorTable>,
    pub heights: HashMap<TileId, Vec<u16>>,
    pub masks: HashMap<TileId, CellMask>,
    pub world: World,
    _dir: tempfile::TempDir,
}

impl Moon {
    /// Builds the pyramid with `tile_size`-cell tiles; `None` (with a SKIPPED
    /// message) when the DEM is not there.
    pub fn build(tile_size: u32) -> Option<Self> {
        let path = testdata::dem_or_skip("moon_crisium_gld100_4096.png")?;
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("moon4k.tess");
        let opts = BuildOptions {
            tile_size,
            offset: -10000.0,
            ..BuildOptions::default()
        };
        build(path.to_str().unwrap(), &out, &opts).unwrap();
        let pyramid = Pyramid::open_file(&out).unwrap();
        let g = *pyramid.geometry();
        let StoredTiles {
            tables,
            heights,
            masks,
        } = StoredTiles::read(&pyramid);
        let world = World {
            geometry: g,
            quant: pyramid.metadata().quantization,
            spacing: glam::DVec2::splat(MOON_SPACING),
            globe: None,
        };
        Some(Self {
            pyramid,
            tables,
            heights,
            masks,
            world,
            _dir: dir,
        })
    }

    /// A tile pool holding every tile.
    pub fn pool(&self) -> TilePool {
        pool_of(&self.tables, &self.heights, &self.masks)
    }
}

/// Every stored tile of a pyramid, decoded (a multi-resolution pyramid's tiles that
/// are not stored are absent here, as they are from the file).
#[derive(Debug, Default)]
pub struct StoredTiles {
    pub tables: HashMap<TileId, ErrorTable>,
    pub heights: HashMap<TileId, Vec<u16>>,
    pub masks: HashMap<TileId, CellMask>,
}

impl StoredTiles {
    pub fn read(pyramid: &Pyramid<FileSource>) -> Self {
        let g = *pyramid.geometry();
        let mut tiles = Self::default();
        for level in g.levels() {
            for tile in g.present_tiles(level) {
                let Some(rec) = pyramid.read_tile(tile).unwrap() else {
                    continue;
                };
                tiles.tables.insert(tile, rec.errors);
                tiles.heights.insert(tile, rec.heights);
                tiles.masks.insert(tile, rec.mask);
            }
        }
        tiles
    }

    /// A tile pool holding every tile.
    pub fn pool(&self) -> TilePool {
        pool_of(&self.tables, &self.heights, &self.masks)
    }
}

fn pool_of(
    tables: &HashMap<TileId, ErrorTable>,
    heights: &HashMap<TileId, Vec<u16>>,
    masks: &HashMap<TileId, CellMask>,
) -> TilePool {
    let mut pool = TilePool::new(tables.len() + 1);
    for (&t, e) in tables {
        pool.insert(t, e.clone(), heights[&t].clone(), masks[&t].clone());
    }
    pool
}

/// A small deterministic generator (SplitMix64), so failures reproduce.
#[derive(Debug)]
pub struct Rng(pub u64);

impl Rng {
    /// Uniform in `[0, 1)`.
    pub fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
}
