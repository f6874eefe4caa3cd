//! The quantized-mesh-1.0 tile format (DECISIONS.md "Cesium terrain"): a mesh from
//! [`super::mesh`] becomes the bytes CesiumJS's `CesiumTerrainProvider` reads, as
//! the spec (CesiumGS/quantized-mesh, README) lays them out, little-endian:
//!
//! 1. the header: centre, height range, bounding sphere, horizon-occlusion point
//!    (88 bytes);
//! 2. the vertex data: count, then u, v and height arrays, each delta- then
//!    zig-zag-coded;
//! 3. the index data, padded to its element size: triangle count, then
//!    high-water-mark-coded indices, 16-bit unless there are more than 65536 vertices;
//! 4. the west, south, east and north edge lists (plain indices, same width);
//! 5. extensions, each an id byte and a 32-bit length, in id order: oct-encoded
//!    vertex normals (id 1), the water mask (id 2) and metadata (id 4) when asked for.
//!
//! The tile is built uncompressed; the server gzips it. Every number in the header is
//! computed from the values a client decodes (quantized positions and heights), not
//! from the mesher's, so the bounds it states hold for what is drawn.
//!
//! [`encode`] is here; what it checks and derives from its input (the rectangle,
//! the mesh, the height range) is in [`input`], the spec's codes (zig-zag deltas,
//! high-water-mark indices, edge lists, normals, the index width) in [`codes`].

pub mod codes;
pub mod input;

#[cfg(test)]
mod tests;

use crate::cesium::header_geometry::{self, possibly_shrunk};
use codes::{IndexWidth, Writer, edge_lists, high_water_mark, vertex_normals, zig_zag};
use glam::DVec3;
use input::{HeightRange, Rect, check_mesh, check_metadata};
use tessera_shared::ellipsoid::Ellipsoid;

/// One vertex: its quantized tile position (0..=32767 across the tile, west→east /
/// south→north) and its height in metres above the ellipsoid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshVertex {
    pub u: u16,
    pub v: u16,
    pub height: f64,
}

/// A tile's mesh: vertices, and triangles indexing them, counter-clockwise seen from
/// above (u east, v north).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TerrainMesh {
    pub vertices: Vec<MeshVertex>,
    pub triangles: Vec<[u32; 3]>,
}

/// What to append after the mesh (spec, "Extensions").
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Extensions {
    /// Oct-encoded per-vertex normals (id 1, `octvertexnormals`).
    pub normals: bool,
    /// The water mask (id 2, `watermask`).
    pub water_mask: Option<WaterMask>,
    /// A JSON object for the metadata extension (id 4, `metadata`), e.g. child
    /// availability.
    pub metadata: Option<String>,
}

/// A tile's water mask (spec, "Water Mask"): one byte for a tile that is all land (0)
/// or all water (255), else 256 × 256 bytes, row by row from the tile's north-west
/// corner (north row first, west to east), 0 land to 255 water.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WaterMask(Vec<u8>);

/// Cells per side of a full water mask.
pub const WATER_MASK_SIDE: usize = 256;

impl WaterMask {
    /// A tile without water.
    pub fn land() -> Self {
        Self(vec![0])
    }

    /// A tile all water.
    pub fn water() -> Self {
        Self(vec![255])
    }

    /// The mask of a 256 × 256 grid (north row first): the one-byte form when every
    /// cell is 0 or every cell is 255. `None` for a grid of another size.
    pub fn from_grid(grid: Vec<u8>) -> Option<Self> {
        if grid.len() != WATER_MASK_SIDE * WATER_MASK_SIDE {
            return None;
        }
        Some(match grid[0] {
            v @ (0 | 255) if grid.iter().all(|&c| c == v) => Self(vec![v]),
            _ => Self(grid),
        })
    }

    /// The extension's bytes: 1 or 65 536.
    pub fn bytes(&self) -> &[u8] {
        &self.0
    }

