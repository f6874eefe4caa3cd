//! The quantized-mesh spec's codes: zig-zag deltas, high-water-mark indices, the
//! edge lists, oct-encoded vertex normals, the index width, and a little-endian
//! writer.

use super::input::Rect;
use super::{MeshVertex, QUANTIZED_MAX};
use glam::DVec3;
use tessera_shared::ellipsoid::Ellipsoid;

/// Zig-zag coding (spec, "VertexData"): 0, −1, 1, −2… become 0, 1, 2, 3…. Deltas of
/// values in 0..=32767 lie in ±32767, whose codes fit 16 bits.
pub(super) fn zig_zag(delta: i32) -> u16 {
    ((delta << 1) ^ (delta >> 31)) as u16
}

/// High-water-mark codes of an index list whose vertices first appear in order
/// (spec, "IndexData", from webgl-loader): the distance below the next new vertex,
/// so 0 means "the next new one".
pub(super) fn high_water_mark(indices: impl Iterator<Item = u32>) -> Vec<u32> {
    let mut next_new = 0u32;
    indices
        .map(|i| {
            debug_assert!(i <= next_new, "vertices out of first-use order");
            let code = next_new - i;
            if code == 0 {
                next_new += 1;
            }
            code
        })
        .collect()
}

/// The four edge lists (west, south, east, north): vertices on each edge, along it.
pub(super) fn edge_lists(vertices: &[MeshVertex]) -> [Vec<u32>; 4] {
    let on = |keep: fn(&MeshVertex) -> bool, along: fn(&MeshVertex) -> u16| {
        let mut list: Vec<u32> = (0..vertices.len() as u32)
            .filter(|&i| keep(&vertices[i as usize]))
            .collect();
        list.sort_by_key(|&i| (along(&vertices[i as usize]), i));
        list
    };
    [
        on(|v| v.u == 0, |v| v.v),
        on(|v| v.v == 0, |v| v.u),
        on(|v| v.u == QUANTIZED_MAX, |v| v.v),
        on(|v| v.v == QUANTIZED_MAX, |v| v.u),
    ]
}

/// Area-weighted vertex normals in ECEF: each triangle adds its edge vectors' cross
/// product, whose length is twice its area, to its corners; sums are normalised.
pub(super) fn vertex_normals(
    vertices: &[MeshVertex],
    triangles: &[[u32; 3]],
    positions: &[DVec3],
    rect: &Rect,
    ellipsoid: &Ellipsoid,
) -> Vec<DVec3> {
    let mut sums = vec![DVec3::ZERO; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| positions[i as usize]);
        let n = (b - a).cross(c - a);
        for &i in t {
            sums[i as usize] += n;
        }
    }
    sums.iter()
        .zip(vertices)
        .map(|(&s, v)| {
            let len = s.length();
            if len > 0.0 && len.is_finite() {
                s / len
            } else {
                let (lon, lat) = rect.lon_lat(v.u, v.v);
                ellipsoid.geodetic_surface_normal(lon.to_radians(), lat.to_radians())
            }
        })
        .collect()
}

/// The width of index data: 16-bit up to 65536 vertices, 32-bit past.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum IndexWidth {
    U16,
    U32,
}

impl IndexWidth {
    pub(super) fn bytes(self) -> usize {
        match self {
            Self::U16 => 2,
            Self::U32 => 4,
        }
    }

    pub(super) fn write(self, out: &mut Writer, value: u32) -> Result<(), ()> {
        match self {
            Self::U16 => out.u16(u16::try_from(value).map_err(|_| ())?),
            Self::U32 => out.u32(value),
        }
        Ok(())
    }
}

/// Little-endian output (spec: "tiles are little-endian").
#[derive(Debug)]
pub(super) struct Writer(pub(super) Vec<u8>);

impl Writer {
    pub(super) fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    pub(super) fn u16(&mut self, v: u16) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(super) fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(super) fn f32(&mut self, v: f32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(super) fn f64s(&mut self, vs: &[f64]) {
        for v in vs {
            self.0.extend_from_slice(&v.to_le_bytes());
        }
    }
    /// Zero bytes up to a multiple of `n` from the tile's start (spec: "padding is
    /// added before the IndexData to ensure 2 byte alignment for IndexData16 and 4
    /// byte alignment for IndexData32").
    pub(super) fn align(&mut self, n: usize) {
        while !self.0.len().is_multiple_of(n) {
            self.0.push(0);
        }
    }
}
