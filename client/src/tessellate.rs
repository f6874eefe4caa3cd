//! The reference tessellator: the exact vertices the renderer's vertex shader must
//! produce for a patch (DESIGN §5–6), in integer global sample coordinates.
//!
//! Vertex `(i, j)` of an inner-LOD-`n` patch sits at tile sample
//! `origin + (i, j)·size/n`. On an edge whose LOD `e < n`, the along-edge index is
//! snapped down to a multiple of `n/e`, which lands exactly on the neighbour's
//! vertices; the snapped triangles along that edge collapse to zero area, so the
//! mesh stays watertight. Heights are the stored samples, read with integer
//! fetches, so both sides of an edge read the same sample.

use crate::select::{EAST, NORTH, Patch, SOUTH, WEST};
use tessera_shared::TileGeometry;

/// A vertex: global finest-grid coordinates and the quantized height.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Vertex {
    pub x: u64,
    pub y: u64,
    pub q: u16,
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

/// Vertex `(i, j)` of a patch, reading its height from the tile's `(T+1)²` samples.
pub fn vertex(g: &TileGeometry, p: &Patch, heights: &[u16], i: u32, j: u32) -> Vertex {
    let (a, b) = snapped_index(p, i, j);
    let step = p.size / p.inner;
    let (u, v) = (p.origin[0] + a * step, p.origin[1] + b * step);
    let spacing = g.spacing(p.tile.level());
    let (gx, gy) = g.origin(p.tile);
    Vertex {
        x: gx + u64::from(u) * spacing,
        y: gy + u64::from(v) * spacing,
        q: heights[v as usize * g.tile_samples() + u as usize],
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
}
