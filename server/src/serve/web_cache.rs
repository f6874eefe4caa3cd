//! What the standard-grid web tiles share across requests
//! (DECISIONS.md "Standard-grid web tiles"): each dataset's [`Footprint`], a bounded LRU
//! of decoded pyramid tiles — so a map's burst of neighbouring requests decodes each
//! source tile once — and a bounded LRU of made tiles. Both caches are weighed in bytes;
//! their sizes, hits and misses are in `/metrics`.

use crate::cesium::terrain::water::WaterRule;
use crate::cesium::terrain::{Terrain, TerrainError};
use crate::cesium::tiling::CesiumTile;
use crate::geoid::Geoid;
use crate::web::encoding::{Encoding, NoData, TileFormat};
use crate::web::footprint::Footprint;
use crate::web::render::ramp::RampSpec;
use crate::web::resample::SourceTile;
use crate::web::tile_matrix::WebTile;
use bytes::Bytes;
use prometheus::{IntCounterVec, IntGaugeVec, Opts, Registry};
use quick_cache::Weighter;
use quick_cache::sync::Cache;
use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex, PoisonError};
use tessera_shared::TileId;

/// What a request for a tile that holds no data gets.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Deserialize)]
pub enum EmptyTiles {
    /// 404 with a JSON reason (MapLibre and GDAL treat it as "no tile here").
    #[default]
    #[value(name = "404")]
    #[serde(rename = "404")]
    NotFound,
    /// 204 No Content (some CDNs cache 204s more readily than 404s).
    #[value(name = "204")]
    #[serde(rename = "204")]
    NoContent,
}

/// The web tiles' settings (`serve --empty-tiles`, `--attribution`, cache sizes).
#[derive(Clone, Debug)]
pub struct WebConfig {
    pub empty_tiles: EmptyTiles,
    /// Shown by maps (TileJSON `attribution`, HTML escaped there).
    pub attribution: Option<String>,
    pub source_cache_bytes: u64,
    pub tile_cache_bytes: u64,
    /// The EPSG96 geoid grid for Cesium terrain heights (`--geoid`), when found.
    pub geoid: Option<Arc<Geoid>>,
    /// What Cesium terrain's water masks mark as water (`--water`, `--no-data-water`,
    /// `--sea-level`); none set: no masks.
    pub water: WaterRule,
    /// Colour ramps loaded from files (`--ramp NAME=FILE`), besides the built-in ones.
    pub ramps: Arc<BTreeMap<String, RampSpec>>,
}

impl Default for WebConfig {
    fn default() -> Self {
        Self {
            empty_tiles: EmptyTiles::NotFound,
            attribution: None,
            source_cache_bytes: 256 << 20,
            tile_cache_bytes: 64 << 20,
            geoid: None,
            water: WaterRule::default(),
            ramps: Arc::default(),
        }
    }
}

/// A dataset's identity in the caches: its content hash (16 hex digits, checked
/// when the file is opened), so a reloaded file never meets its old tiles.
pub fn dataset_key(content_hash: &str) -> u64 {
    u64::from_str_radix(content_hash, 16).unwrap_or_default()
}

/// A made tile's identity.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct MadeKey {
    pub dataset: u64,
    pub tile: WebTile,
    pub px: u32,
    pub look: Look,
    pub format: TileFormat,
}

/// What a made tile's pixels are.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Look {
    /// Encoded heights (routes/web_grid.rs).
    Heights(Encoding, NoData),
    /// Rendered terrain (routes/rendered.rs): a 128-bit hash of the layer's canonical
    /// description, options and resolved ramp included.
    Rendered(u128),
    /// Contour lines (routes/contours.rs): a 128-bit hash of their canonical
    /// description.
    Contours(u128),
}

/// A made Cesium terrain tile's identity: the tile and the extensions it carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TerrainKey {
    pub dataset: u64,
    pub tile: CesiumTile,
    pub normals: bool,
    pub water_mask: bool,
    pub metadata: bool,
}

#[derive(Clone, Copy, Debug)]
struct SourceBytes;

impl Weighter<(u64, TileId), Arc<SourceTile>> for SourceBytes {
    fn weight(&self, _: &(u64, TileId), v: &Arc<SourceTile>) -> u64 {
        v.bytes().max(1)
    }
}

#[derive(Clone, Copy, Debug)]
struct MadeBytes;