    /// Whether cell `(column, row)` (row 0 north) is water (≥ 128), for either form.
    pub fn is_water(&self, column: usize, row: usize) -> bool {
        let v = if self.0.len() == 1 {
            self.0[0]
        } else {
            self.0[row * WATER_MASK_SIDE + column]
        };
        v >= 128
    }
}

/// The largest quantized coordinate: u, v and heights run over 0..=32767 (spec,
/// "VertexData").
pub const QUANTIZED_MAX: u16 = 32767;

/// The header's size: ten f64 and two f32.
pub const HEADER_BYTES: usize = 88;

/// The most vertices a tile may have and keep 16-bit indices (spec: tiles with more
/// than 65536 vertices use `IndexData32`; CesiumJS tests `vertexCount > 64 * 1024`).
pub const MAX_VERTICES_16_BIT: usize = 65_536;

/// Extension ids (spec, "Extensions").
pub const EXTENSION_OCT_NORMALS: u8 = 1;
pub const EXTENSION_WATER_MASK: u8 = 2;
pub const EXTENSION_METADATA: u8 = 4;

/// Where the header's occlusion point goes, in scaled space along the tile's
/// direction, when no finite point bounds the tile (a hemisphere, level 0 of the
/// EPSG:4326 grid): so far out that the region it is hidden from is, to 1 part in
/// 1000 as far as 1000 radii out, the unit cylinder behind the body, from where none of
/// a hemisphere's surface can be seen (only vertices raised above its rim, at grazing
/// angles). CesiumJS, finding no point for such a tile of its own, skips the horizon
/// test for it; the header has no way to say "none".
pub const UNBOUNDED_HORIZON_DISTANCE: f64 = 1e6;

/// The order the tile stores the mesh's vertices in: tile vertex `k` is
/// `mesh.vertices[order[k]]`. High-water-mark coding (spec, "IndexData") needs each
/// vertex to first appear in the triangle list right after those before it, so
/// vertices go in order of first use; any that no triangle uses follow, in their
/// own order. Indices out of range are skipped here ([`encode`] rejects them).
pub fn vertex_order(mesh: &TerrainMesh) -> Vec<u32> {
    let n = mesh.vertices.len();
    let mut placed = vec![false; n];
    let mut order = Vec::with_capacity(n);
    let used = mesh.triangles.iter().flatten().copied();
    for i in used.chain(0..n as u32) {
        if let Some(seen) = placed.get_mut(i as usize)
            && !*seen
        {
            *seen = true;
            order.push(i);
        }
    }
    order
}

/// Why a mesh cannot be a quantized-mesh tile ([`encode`]).
#[derive(Debug, thiserror::Error)]
pub enum EncodeError {
    #[error("degenerate tile rectangle {rect:?}: {why}")]
    DegenerateRect { rect: [f64; 4], why: &'static str },
    #[error("a tile needs at least one vertex")]
    NoVertices,
    #[error("{vertices} vertices and {triangles} triangles: more than a tile's 32-bit counts hold")]
    TooLarge { vertices: usize, triangles: usize },
    #[error("vertex {vertex} at u {u} v {v}: past {QUANTIZED_MAX}")]
    VertexPast { vertex: usize, u: u16, v: u16 },
    #[error("vertex {vertex} has height {height}")]
    HeightNotFinite { vertex: usize, height: f64 },
    #[error("triangle {triangle} {indices:?} uses vertex {vertex} of {vertices}")]
    NoSuchVertex {
        triangle: usize,
        indices: [u32; 3],
        vertex: u32,
        vertices: usize,
    },
    #[error("metadata longer than 32-bit lengths hold")]
    MetadataTooLong,
    #[error("metadata must be a JSON object (spec, \"Metadata\")")]
    MetadataNotAnObject,
    #[error("metadata is not JSON: {0}")]
    MetadataNotJson(serde_json::Error),
    #[error("heights {lo}..{hi} m have no finite f32 bounds")]
    NoF32Bounds { lo: f64, hi: f64 },
    #[error(
        "{vertices} vertices take 16-bit indices, but the triangle list has an index \
         code of {code}, past 16 bits; the mesh must use one vertex more or fewer"
    )]
    CodePast16Bits { vertices: usize, code: u32 },
    #[error("edge index past its width")]
    EdgeIndexPastWidth,
}

