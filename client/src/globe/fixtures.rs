//! Globes and measurements the globe's and selection's tests share.

use super::Globe;
use super::grid::LonLatGrid;
use glam::{DVec2, DVec3};
use tessera_shared::ellipsoid::Ellipsoid;

/// The moon 8192² grid (1/256°, from 43°E, 32.99°N) on its sphere.
pub(crate) fn moon() -> Globe {
    Globe {
        ellipsoid: Ellipsoid::new(1_737_400.0, 1_737_400.0).expect("a sphere"),
        grid: LonLatGrid {
            lon0: 43.0 + 0.5 / 256.0,
            dlon: 1.0 / 256.0,
            lat0: 32.992_187_5 - 0.5 / 256.0,
            dlat: -1.0 / 256.0,
        },
        spacing: DVec2::new(113.0, 118.45),
        min_height: -5547.0,
    }
}

/// A grid of `per_degree` samples per degree from 8°E, 47°N (N46E008) on WGS 84,
/// `spacing` metres apart on the map.
pub(crate) fn alps(per_degree: f64, spacing: DVec2) -> Globe {
    Globe {
        ellipsoid: Ellipsoid::new(6_378_137.0, 6_356_752.314_245).expect("WGS 84"),
        grid: LonLatGrid {
            lon0: 8.0,
            dlon: 1.0 / per_degree,
            lat0: 47.0,
            dlat: -1.0 / per_degree,
        },
        spacing,
        min_height: 187.0,
    }
}

/// The true distance from the map pose `eye` to the curved box `min..max`, as the
/// nearest of a dense sample: `n + 1` points a side of the box at each of `heights`.
/// It can only overestimate (by the sample's spacing at most).
pub(crate) fn nearest_sampled(
    g: &Globe,
    eye: DVec3,
    min: DVec3,
    max: DVec3,
    n: u32,
    heights: &[f64],
) -> f64 {
    let e = g.ecef_of_world(eye);
    let mut nearest = f64::MAX;
    for j in 0..=n {
        for i in 0..=n {
            let (fi, fj) = (f64::from(i) / f64::from(n), f64::from(j) / f64::from(n));
            for &h in heights {
                let p = g.ecef_of_world(DVec3::new(
                    min.x + fi * (max.x - min.x),
                    h,
                    min.z + fj * (max.z - min.z),
                ));
                nearest = nearest.min(p.distance(e));
            }
        }
    }
    nearest
}
