//! A quantized-mesh-1.0 tile read back: the header's bounds, the vertices as a client
//! decodes them, the triangles, the edge lists and the oct-encoded normals. 3D Tiles
//! terrain is made from the bytes the quantized-mesh route serves, so both formats
//! draw the same vertices and state the same bounds.

use crate::cesium::header_geometry::oct_decode;
use crate::cesium::quantized_mesh::{EXTENSION_OCT_NORMALS, HEADER_BYTES, MAX_VERTICES_16_BIT};
use glam::DVec3;

/// One tile, as decoded.
#[derive(Debug, Clone, PartialEq)]
pub struct QuantizedTile {
    /// The header's centre (ECEF metres).
    pub centre: DVec3,
    pub minimum_height: f32,
    pub maximum_height: f32,
    /// The bounding sphere's centre (ECEF) and radius.
    pub sphere_centre: DVec3,
    pub sphere_radius: f64,
    /// The horizon-occlusion point (ellipsoid-scaled space).
    pub horizon_occlusion_point: DVec3,
    /// Per vertex: u, v (0..=32767 west→east, south→north) and the height code
    /// (0..=32767 between the minimum and maximum height).
    pub u: Vec<u16>,
    pub v: Vec<u16>,
    pub h: Vec<u16>,
    pub triangles: Vec<[u32; 3]>,
    /// West, south, east and north edge vertices, along each edge.
    pub edges: [Vec<u32>; 4],
    /// Unit ECEF normals, when the tile has the normals extension.
    pub normals: Option<Vec<DVec3>>,
}

/// Why bytes are not a quantized-mesh tile.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ReadError {
    #[error("the tile ends at byte {0}, inside its {1}")]
    Truncated(usize, &'static str),
    #[error("triangle index {index} names no vertex of {vertices}")]
    BadIndex { index: u32, vertices: usize },
    #[error("the normals extension holds {0} bytes, not two per vertex")]
    BadNormals(usize),
}

