//! The reference tessellator: the exact vertices the renderer's vertex shader must
//! produce for a patch (docs/ARCHITECTURE.md#rendering,
//! docs/ARCHITECTURE.md#crack-free-edges), in integer global sample coordinates.
//!
//! Vertex `(i, j)` of an inner-LOD-`n` patch sits at tile sample
//! `origin + (i, j)·size/n`. On an edge whose LOD `e < n`, the along-edge index is
//! snapped down to a multiple of `n/e`, which lands exactly on the neighbour's
//! vertices; the snapped triangles along that edge collapse to zero area, so the
//! mesh stays watertight. Heights are the stored samples, read with integer
//! fetches, so both sides of an edge read the same sample.
//!
//! Geomorphing ([`crate::select::morph`]): a vertex at an odd index slides towards
//! the average of its even neighbours' samples, by the patch's interior factor
//! inside and by the side's factor on a side (where the index that counts is the
//! one on the side's own, snapped grid). Heights are mixed in integers
//! ([`morph::mix`]), so the shader computes the same bits.

use crate::select::morph::{self, Morph};
use crate::select::{EAST, NORTH, Patch, SOUTH, WEST};
use tessera_shared::TileGeometry;

/// A vertex: global finest-grid coordinates, the quantized sample there, and the
/// height drawn after morphing, in `1/`[`morph::HEIGHT_UNITS`] quantization steps
/// (`h = q·HEIGHT_UNITS` when the vertex does not move).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Vertex {
    pub x: u64,
    pub y: u64,
    pub q: u16,
    pub h: u32,
}

/// The along-edge index after snapping (`e` divides `n`, both powers of two).
pub const fn snap(index: u32, n: u32, e: u32) -> u32 {
    let step = n / e;
    index / step * step
}

/// Grid index of vertex `(i, j)` after edge snapping: on the north/south rows the
/// along-edge index is `i`, on the west/east columns it is `j`.
pub fn snapped_index(p: &Patch, i: u32, j: u32) -> (u32, u32) {
    let n = p.inner;
    let a = match j {
        0 => snap(i, n, p.edges[NORTH]),
        _ if j == n => snap(i, n, p.edges[SOUTH]),
        _ => i,
    };
    let b = match i {
        0 => snap(j, n, p.edges[WEST]),
        _ if i == n => snap(j, n, p.edges[EAST]),
        _ => j,
    };
    (a, b)
}

/// The two grid points whose average vertex `(i, j)` morphs towards (snapped
/// index `(a, b)`), and the factor; `None` when it does not move (an even vertex).
pub fn morph_target(p: &Patch, i: u32, j: u32) -> Option<([u32; 2], [u32; 2], u16)> {
    let n = p.inner;
    let (a, b) = snapped_index(p, i, j);
    let Morph { inner, edges } = p.morph;
    // A side: odd on the side's own grid (edge LOD e, every n/e grid indices).
    let along = |index: u32, side: usize| {
        let per = n / p.edges[side].max(1);
        // Edge LOD ≥ 2: the side's ends are even, and its neighbours on the side.
        let odd = p.edges[side] >= 2 && index / per % 2 == 1;
        (odd && edges[side] > 0).then_some((per, edges[side]))
    };
    if j == 0 || j == n {
        let side = if j == 0 { NORTH } else { SOUTH };
        return along(a, side).map(|(per, f)| ([a - per, b], [a + per, b], f));
    }
    if i == 0 || i == n {
        let side = if i == 0 { WEST } else { EAST };
        return along(b, side).map(|(per, f)| ([a, b - per], [a, b + per], f));
    }
    if inner == 0 {
        return None;
    }
    // Inside: towards the n/2 grid, whose cells split north-west → south-east.
    match (i % 2, j % 2) {
        (1, 0) => Some(([i - 1, j], [i + 1, j], inner)),
        (0, 1) => Some(([i, j - 1], [i, j + 1], inner)),
        (1, 1) => Some(([i - 1, j - 1], [i + 1, j + 1], inner)),
        _ => None,
    }
}

/// Vertex `(i, j)` of a patch, reading its height from the tile's `(T+1)²` samples.
pub fn vertex(g: &TileGeometry, p: &Patch, heights: &[u16], i: u32, j: u32) -> Vertex {
    let (a, b) = snapped_index(p, i, j);
    let step = p.size / p.inner;
    let sample = |[a, b]: [u32; 2]| {
        let (u, v) = (p.origin[0] + a * step, p.origin[1] + b * step);
        heights[v as usize * g.tile_samples() + u as usize]
    };
    let (u, v) = (p.origin[0] + a * step, p.origin[1] + b * step);
    let spacing = g.spacing(p.tile.level());
    let (gx, gy) = g.origin(p.tile);
    let q = sample([a, b]);
    let h = match morph_target(p, i, j) {
        Some((lo, hi, f)) => morph::mix(q, sample(lo), sample(hi), f),
        None => u32::from(q) * morph::HEIGHT_UNITS,
    };
    Vertex {
        x: gx + u64::from(u) * spacing,
        y: gy + u64::from(v) * spacing,
        q,
        h,
    }
}

