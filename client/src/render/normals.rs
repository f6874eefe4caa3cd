//! Normal maps from height differences, one per tile, built when the tile is
//! uploaded: on the GPU by default (`gpu_normals.rs`, `normals.wgsl`), or here on
//! the CPU — this module's [`normal_map`] is also the reference the GPU's maps
//! are tested against.
//!
//! Central differences over the tile's own samples; on a border the missing
//! neighbour sample comes from the adjacent tile of the same level when it is
//! decoded, so both tiles compute the same normal on their shared border samples
//! (shading is continuous across tiles). Without that neighbour the difference is
//! one-sided. Across pyramid levels the two sides differentiate at different
//! sample spacings, so shading there is close but not identical (DECISIONS.md).

use glam::DVec2;

/// Where normal maps are built.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum NormalSource {
    /// A compute pass over the uploaded heights (an upload is only texture copies);
    /// the CPU path where the device has no compute shaders.
    #[default]
    Gpu,
    /// On the CPU at upload, with the tile's decoded neighbours (the reference).
    Cpu,
}

/// The four neighbours' heights (north, east, south, west), each `(T+1)²` samples.
pub type Neighbours<'a> = [Option<&'a [u16]>; 4];

/// Normal `(x, z)` components as signed bytes (the `y` component is implied), for
/// an `Rg8Snorm` texture. `metres_per_sample` is the horizontal distance between
/// the tile's samples east–west (`x`) and north–south (`y`; they differ where cells
/// are not square), `scale` metres per quantization step.
pub fn normal_map(
    heights: &[u16],
    samples: usize,
    neighbours: &Neighbours<'_>,
    metres_per_sample: DVec2,
    scale: f64,
) -> Vec<[i8; 2]> {
    let n = samples;
    let h = |u: usize, v: usize| f64::from(heights[v * n + u]);
    // Height one step beyond the tile, from a neighbour, when it is there.
    let beyond = |side: usize, u: usize, v: usize| -> Option<f64> {
        neighbours[side].map(|nb| f64::from(nb[v * n + u]))
    };
    let mut out = Vec::with_capacity(n * n);
    for v in 0..n {
        for u in 0..n {
            let (west, west_d) = if u > 0 {
                (h(u - 1, v), 1.0)
            } else {
                beyond(3, n - 2, v).map_or((h(u, v), 0.0), |x| (x, 1.0))
            };
            let (east, east_d) = if u + 1 < n {
                (h(u + 1, v), 1.0)
            } else {
                beyond(1, 1, v).map_or((h(u, v), 0.0), |x| (x, 1.0))
            };
            let (north, north_d) = if v > 0 {
                (h(u, v - 1), 1.0)
            } else {
                beyond(0, u, n - 2).map_or((h(u, v), 0.0), |x| (x, 1.0))
            };
            let (south, south_d) = if v + 1 < n {
                (h(u, v + 1), 1.0)
            } else {
                beyond(2, u, 1).map_or((h(u, v), 0.0), |x| (x, 1.0))
            };
            let dx = (east - west) * scale / ((east_d + west_d) * metres_per_sample.x);
            let dz = (south - north) * scale / ((south_d + north_d) * metres_per_sample.y);
            // Surface y = f(x, z): normal ∝ (−∂f/∂x, 1, −∂f/∂z).
            let len = (dx * dx + 1.0 + dz * dz).sqrt();
            let enc = |c: f64| (c / len * 127.0).round().clamp(-127.0, 127.0) as i8;
            out.push([enc(-dx), enc(-dz)]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plane_tilted_east_has_the_same_normal_everywhere() {
        let n = 5;
        // Height rises 1 quantum per sample eastwards; 1 m per sample, 1 m per quantum:
        // a 45° slope whose normal is (−1, 1, 0)/√2.
        let h: Vec<u16> = (0..n * n).map(|i| 100 + (i % n) as u16).collect();
        let m = normal_map(&h, n, &[None; 4], DVec2::splat(1.0), 1.0);
        let expected = (-127.0 / 2f64.sqrt()).round() as i8;
        assert!(m.iter().all(|&[x, z]| x == expected && z == 0), "{m:?}");
    }

    #[test]
    fn slopes_are_measured_in_metres_along_each_axis() {
        let n = 5;
        // Height rises 1 m per sample both eastwards and southwards, on cells 1 m
        // east–west and 2 m north–south (a geographic DEM's shape): 45° east, but
        // only 1:2 south, so the normal is (−1, 1, −½) normalized.
        let h: Vec<u16> = (0..n * n).map(|i| 100 + (i % n + i / n) as u16).collect();
        let m = normal_map(&h, n, &[None; 4], DVec2::new(1.0, 2.0), 1.0);
        let len = (1.0f64 + 1.0 + 0.25).sqrt();
        let (ex, ez) = (
            (-127.0 / len).round() as i8,
            (-0.5 * 127.0 / len).round() as i8,
        );
        assert!(m.iter().all(|&[x, z]| x == ex && z == ez), "{m:?}");
    }

    #[test]
    fn shared_borders_get_the_same_normal_from_both_tiles() {
        let n = 5;
        // A bumpy surface sampled by two tiles side by side: west covers x 0..=4,
        // east covers x 4..=8 (column 4 is shared).
        let f = |x: usize, y: usize| (((x * 7 + y * 3) % 11) * 20) as u16;
        let west: Vec<u16> = (0..n * n).map(|i| f(i % n, i / n)).collect();
        let east: Vec<u16> = (0..n * n).map(|i| f(i % n + 4, i / n)).collect();
        let s = DVec2::splat(30.0);
        let mw = normal_map(&west, n, &[None, Some(&east), None, None], s, 0.5);
        let me = normal_map(&east, n, &[None, None, None, Some(&west)], s, 0.5);
        for v in 0..n {
            assert_eq!(mw[v * n + n - 1], me[v * n], "row {v}");
        }
        // Without the neighbour the border is one-sided, and differs here.
        let alone = normal_map(&west, n, &[None; 4], s, 0.5);
        assert!((0..n).any(|v| alone[v * n + n - 1] != mw[v * n + n - 1]));
    }
}