impl Weighter<MadeKey, Bytes> for MadeBytes {
    fn weight(&self, _: &MadeKey, v: &Bytes) -> u64 {
        // An empty tile (no data) still holds its key.
        v.len() as u64 + 64
    }
}

#[derive(Clone, Copy, Debug)]
struct TerrainBytes;

impl Weighter<TerrainKey, Bytes> for TerrainBytes {
    fn weight(&self, _: &TerrainKey, v: &Bytes) -> u64 {
        v.len() as u64 + 64
    }
}

/// Why a dataset has no footprint (no place on the standard grids): the error of
/// [`Footprint::new`], kept beside the footprints made and cloned to each asker.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{0:#}")]
pub struct NoFootprint(Arc<anyhow::Error>);

/// The shared state of the web tiles.
pub struct WebTiles {
    pub config: WebConfig,
    footprints: Mutex<HashMap<u64, Result<Arc<Footprint>, NoFootprint>>>,
    terrains: Mutex<HashMap<u64, Result<Arc<Terrain>, TerrainError>>>,
    terrain_tiles: Cache<TerrainKey, Bytes, TerrainBytes>,
    sources: Cache<(u64, TileId), Arc<SourceTile>, SourceBytes>,
    made: Cache<MadeKey, Bytes, MadeBytes>,
    /// `tessera_web_cache_bytes{cache=source|tile}`.
    bytes: IntGaugeVec,
    /// `tessera_web_cache_requests_total{cache, result=hit|miss}`.
    lookups: IntCounterVec,
}

impl std::fmt::Debug for WebTiles {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WebTiles")
            .field("config", &self.config)
            .field("source_bytes", &self.sources.weight())
            .field("tile_bytes", &self.made.weight())
            .finish_non_exhaustive()
    }
}

/// An estimate of entries for the caches' tables (they are bounded by weight).
fn estimated_items(bytes: u64, typical: u64) -> usize {
    usize::try_from(bytes / typical)
        .unwrap_or(usize::MAX)
        .clamp(16, 1 << 20)
}

impl WebTiles {
    /// Empty caches of the configured sizes, their metrics registered in `registry`.
    pub fn new(config: WebConfig, registry: &Registry) -> Self {
        let bytes = IntGaugeVec::new(
            Opts::new(
                "tessera_web_cache_bytes",
                "Bytes held by the web tiles' caches (source: decoded pyramid tiles; tile: made tiles)",
            ),
            &["cache"],
        )
        .expect("valid metric");
        let lookups = IntCounterVec::new(
            Opts::new(
                "tessera_web_cache_requests_total",
                "Lookups in the web tiles' caches, by cache and result",
            ),
            &["cache", "result"],
        )
        .expect("valid metric");
        registry
            .register(Box::new(bytes.clone()))
            .expect("metric names are unique");
        registry
            .register(Box::new(lookups.clone()))
            .expect("metric names are unique");
        for cache in ["source", "tile", "terrain"] {
            bytes.with_label_values(&[cache]).set(0);
            for result in ["hit", "miss"] {
                lookups.with_label_values(&[cache, result]).inc_by(0);
            }
        }
        Self {
            sources: Cache::with_weighter(
                estimated_items(config.source_cache_bytes, 256 << 10),
                config.source_cache_bytes,
                SourceBytes,
            ),
            made: Cache::with_weighter(
                estimated_items(config.tile_cache_bytes, 64 << 10),
                config.tile_cache_bytes,
                MadeBytes,
            ),
            terrain_tiles: Cache::with_weighter(
                estimated_items(config.tile_cache_bytes, 32 << 10),
                config.tile_cache_bytes,
                TerrainBytes,
            ),
            config,
            footprints: Mutex::new(HashMap::new()),
            terrains: Mutex::new(HashMap::new()),
            bytes,
            lookups,
        }
    }

    /// The footprint of the dataset with this content hash, made once.
    pub fn footprint(
        &self,
        content_hash: &str,
        make: impl FnOnce() -> anyhow::Result<Footprint>,
    ) -> Result<Arc<Footprint>, NoFootprint> {
        let key = dataset_key(content_hash);
        let mut map = self
            .footprints
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        map.entry(key)
            .or_insert_with(|| make().map(Arc::new).map_err(|e| NoFootprint(Arc::new(e))))
            .clone()
    }