/// All `(n+1)²` vertices of a patch, row-major.
pub fn vertices(g: &TileGeometry, p: &Patch, heights: &[u16]) -> Vec<Vertex> {
    let n = p.inner;
    (0..=n)
        .flat_map(|j| (0..=n).map(move |i| (i, j)))
        .map(|(i, j)| vertex(g, p, heights, i, j))
        .collect()
}

/// The `n + 1` vertices along one side (north, east, south, west), in order.
pub fn side_vertices(g: &TileGeometry, p: &Patch, heights: &[u16], side: usize) -> Vec<Vertex> {
    let n = p.inner;
    (0..=n)
        .map(|s| match side {
            NORTH => (s, 0),
            EAST => (n, s),
            SOUTH => (s, n),
            _ => (0, s),
        })
        .map(|(i, j)| vertex(g, p, heights, i, j))
        .collect()
}

/// Triangles of the `n × n` grid as vertex-index triples, each cell split along its
/// north-west → south-east diagonal (as FORMAT.md's error tables assume).
pub fn triangles(n: u32) -> Vec<[u32; 3]> {
    let w = n + 1;
    let mut t = Vec::with_capacity((2 * n * n) as usize);
    for j in 0..n {
        for i in 0..n {
            let (a, b, c, d) = (
                j * w + i,
                j * w + i + 1,
                (j + 1) * w + i,
                (j + 1) * w + i + 1,
            );
            t.push([a, b, d]);
            t.push([a, d, c]);
        }
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::{Level, TileId};

    #[test]
    fn snapping_lands_on_the_coarser_edge_vertices() {
        assert_eq!(snap(5, 8, 2), 4);
        assert_eq!(snap(7, 8, 8), 7);
        assert_eq!(snap(8, 8, 1), 8);
        let g = TileGeometry::new(65, 65, 64).unwrap();
        let p = Patch {
            tile: TileId::new(Level::ROOT, 0, 0).unwrap(),
            origin: [0, 0],
            size: 64,
            inner: 8,
            edges: [2, 8, 1, 4],
            morph: Morph::NONE,
            fade: crate::select::fade::Fade::NONE,
        };
        let h: Vec<u16> = (0..65 * 65).map(|i| i as u16).collect();
        let v = vertices(&g, &p, &h);
        // North edge LOD 2: vertices only at x = 0, 32, 64.
        let north: std::collections::BTreeSet<u64> = v[..9].iter().map(|v| v.x).collect();
        assert_eq!(north.into_iter().collect::<Vec<_>>(), [0, 32, 64]);
        // South edge LOD 1: only the corners.
        let south: std::collections::BTreeSet<u64> = v[72..].iter().map(|v| v.x).collect();
        assert_eq!(south.into_iter().collect::<Vec<_>>(), [0, 64]);
        // West edge LOD 4 (x = 0 column): y = 0, 16, 32, 48, 64.
        let west: std::collections::BTreeSet<u64> = (0..9).map(|j| v[j * 9].y).collect();
        assert_eq!(west.into_iter().collect::<Vec<_>>(), [0, 16, 32, 48, 64]);
        // Heights come from the sample at the snapped position.
        assert!(v.iter().all(|v| v.q == (v.y * 65 + v.x) as u16));
        assert_eq!(triangles(8).len(), 128);
    }

    /// A finest DEM of 129² pseudo-random samples, and its two pyramid levels:
    /// tile `(1, 0, 0)` (the finest) and the root, decimated (FORMAT.md).
    fn two_levels() -> (TileGeometry, Vec<u16>, Vec<u16>) {
        let g = TileGeometry::new(129, 129, 64).unwrap();
        let dem = |x: u32, y: u32| {
            let h = (x.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503)).wrapping_mul(97);
            (h >> 20) as u16
        };
        let tile = |step: u32| -> Vec<u16> {
            (0..65u32)
                .flat_map(|v| (0..65u32).map(move |u| (u, v)))
                .map(|(u, v)| dem(u * step, v * step))
                .collect()
        };
        (g, tile(1), tile(2))
    }

    /// The drawn surface of a patch at finest-grid point `(x, y)`, in quantization
    /// steps: the triangle holding it, interpolated (degenerate triangles skipped).
    fn surface(g: &TileGeometry, p: &Patch, heights: &[u16], x: f64, y: f64) -> f64 {
        let v = vertices(g, p, heights);
        for t in triangles(p.inner) {
            let [a, b, c] = t.map(|i| v[i as usize]);
            let (ax, ay, bx, by, cx, cy) = (
                a.x as f64, a.y as f64, b.x as f64, b.y as f64, c.x as f64, c.y as f64,
            );
            let det = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy);
            if det.abs() < 1e-9 {
                continue;
            }
            let l1 = ((by - cy) * (x - cx) + (cx - bx) * (y - cy)) / det;
            let l2 = ((cy - ay) * (x - cx) + (ax - cx) * (y - cy)) / det;
            let l3 = 1.0 - l1 - l2;
            if l1 >= -1e-12 && l2 >= -1e-12 && l3 >= -1e-12 {
                let h = |v: Vertex| f64::from(v.h) / f64::from(morph::HEIGHT_UNITS);
                return l1 * h(a) + l2 * h(b) + l3 * h(c);
            }
        }
        panic!("({x}, {y}) is outside {p:?}");
    }

    fn patch(tile: TileId, size: u32, inner: u32, m: u16) -> Patch {
        Patch {
            tile,
            origin: [0, 0],
            size,
            inner,
            edges: [inner; 4],
            morph: Morph::new(m, [m; 4]).unwrap(),
            fade: crate::select::fade::Fade::NONE,
        }
    }

    /// Points spread over `[0, extent]²` (finest samples), off the grid lines too.
    fn points(extent: f64) -> impl Iterator<Item = (f64, f64)> {
        (0..400).map(move |k| {
            let (a, b) = (f64::from(k % 20), f64::from(k / 20));
            (
                (a * 0.618 + b * 0.05) % 1.0 * extent,
                (b * 0.377 + a * 0.031) % 1.0 * extent,
            )
        })
    }

    #[test]
    fn a_fully_morphed_patch_is_the_next_coarser_patch() {
        let (g, fine, _) = two_levels();
        let tile = TileId::new(Level::new(1).unwrap(), 0, 0).unwrap();
        for n in [2, 4, 8, 64] {
            let coarse = patch(tile, 64, n / 2, 0);
            let full = patch(tile, 64, n, morph::FULL);
            let none = patch(tile, 64, n, 0);
            let mut differs = 0;
            for (x, y) in points(64.0) {
                let want = surface(&g, &coarse, &fine, x, y);
                let got = surface(&g, &full, &fine, x, y);
                assert!(
                    (got - want).abs() < 1e-6,
                    "n = {n} at ({x}, {y}): {got} vs {want}"
                );
                differs += usize::from((surface(&g, &none, &fine, x, y) - want).abs() > 1e-3);
            }
            // Unmorphed, the finer patch is another surface: the test can fail.
            assert!(differs > 100, "n = {n}: {differs}");
        }
    }

    #[test]
    fn a_child_tile_fully_morphed_is_its_parents_surface() {
        let (g, child, parent) = two_levels();
        let (c, p) = (
            TileId::new(Level::new(1).unwrap(), 0, 0).unwrap(),
            TileId::new(Level::ROOT, 0, 0).unwrap(),
        );
        // The child's whole tile (64 of its samples, 64 finest) at LOD n against
        // the parent's quarter (32 of its samples, the same 64 finest) at LOD n/2:
        // the child's factor-1 grid (n/2) and the parent's are the same points.
        for (n, parent_n) in [(16, 8), (8, 4), (64, 32), (2, 1)] {
            let parent_patch = patch(p, 32, parent_n, 0);
            let at_one = patch(c, 64, n, morph::FULL);
            let at_zero = patch(c, 64, n, 0);
            let mut differs = 0;
            for (x, y) in points(64.0) {
                let want = surface(&g, &parent_patch, &parent, x, y);
                let got = surface(&g, &at_one, &child, x, y);
                assert!(
                    (got - want).abs() < 1e-6,
                    "{n}: ({x}, {y}): {got} vs {want}"
                );
                differs += usize::from((surface(&g, &at_zero, &child, x, y) - want).abs() > 1e-3);
            }
            assert!(differs > 100, "{n}: {differs}");
        }
    }

    #[test]
    fn a_half_morphed_vertex_is_halfway_and_even_vertices_stay() {
        let (g, fine, _) = two_levels();
        let tile = TileId::new(Level::new(1).unwrap(), 0, 0).unwrap();
        let p = patch(tile, 64, 8, morph::FULL / 2);
        let v = vertices(&g, &p, &fine);
        let q = |i: usize, j: usize| f64::from(v[j * 9 + i].q);
        // Halfway between the vertex's own sample and its neighbours' average.
        let half = |own: f64, a: f64, b: f64| f64::midpoint(own, f64::midpoint(a, b));
        let h = |i: usize, j: usize| f64::from(v[j * 9 + i].h) / f64::from(morph::HEIGHT_UNITS);
        // Odd column on an even row, inside; odd row and column (the diagonal); an
        // odd vertex on the north side (its own factor, here the same).
        assert_eq!(h(3, 2), half(q(3, 2), q(2, 2), q(4, 2)));
        assert_eq!(h(3, 5), half(q(3, 5), q(2, 4), q(4, 6)));
        assert_eq!(h(5, 0), half(q(5, 0), q(4, 0), q(6, 0)));
        for (i, j) in [(0, 0), (2, 4), (8, 8), (4, 0), (0, 6)] {
            assert_eq!(h(i, j), q(i, j), "even ({i}, {j})");
        }
    }
}