/// The tile's bytes, uncompressed, for `mesh` over `rect_deg` = [west, south, east,
/// north] (degrees) on `ellipsoid`, with the extensions `ext` asks for.
///
/// The header:
/// - centre: the ECEF position of the rectangle's centre at the middle of the
///   header's height range. Clients draw vertices relative to it (CesiumJS keeps
///   them as offsets from it), so it must be near the tile, and taking it from the
///   rectangle rather than the vertices' centroid makes it depend on the tile alone,
///   not on where the mesher put its vertices; it is also the direction the
///   occlusion point is sought along.
/// - minimum/maximum height: the vertices' least and greatest heights, as f32 rounded
///   down and up so that they contain every vertex.
/// - bounding sphere: of the vertices' decoded ECEF positions
///   ([`header_geometry::bounding_sphere`]).
/// - horizon-occlusion point: of the same positions
///   ([`header_geometry::horizon_occlusion_point`]), against the ellipsoid shrunk by
///   a negative minimum height as CesiumJS tests it ([`possibly_shrunk`]);
///   for a tile no point bounds, [`UNBOUNDED_HORIZON_DISTANCE`].
///
/// Heights are quantized to 0..=32767 between the header's f32 minimum and maximum,
/// to nearest; a flat tile (maximum = minimum) stores 0 everywhere. Vertices are
/// reordered for the index coding ([`vertex_order`]). Edge lists hold the vertices
/// with u = 0, v = 0, u = 32767 and v = 32767, sorted south→north or west→east.
/// Normals (extension 1) are the area-weighted average of the ECEF face normals of
/// the triangles around each vertex, at the decoded positions; a vertex no
/// triangle with area touches takes the ellipsoid's normal.
///
/// Errors: no vertices; u or v above 32767; a height that is not finite or has no
/// finite f32 bounds; a triangle index past the vertices; a rectangle with a
/// non-finite edge, west ≥ east, south ≥ north, more than 360° wide, or a latitude
/// beyond ±90°; metadata that is not a JSON object; exactly 65536 vertices with an
/// index code past 16 bits (the one layout the spec cannot store).
pub fn encode(
    mesh: &TerrainMesh,
    rect_deg: [f64; 4],
    ellipsoid: &Ellipsoid,
    ext: &Extensions,
) -> Result<Vec<u8>, EncodeError> {
    let rect = Rect::new(rect_deg)?;
    check_mesh(mesh)?;
    if let Some(json) = &ext.metadata {
        check_metadata(json)?;
    }

    // Put the vertices in first-use order and renumber the triangles to match.
    let order = vertex_order(mesh);
    let mut renumber = vec![0u32; order.len()];
    for (k, &old) in order.iter().enumerate() {
        renumber[old as usize] = k as u32;
    }
    let vertices: Vec<MeshVertex> = order.iter().map(|&i| mesh.vertices[i as usize]).collect();
    let triangles: Vec<[u32; 3]> = mesh
        .triangles
        .iter()
        .map(|t| t.map(|i| renumber[i as usize]))
        .collect();

    let range = HeightRange::of(&vertices)?;
    let quantized: Vec<u16> = vertices.iter().map(|v| range.quantize(v.height)).collect();
    // Longitudes and latitudes are degrees here, radians to the ellipsoid.
    let ecef =
        |lon: f64, lat: f64, h: f64| ellipsoid.to_ecef(lon.to_radians(), lat.to_radians(), h);
    let positions: Vec<DVec3> = vertices
        .iter()
        .zip(&quantized)
        .map(|(v, &q)| {
            let (lon, lat) = rect.lon_lat(v.u, v.v);
            ecef(lon, lat, range.decode(q))
        })
        .collect();

    let (centre_lon, centre_lat) = rect.centre();
    let centre = ecef(centre_lon, centre_lat, range.middle());
    let (sphere_centre, sphere_radius) = header_geometry::bounding_sphere(&positions);
    let occluder = possibly_shrunk(ellipsoid, f64::from(range.min));
    let horizon = header_geometry::horizon_occlusion_point(&occluder, centre, &positions)
        .unwrap_or_else(|| {
            let s = occluder.to_scaled_space(ecef(centre_lon, centre_lat, 0.0));
            s / s.length() * UNBOUNDED_HORIZON_DISTANCE
        });

    let width = if vertices.len() > MAX_VERTICES_16_BIT {
        IndexWidth::U32
    } else {
        IndexWidth::U16
    };
    let edges = edge_lists(&vertices);
    let edge_count: usize = edges.iter().map(Vec::len).sum();
    let mut out = Writer(Vec::with_capacity(
        HEADER_BYTES
            + 4
            + 6 * vertices.len()
            + 4
            + 4
            + width.bytes() * (3 * triangles.len() + edge_count)
            + 16
            + if ext.normals {
                5 + 2 * vertices.len()
            } else {
                0
            }
            + ext.water_mask.as_ref().map_or(0, |m| 5 + m.bytes().len())
            + ext.metadata.as_ref().map_or(0, |m| 9 + m.len()),
    ));

    // Header (spec, "QuantizedMeshHeader").
    out.f64s(&centre.to_array());
    out.f32(range.min);
    out.f32(range.max);
    out.f64s(&sphere_centre.to_array());
    out.f64s(&[sphere_radius]);
    out.f64s(&horizon.to_array());

    // Vertex data (spec, "VertexData"): count, then u, v, height arrays of zig-zagged
    // deltas from the previous vertex's value (from 0 for the first).
    out.u32(vertices.len() as u32);
    for values in [
        vertices.iter().map(|v| v.u).collect::<Vec<_>>(),
        vertices.iter().map(|v| v.v).collect(),
        quantized,
    ] {
        let mut previous = 0i32;
        for value in values {
            let delta = i32::from(value) - previous;
            previous = i32::from(value);
            out.u16(zig_zag(delta));
        }
    }

    // Index data (spec, "IndexData16/32"), aligned to its element size.
    out.align(width.bytes());
    out.u32(triangles.len() as u32);
    for code in high_water_mark(triangles.iter().flatten().copied()) {
        width
            .write(&mut out, code)
            .map_err(|()| EncodeError::CodePast16Bits {
                vertices: vertices.len(),
                code,
            })?;
    }

    // Edge lists (spec, "EdgeIndices16/32"): west, south, east, north.
    for list in &edges {
        out.u32(list.len() as u32);
        for &i in list {
            // Edge indices are vertex numbers, which fit the width by its choice.
            width
                .write(&mut out, i)
                .map_err(|()| EncodeError::EdgeIndexPastWidth)?;
        }
    }

    // Extensions (spec, "Extensions"), each an id byte and a 32-bit length.
    if ext.normals {
        let normals = vertex_normals(&vertices, &triangles, &positions, &rect, ellipsoid);
        out.u8(EXTENSION_OCT_NORMALS);
        out.u32(2 * vertices.len() as u32);
        for n in normals {
            out.0.extend_from_slice(&header_geometry::oct_encode(n));
        }
    }
    if let Some(mask) = &ext.water_mask {
        out.u8(EXTENSION_WATER_MASK);
        out.u32(mask.bytes().len() as u32);
        out.0.extend_from_slice(mask.bytes());
    }
    if let Some(json) = &ext.metadata {
        // The extension's data is itself a length and the JSON (spec, "Metadata").
        out.u8(EXTENSION_METADATA);
        out.u32(4 + json.len() as u32);
        out.u32(json.len() as u32);
        out.0.extend_from_slice(json.as_bytes());
    }
    Ok(out.0)
}