    /// The Cesium terrain plan of the dataset with this content hash, made once.
    pub fn terrain(
        &self,
        content_hash: &str,
        make: impl FnOnce() -> Result<Terrain, TerrainError>,
    ) -> Result<Arc<Terrain>, TerrainError> {
        let key = dataset_key(content_hash);
        let mut map = self.terrains.lock().unwrap_or_else(PoisonError::into_inner);
        map.entry(key)
            .or_insert_with(|| make().map(Arc::new))
            .clone()
    }

    /// A made terrain tile, if the cache holds it.
    pub fn terrain_tile(&self, key: &TerrainKey) -> Option<Bytes> {
        let got = self.terrain_tiles.get(key);
        self.count("terrain", got.is_none(), self.terrain_tiles.weight());
        got
    }

    /// Keeps a made terrain tile.
    pub fn keep_terrain(&self, key: TerrainKey, body: Bytes) {
        self.terrain_tiles.insert(key, body);
        self.bytes
            .with_label_values(&["terrain"])
            .set(i64::try_from(self.terrain_tiles.weight()).unwrap_or(i64::MAX));
    }

    /// A decoded pyramid tile: from the cache, or made by `load` — once, however
    /// many requests ask for it at the same time (the others wait for it).
    pub fn source<E>(
        &self,
        dataset: u64,
        tile: TileId,
        load: impl FnOnce() -> Result<Arc<SourceTile>, E>,
    ) -> Result<Arc<SourceTile>, E> {
        let mut missed = false;
        let got = self.sources.get_or_insert_with(&(dataset, tile), || {
            missed = true;
            load()
        });
        self.count("source", missed, self.sources.weight());
        got
    }

    /// A made tile, if the cache holds it.
    pub fn made(&self, key: &MadeKey) -> Option<Bytes> {
        let got = self.made.get(key);
        self.count("tile", got.is_none(), self.made.weight());
        got
    }

    /// Keeps a made tile (an empty body for a tile without data).
    pub fn keep(&self, key: MadeKey, body: Bytes) {
        self.made.insert(key, body);
        self.bytes
            .with_label_values(&["tile"])
            .set(i64::try_from(self.made.weight()).unwrap_or(i64::MAX));
    }

    fn count(&self, cache: &str, missed: bool, weight: u64) {
        let result = if missed { "miss" } else { "hit" };
        self.lookups.with_label_values(&[cache, result]).inc();
        self.bytes
            .with_label_values(&[cache])
            .set(i64::try_from(weight).unwrap_or(i64::MAX));
    }

    /// Bytes held by the source-tile cache.
    pub fn source_bytes(&self) -> u64 {
        self.sources.weight()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use tessera_shared::mask::CellMask;
    use tessera_shared::{Level, Quantization};

    fn tile(side: u32) -> Arc<SourceTile> {
        Arc::new(SourceTile {
            heights: vec![0; ((side + 1) * (side + 1)) as usize],
            mask: CellMask::all_valid(side),
            quantization: Quantization {
                offset: 0.0,
                scale: 1.0,
                max_error: 0.0,
            },
            block_errors: None,
        })
    }

    #[test]
    fn a_burst_of_requests_for_one_tile_loads_it_once() {
        let web = WebTiles::new(WebConfig::default(), &Registry::new());
        let loads = AtomicUsize::new(0);
        let id = TileId::new(Level::new(2).unwrap(), 1, 3).unwrap();
        std::thread::scope(|s| {
            for _ in 0..8 {
                s.spawn(|| {
                    web.source::<()>(7, id, || {
                        loads.fetch_add(1, Ordering::SeqCst);
                        std::thread::sleep(std::time::Duration::from_millis(50));
                        Ok(tile(64))
                    })
                    .unwrap();
                });
            }
        });
        assert_eq!(loads.load(Ordering::SeqCst), 1);
        assert_eq!(web.source_bytes(), tile(64).bytes());
    }

    #[test]
    fn the_source_cache_stays_within_its_bytes() {
        let one = tile(256).bytes();
        let config = WebConfig {
            source_cache_bytes: one * 10,
            ..WebConfig::default()
        };
        let web = WebTiles::new(config, &Registry::new());
        let level = Level::new(6).unwrap();
        for x in 0..40 {
            let id = TileId::new(level, x, 0).unwrap();
            web.source::<()>(1, id, || Ok(tile(256))).unwrap();
            assert!(
                web.source_bytes() <= one * 10,
                "{} > {}",
                web.source_bytes(),
                one * 10
            );
        }
        assert!(web.source_bytes() >= one * 5, "it keeps what fits");
    }
}
