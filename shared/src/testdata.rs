//! The real DEMs in `../shared/data/dem/` (beside the repository) and the facts
//! their README states, for tests in every crate. Enabled by the `testdata` feature.
//!
//! A test that needs a DEM calls [`dem_or_skip`]: on a machine without the data
//! it prints a visible `SKIPPED` line and returns `None`, but when the `CI`
//! environment variable is set a missing file is a failure, so CI can never pass
//! by skipping.

use std::path::PathBuf;

/// Where the DEMs live: `$TESSERA_DEM_DIR`, else `../shared/data/dem` beside the repository.
pub fn dem_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("TESSERA_DEM_DIR") {
        return PathBuf::from(d);
    }
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/dem")
}

/// The path of a DEM, or `None` (after a visible message) when it is absent outside CI.
///
/// # Panics
/// When the file is absent and `CI` is set.
pub fn dem_or_skip(name: &str) -> Option<PathBuf> {
    let path = dem_dir().join(name);
    if path.is_file() {
        return Some(path);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "test data {} is missing and CI is set: the shared DEMs must be present",
        path.display()
    );
    eprintln!("SKIPPED: test data {} is absent", path.display());
    None
}

/// Facts the data README states about one DEM.
#[derive(Clone, Copy, Debug)]
pub struct DemFacts {
    pub name: &'static str,
    pub width: u32,
    pub height: u32,
    /// Elevation range in metres after the stated scale/offset.
    pub min: f64,
    pub max: f64,
    /// `(scale, offset)` that turn stored integers into metres.
    pub scale: f64,
    pub offset: f64,
    pub epsg: Option<u32>,
    /// GDAL-style extent `[west, south, east, north]` of the pixel areas, when georeferenced.
    pub extent: Option<[f64; 4]>,
    /// Samples the README reports as no-data.
    pub nodata_count: u64,
}

const ARC3: f64 = 1.0 / 1200.0;

/// Every DEM a reader test covers, with the values from `../shared/data/dem/README.md`.
pub const DEMS: &[DemFacts] = &[
    DemFacts {
        name: "N46E008.tif",
        width: 1201,
        height: 1201,
        min: 187.0,
        max: 4173.0,
        scale: 1.0,
        offset: 0.0,
        epsg: Some(4326),
        // PixelIsPoint: the tiepoint (8 E, 47 N) is the centre of the first sample.
        extent: Some([
            8.0 - ARC3 / 2.0,
            46.0 - ARC3 / 2.0,
            9.0 + ARC3 / 2.0,
            47.0 + ARC3 / 2.0,
        ]),
        nodata_count: 103_743,
    },
    DemFacts {
        name: "aletsch.tif",
        width: 358,
        height: 310,
        min: 502.0,
        max: 4216.3,
        scale: 1.0,
        offset: 0.0,
        epsg: Some(2056),
        // PixelIsArea, 200 m pixels from the tiepoint (2601100, 1184500).
        extent: Some([
            2_601_100.0,
            1_184_500.0 - 310.0 * 200.0,
            2_601_100.0 + 358.0 * 200.0,
            1_184_500.0,
        ]),
        nodata_count: 0,
    },
    DemFacts {
        name: "bigtujunga.tif",
        width: 1197,
        height: 643,
        min: 315.0,
        max: 2295.0,
        scale: 1.0,
        offset: 0.0,
        epsg: Some(32611),
        extent: None,
        nodata_count: 0,
    },
    DemFacts {
        name: "lidar_dem_1m.tif",
        width: 400,
        height: 400,
        min: 379.66,
        max: 410.76,
        scale: 1.0,
        offset: 0.0,
        epsg: Some(26915),
        extent: None,
        nodata_count: 0,
    },
    DemFacts {
        name: "luxembourg_elev.tif",
        width: 95,
        height: 90,
        min: 141.0,
        max: 547.0,
        scale: 1.0,
        offset: 0.0,
        epsg: Some(4326),
        extent: None,
        nodata_count: 3942,
    },
    DemFacts {
        name: "N44W072.hgt",
        width: 1201,
        height: 1201,
        min: 115.0,
        max: 1908.0,
        scale: 1.0,
        offset: 0.0,
        epsg: Some(4326),
        // The name gives the SW sample centre (44 N, 72 W); SRTM samples are points.
        extent: Some([
            -72.0 - ARC3 / 2.0,
            44.0 - ARC3 / 2.0,
            -71.0 + ARC3 / 2.0,
            45.0 + ARC3 / 2.0,
        ]),
        nodata_count: 0,
    },
    DemFacts {
        name: "moon_crisium_gld100_4096.png",
        width: 4096,
        height: 4096,
        min: -5547.0,
        max: 1986.0,
        scale: 1.0,
        offset: -10000.0,
        epsg: None,
        extent: None,
        nodata_count: 0,
    },
    DemFacts {
        name: "jacksboro_fault_dem.png",
        width: 403,
        height: 344,
        min: 236.0,
        max: 1076.0,
        scale: 1.0,
        offset: 0.0,
        epsg: None,
        extent: None,
        nodata_count: 0,
    },
    DemFacts {
        name: "topobathy.png",
        width: 120,
        height: 91,
        min: -1437.0,
        max: 2205.0,
        scale: 1.0,
        offset: -2000.0,
        epsg: None,
        extent: None,
        nodata_count: 0,
    },
    DemFacts {
        name: "sthelens_10m.png",
        width: 2000,
        height: 2000,
        min: 567.5,
        max: 2538.2,
        scale: 0.1,
        offset: 0.0,
        epsg: None,
        extent: None,
        nodata_count: 0,
    },
];

/// A file of the real imagery beside the DEMs (`../shared/data/imagery/`, Landsat 7
/// over Olinda with its DEM; see its README), or `None` (after a visible message) when
/// absent outside CI, as [`dem_or_skip`].
///
/// # Panics
/// When the file is absent and `CI` is set.
pub fn imagery_or_skip(name: &str) -> Option<PathBuf> {
    let path = dem_dir().join("../imagery").join(name);
    if path.is_file() {
        return Some(path);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "test data {} is missing and CI is set: the shared imagery must be present",
        path.display()
    );
    eprintln!("SKIPPED: {} is not present", path.display());
    None
}

/// The facts for `name`.
///
/// # Panics
/// When `name` is not in [`DEMS`].
pub fn facts(name: &str) -> DemFacts {
    *DEMS
        .iter()
        .find(|d| d.name == name)
        .unwrap_or_else(|| panic!("no facts recorded for {name}"))
}
