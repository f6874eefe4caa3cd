//! Which interfaces a dataset offers, decided by the same checks the routes make
//! (the footprint for the standard grids, WMTS and OGC API – Tiles; the terrain plan
//! for Cesium), so that a page or a document never links a URL that answers 404.

use super::AppState;
use super::dataset::Dataset;
use super::web_cache::NoFootprint;
use crate::cesium::terrain::{Terrain, TerrainError};
use crate::web::footprint::Footprint;
use std::sync::Arc;
use tessera_shared::api::{DatasetLinks, EncodingLinks, StandardGridLinks, fill, routes};

/// WGS 84's equatorial radius; a body within a kilometre of it is the Earth (as the
/// Cesium terrain decides).
const EARTH_RADIUS: f64 = 6_378_137.0;

/// What a dataset offers beyond its pyramid.
#[derive(Debug, Clone)]
pub struct Offered {
    /// The dataset's place on a map (standard-grid tiles and their TileJSON, WMTS, OGC
    /// API – Tiles, the map viewer), or why it has none.
    pub grids: Result<Arc<Footprint>, NoFootprint>,
    /// Cesium terrain, or why not.
    pub terrain: Result<Arc<Terrain>, TerrainError>,
    /// The radii `[a, a, b]` of the body the dataset's CRS names, when it names one.
    pub radii: Option<[f64; 3]>,
}

impl Offered {
    /// Whether the dataset lies on the Earth (or names no body): the standard grids
    /// are the Earth's, so a dataset on another body is placed on the Earth's map at
    /// its own longitudes and latitudes.
    pub fn on_earth(&self) -> bool {
        self.radii
            .is_none_or(|[a, _, _]| (a - EARTH_RADIUS).abs() < 1000.0)
    }
}

/// What `ds` offers, from the server's caches (the routes' own footprints and terrain
/// plans: computed once per dataset version).
pub fn offered(state: &AppState, ds: &Dataset) -> Offered {
    let m = ds.pyramid.metadata();
    let grids = state.web.footprint(ds.content_hash(), || Footprint::new(m));
    let terrain = state.web.terrain(ds.content_hash(), || {
        Terrain::new(m, state.web.config.geoid.clone())
    });
    let radii = m
        .georef
        .as_ref()
        .and_then(crate::crs::Crs::of)
        .and_then(|c| c.body_radii())
        .map(|(a, b)| [a, a, b]);
    Offered {
        grids,
        terrain,
        radii,
    }
}

/// The standard-grid TileJSON of `grid` (`webmercator`, `crs84`) in one encoding.
pub fn grid_tilejson(name: &str, grid: &str, encoding: &str) -> String {
    format!(
        "{}?encoding={encoding}",
        fill(routes::GRID_TILEJSON, &[("name", name), ("grid", grid)])
    )
}

/// Cesium's terrain directory (what `CesiumTerrainProvider.fromUrl` takes: it appends
/// `layer.json` itself).
pub fn cesium_dir(name: &str) -> String {
    let layer = fill(routes::CESIUM_LAYER, &[("name", name)]);
    layer.trim_end_matches("layer.json").to_string()
}

/// Adds the links of every interface `ds` offers to `links` (server-relative, as the
/// document's other links); `viewer` is whether the built-in viewer is on.
pub fn add_links(links: &mut DatasetLinks, name: &str, offered: &Offered, viewer: bool) {
    let at = |template: &str| fill(template, &[("name", name)]);
    links.bootstrap = Some(at(routes::BOOTSTRAP));
    links.preview = Some(at(routes::PREVIEW));
    if offered.grids.is_ok() {
        let grid = |g: &str| EncodingLinks {
            terrarium: grid_tilejson(name, g, "terrarium"),
            mapbox: grid_tilejson(name, g, "mapbox"),
        };
        links.standard_grids = Some(StandardGridLinks {
            web_mercator_quad: grid("webmercator"),
            world_crs84_quad: grid("crs84"),
        });
        links.wmts = Some(at(routes::DATASET_WMTS));
        links.ogcapi_collection = Some(at(routes::OGC_COLLECTION));
        links.ogcapi_tilesets = Some(at(routes::OGC_TILESETS));
        if viewer {
            links.viewer = Some(at(routes::VIEWER));
        }
    }
    if offered.terrain.is_ok() {
        links.cesium = Some(at(routes::CESIUM_LAYER));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_come_from_the_routes() {
        assert_eq!(
            grid_tilejson("N46E008", "webmercator", "mapbox"),
            "/v1/datasets/N46E008/webmercator/tilejson.json?encoding=mapbox"
        );
        assert_eq!(cesium_dir("a.b"), "/v1/datasets/a.b/cesium/");
    }
}