struct Cursor<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Cursor<'_> {
    fn take(&mut self, n: usize, what: &'static str) -> Result<&[u8], ReadError> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&e| e <= self.bytes.len())
            .ok_or(ReadError::Truncated(self.bytes.len(), what))?;
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u32(&mut self, what: &'static str) -> Result<u32, ReadError> {
        Ok(u32::from_le_bytes(
            self.take(4, what)?.try_into().expect("4 bytes"),
        ))
    }
    fn u16s(&mut self, n: usize, what: &'static str) -> Result<Vec<u16>, ReadError> {
        Ok(self
            .take(n.checked_mul(2).ok_or(ReadError::Truncated(0, what))?, what)?
            .chunks_exact(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect())
    }
    fn indices(&mut self, n: usize, wide: bool, what: &'static str) -> Result<Vec<u32>, ReadError> {
        let width = if wide { 4 } else { 2 };
        let raw = self.take(
            n.checked_mul(width).ok_or(ReadError::Truncated(0, what))?,
            what,
        )?;
        Ok(if wide {
            raw.chunks_exact(4)
                .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        } else {
            raw.chunks_exact(2)
                .map(|c| u32::from(u16::from_le_bytes([c[0], c[1]])))
                .collect()
        })
    }
}

impl QuantizedTile {
    /// Decodes a tile (uncompressed), as the quantized-mesh spec lays it out.
    pub fn decode(bytes: &[u8]) -> Result<Self, ReadError> {
        let mut c = Cursor { bytes, at: 0 };
        let header = c.take(HEADER_BYTES, "header")?;
        let f64_at = |p: usize| f64::from_le_bytes(header[p..p + 8].try_into().expect("8"));
        let f32_at = |p: usize| f32::from_le_bytes(header[p..p + 4].try_into().expect("4"));
        let centre = DVec3::new(f64_at(0), f64_at(8), f64_at(16));
        let (minimum_height, maximum_height) = (f32_at(24), f32_at(28));
        let sphere_centre = DVec3::new(f64_at(32), f64_at(40), f64_at(48));
        let sphere_radius = f64_at(56);
        let horizon_occlusion_point = DVec3::new(f64_at(64), f64_at(72), f64_at(80));

        let n = c.u32("vertex count")? as usize;
        let mut arrays = [Vec::new(), Vec::new(), Vec::new()];
        for a in &mut arrays {
            let mut value = 0i32;
            *a = c
                .u16s(n, "vertex data")?
                .into_iter()
                .map(|code| {
                    let code = i32::from(code);
                    value += (code >> 1) ^ -(code & 1);
                    value as u16
                })
                .collect();
        }
        let [u, v, h] = arrays;

        let wide = n > MAX_VERTICES_16_BIT;
        let width = if wide { 4 } else { 2 };
        c.take(c.at.next_multiple_of(width) - c.at, "index padding")?;
        let count = c.u32("triangle count")? as usize;
        let codes = c.indices(
            count
                .checked_mul(3)
                .ok_or(ReadError::Truncated(0, "indices"))?,
            wide,
            "indices",
        )?;
        let mut highest = 0u32;
        let mut flat = Vec::with_capacity(codes.len());
        for code in codes {
            let index = highest.wrapping_sub(code);
            if code == 0 {
                highest += 1;
            }
            if index as usize >= n {
                return Err(ReadError::BadIndex { index, vertices: n });
            }
            flat.push(index);
        }
        let triangles = flat.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
        let mut edges: [Vec<u32>; 4] = Default::default();
        for e in &mut edges {
            let k = c.u32("edge list")? as usize;
            *e = c.indices(k, wide, "edge list")?;
            if let Some(&index) = e.iter().find(|&&i| i as usize >= n) {
                return Err(ReadError::BadIndex { index, vertices: n });
            }
        }
        let mut normals = None;
        while c.at < bytes.len() {
            let id = c.take(1, "extension id")?[0];
            let len = c.u32("extension length")? as usize;
            let data = c.take(len, "extension")?;
            if id == EXTENSION_OCT_NORMALS {
                if len != 2 * n {
                    return Err(ReadError::BadNormals(len));
                }
                normals = Some(
                    data.chunks_exact(2)
                        .map(|p| oct_decode([p[0], p[1]]))
                        .collect(),
                );
            }
        }
        Ok(Self {
            centre,
            minimum_height,
            maximum_height,
            sphere_centre,
            sphere_radius,
            horizon_occlusion_point,
            u,
            v,
            h,
            triangles,
            edges,
            normals,
        })
    }

    /// Vertex `i`'s height as a client decodes it (linear between the header's
    /// minimum and maximum).
    pub fn height(&self, i: usize) -> f64 {
        let (lo, hi) = (
            f64::from(self.minimum_height),
            f64::from(self.maximum_height),
        );
        lo + f64::from(self.h[i]) / 32767.0 * (hi - lo)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cesium::quantized_mesh::{Extensions, MeshVertex, TerrainMesh, encode};
    use tessera_shared::ellipsoid::Ellipsoid;

    fn mesh() -> TerrainMesh {
        let mut vertices = Vec::new();
        for j in 0..5u16 {
            for i in 0..5u16 {
                vertices.push(MeshVertex {
                    u: i * 8191 + i / 4 * 3,
                    v: j * 8191 + j / 4 * 3,
                    height: 100.0 + f64::from(i * j) * 37.5,
                });
            }
        }
        let mut triangles = Vec::new();
        for j in 0..4u32 {
            for i in 0..4u32 {
                let a = j * 5 + i;
                triangles.push([a, a + 1, a + 6]);
                triangles.push([a, a + 6, a + 5]);
            }
        }
        TerrainMesh {
            vertices,
            triangles,
        }
    }

    #[test]
    fn reads_back_what_the_encoder_wrote() {
        let m = mesh();
        let rect = [8.0, 46.0, 8.5, 46.5];
        let ext = Extensions {
            normals: true,
            ..Extensions::default()
        };
        let bytes = encode(&m, rect, &Ellipsoid::WGS84, &ext).unwrap();
        let t = QuantizedTile::decode(&bytes).unwrap();
        assert_eq!(t.u.len(), 25);
        assert_eq!(t.triangles.len(), 32);
        assert_eq!(t.minimum_height, 100.0);
        assert_eq!(t.maximum_height, 700.0);
        // The same vertex set (the encoder reorders vertices).
        let mut got: Vec<(u16, u16, f64)> =
            (0..25).map(|i| (t.u[i], t.v[i], t.height(i))).collect();
        let mut want: Vec<(u16, u16, f64)> =
            m.vertices.iter().map(|v| (v.u, v.v, v.height)).collect();
        got.sort_unstable_by_key(|&(u, v, _)| (u, v));
        want.sort_unstable_by_key(|&(u, v, _)| (u, v));
        for (g, w) in got.iter().zip(&want) {
            // Heights to within half a step of 600 m / 32767.
            assert_eq!((g.0, g.1), (w.0, w.1));
            assert!(
                (g.2 - w.2).abs() <= 0.5 * 600.0 / 32767.0 + 1e-9,
                "{g:?} {w:?}"
            );
        }
        // Triangles name the same corners.
        let key = |u: u16, v: u16| (u, v);
        let mut got_t: Vec<[(u16, u16); 3]> = t
            .triangles
            .iter()
            .map(|tri| tri.map(|i| key(t.u[i as usize], t.v[i as usize])))
            .collect();
        let mut want_t: Vec<[(u16, u16); 3]> = m
            .triangles
            .iter()
            .map(|tri| tri.map(|i| key(m.vertices[i as usize].u, m.vertices[i as usize].v)))
            .collect();
        got_t.sort_unstable();
        want_t.sort_unstable();
        assert_eq!(got_t, want_t);
        // Edges: five vertices each, on their edge, in order along it.
        for (k, e) in t.edges.iter().enumerate() {
            assert_eq!(e.len(), 5, "edge {k}");
            for &i in e {
                let (u, v) = (t.u[i as usize], t.v[i as usize]);
                assert!(match k {
                    0 => u == 0,
                    1 => v == 0,
                    2 => u == 32767,
                    _ => v == 32767,
                });
            }
        }
        let normals = t.normals.as_ref().unwrap();
        assert_eq!(normals.len(), 25);
        assert!(normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-9));
        // Bounds: the sphere holds every decoded vertex.
        let rect_lon = |u: u16| 8.0 + f64::from(u) / 32767.0 * 0.5;
        let rect_lat = |v: u16| 46.0 + f64::from(v) / 32767.0 * 0.5;
        for i in 0..25 {
            let p = Ellipsoid::WGS84.to_ecef(
                rect_lon(t.u[i]).to_radians(),
                rect_lat(t.v[i]).to_radians(),
                t.height(i),
            );
            assert!(p.distance(t.sphere_centre) <= t.sphere_radius * (1.0 + 1e-12));
        }
    }

    #[test]
    fn refuses_truncated_tiles() {
        let bytes = encode(
            &mesh(),
            [8.0, 46.0, 8.5, 46.5],
            &Ellipsoid::WGS84,
            &Extensions::default(),
        )
        .unwrap();
        for cut in [0, 50, 100, bytes.len() - 1] {
            assert!(
                matches!(
                    QuantizedTile::decode(&bytes[..cut]),
                    Err(ReadError::Truncated(..))
                ),
                "{cut}"
            );
        }
    }
}
