//! The quantized-mesh-1.0 tile format (issue 15, DESIGN §9): a mesh from
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
//! 5. extensions, each an id byte and a 32-bit length: oct-encoded vertex normals
//!    (id 1) and metadata (id 4) when asked for.
//!
//! The tile is built uncompressed; the server gzips it. Every number in the header is
//! computed from the values a client decodes (quantized positions and heights), not
//! from the mesher's, so the bounds it states hold for what is drawn.

use super::ellipsoid::{self, Ellipsoid};

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
    /// A JSON object for the metadata extension (id 4, `metadata`), e.g. child
    /// availability.
    pub metadata: Option<String>,
    // The water mask (id 2) is not produced: it would be one more field here and one
    // more extension between the normals and the metadata in `encode`.
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
///   ([`ellipsoid::bounding_sphere`]).
/// - horizon-occlusion point: of the same positions
///   ([`ellipsoid::horizon_occlusion_point`]), against the ellipsoid shrunk by a
///   negative minimum height as CesiumJS tests it ([`Ellipsoid::possibly_shrunk`]);
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
) -> Result<Vec<u8>, String> {
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
    let positions: Vec<[f64; 3]> = vertices
        .iter()
        .zip(&quantized)
        .map(|(v, &q)| {
            let (lon, lat) = rect.lon_lat(v.u, v.v);
            ellipsoid.to_ecef(lon, lat, range.decode(q))
        })
        .collect();

    let (centre_lon, centre_lat) = rect.centre();
    let centre = ellipsoid.to_ecef(centre_lon, centre_lat, range.middle());
    let (sphere_centre, sphere_radius) = ellipsoid::bounding_sphere(&positions);
    let occluder = ellipsoid.possibly_shrunk(f64::from(range.min));
    let horizon =
        ellipsoid::horizon_occlusion_point(&occluder, centre, &positions).unwrap_or_else(|| {
            let s = occluder.to_scaled_space(ellipsoid.to_ecef(centre_lon, centre_lat, 0.0));
            let len = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
            s.map(|c| c / len * UNBOUNDED_HORIZON_DISTANCE)
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
            + ext.metadata.as_ref().map_or(0, |m| 9 + m.len()),
    ));

    // Header (spec, "QuantizedMeshHeader").
    out.f64s(&centre);
    out.f32(range.min);
    out.f32(range.max);
    out.f64s(&sphere_centre);
    out.f64s(&[sphere_radius]);
    out.f64s(&horizon);

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
        width.write(&mut out, code).map_err(|()| {
            format!(
                "{} vertices take 16-bit indices, but the triangle list has an index \
                 code of {code}, past 16 bits; the mesh must use one vertex more or fewer",
                vertices.len()
            )
        })?;
    }

    // Edge lists (spec, "EdgeIndices16/32"): west, south, east, north.
    for list in &edges {
        out.u32(list.len() as u32);
        for &i in list {
            // Edge indices are vertex numbers, which fit the width by its choice.
            width
                .write(&mut out, i)
                .map_err(|()| "edge index past its width".to_string())?;
        }
    }

    // Extensions (spec, "Extensions"), each an id byte and a 32-bit length.
    if ext.normals {
        let normals = vertex_normals(&vertices, &triangles, &positions, &rect, ellipsoid);
        out.u8(EXTENSION_OCT_NORMALS);
        out.u32(2 * vertices.len() as u32);
        for n in normals {
            out.0.extend_from_slice(&ellipsoid::oct_encode(n));
        }
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

/// A tile's rectangle in degrees, checked.
#[derive(Debug, Clone, Copy)]
struct Rect {
    west: f64,
    south: f64,
    east: f64,
    north: f64,
}

impl Rect {
    fn new([west, south, east, north]: [f64; 4]) -> Result<Self, String> {
        let bad = |why: &str| {
            Err(format!(
                "degenerate tile rectangle {:?}: {why}",
                [west, south, east, north]
            ))
        };
        if ![west, south, east, north].iter().all(|c| c.is_finite()) {
            return bad("an edge is not finite");
        }
        if west >= east || south >= north {
            return bad("it must run west < east and south < north");
        }
        if east - west > 360.0 {
            return bad("it is more than 360° wide");
        }
        if south < -90.0 || north > 90.0 {
            return bad("a latitude is beyond ±90°");
        }
        Ok(Self {
            west,
            south,
            east,
            north,
        })
    }

    /// Longitude and latitude of a quantized position (spec: linear between the edges).
    fn lon_lat(&self, u: u16, v: u16) -> (f64, f64) {
        let t = |q: u16| f64::from(q) / f64::from(QUANTIZED_MAX);
        (
            self.west + t(u) * (self.east - self.west),
            self.south + t(v) * (self.north - self.south),
        )
    }

    fn centre(&self) -> (f64, f64) {
        (
            f64::midpoint(self.west, self.east),
            f64::midpoint(self.south, self.north),
        )
    }
}

fn check_mesh(mesh: &TerrainMesh) -> Result<(), String> {
    let n = mesh.vertices.len();
    if n == 0 {
        return Err("a tile needs at least one vertex".into());
    }
    if u32::try_from(n).is_err() || u32::try_from(mesh.triangles.len()).is_err() {
        return Err(format!(
            "{n} vertices and {} triangles: more than a tile's 32-bit counts hold",
            mesh.triangles.len()
        ));
    }
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.u > QUANTIZED_MAX || v.v > QUANTIZED_MAX {
            return Err(format!(
                "vertex {i} at u {} v {}: past {QUANTIZED_MAX}",
                v.u, v.v
            ));
        }
        if !v.height.is_finite() {
            return Err(format!("vertex {i} has height {}", v.height));
        }
    }
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if let Some(&i) = tri.iter().find(|&&i| i as usize >= n) {
            return Err(format!("triangle {t} {tri:?} uses vertex {i} of {n}"));
        }
    }
    Ok(())
}

fn check_metadata(json: &str) -> Result<(), String> {
    match serde_json::from_str::<serde_json::Value>(json) {
        Ok(serde_json::Value::Object(_)) if u32::try_from(json.len() + 4).is_ok() => Ok(()),
        Ok(serde_json::Value::Object(_)) => Err("metadata longer than 32-bit lengths hold".into()),
        Ok(_) => Err("metadata must be a JSON object (spec, \"Metadata\")".into()),
        Err(e) => Err(format!("metadata is not JSON: {e}")),
    }
}

/// The header's height range and the quantization between its ends.
#[derive(Debug, Clone, Copy)]
struct HeightRange {
    min: f32,
    max: f32,
}

impl HeightRange {
    fn of(vertices: &[MeshVertex]) -> Result<Self, String> {
        let lo = vertices
            .iter()
            .map(|v| v.height)
            .fold(f64::INFINITY, f64::min);
        let hi = vertices
            .iter()
            .map(|v| v.height)
            .fold(f64::NEG_INFINITY, f64::max);
        let (min, max) = (f32_at_most(lo), f32_at_least(hi));
        if !(min.is_finite() && max.is_finite()) {
            return Err(format!("heights {lo}..{hi} m have no finite f32 bounds"));
        }
        Ok(Self { min, max })
    }

    fn span(self) -> f64 {
        f64::from(self.max) - f64::from(self.min)
    }

    fn middle(self) -> f64 {
        f64::midpoint(f64::from(self.min), f64::from(self.max))
    }

    /// The code whose decoded height is nearest `h`.
    fn quantize(self, h: f64) -> u16 {
        let span = self.span();
        if span <= 0.0 {
            return 0;
        }
        let t = (h - f64::from(self.min)) / span;
        (t * f64::from(QUANTIZED_MAX))
            .round()
            .clamp(0.0, f64::from(QUANTIZED_MAX)) as u16
    }

    /// The height a client decodes from a code (spec: linear between the header's
    /// minimum and maximum).
    fn decode(self, q: u16) -> f64 {
        f64::from(self.min) + f64::from(q) / f64::from(QUANTIZED_MAX) * self.span()
    }
}

/// The greatest f32 not above `x`.
fn f32_at_most(x: f64) -> f32 {
    let f = x as f32;
    if f64::from(f) > x { f.next_down() } else { f }
}

/// The least f32 not below `x`.
fn f32_at_least(x: f64) -> f32 {
    let f = x as f32;
    if f64::from(f) < x { f.next_up() } else { f }
}

/// Zig-zag coding (spec, "VertexData"): 0, −1, 1, −2… become 0, 1, 2, 3…. Deltas of
/// values in 0..=32767 lie in ±32767, whose codes fit 16 bits.
fn zig_zag(delta: i32) -> u16 {
    ((delta << 1) ^ (delta >> 31)) as u16
}

/// High-water-mark codes of an index list whose vertices first appear in order
/// (spec, "IndexData", from webgl-loader): the distance below the next new vertex,
/// so 0 means "the next new one".
fn high_water_mark(indices: impl Iterator<Item = u32>) -> Vec<u32> {
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
fn edge_lists(vertices: &[MeshVertex]) -> [Vec<u32>; 4] {
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
fn vertex_normals(
    vertices: &[MeshVertex],
    triangles: &[[u32; 3]],
    positions: &[[f64; 3]],
    rect: &Rect,
    ellipsoid: &Ellipsoid,
) -> Vec<[f64; 3]> {
    let mut sums = vec![[0.0f64; 3]; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| positions[i as usize]);
        let ab = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let ac = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [
            ab[1] * ac[2] - ab[2] * ac[1],
            ab[2] * ac[0] - ab[0] * ac[2],
            ab[0] * ac[1] - ab[1] * ac[0],
        ];
        for &i in t {
            for (s, n) in sums[i as usize].iter_mut().zip(n) {
                *s += n;
            }
        }
    }
    sums.iter()
        .zip(vertices)
        .map(|(s, v)| {
            let len = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
            if len > 0.0 && len.is_finite() {
                s.map(|c| c / len)
            } else {
                let (lon, lat) = rect.lon_lat(v.u, v.v);
                ellipsoid.geodetic_surface_normal(lon, lat)
            }
        })
        .collect()
}

/// The width of index data: 16-bit up to 65536 vertices, 32-bit past.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum IndexWidth {
    U16,
    U32,
}

impl IndexWidth {
    fn bytes(self) -> usize {
        match self {
            Self::U16 => 2,
            Self::U32 => 4,
        }
    }

    fn write(self, out: &mut Writer, value: u32) -> Result<(), ()> {
        match self {
            Self::U16 => out.u16(u16::try_from(value).map_err(|_| ())?),
            Self::U32 => out.u32(value),
        }
        Ok(())
    }
}

/// Little-endian output (spec: "tiles are little-endian").
#[derive(Debug)]
struct Writer(Vec<u8>);

impl Writer {
    fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    fn u16(&mut self, v: u16) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f32(&mut self, v: f32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f64s(&mut self, vs: &[f64]) {
        for v in vs {
            self.0.extend_from_slice(&v.to_le_bytes());
        }
    }
    /// Zero bytes up to a multiple of `n` from the tile's start (spec: "padding is
    /// added before the IndexData to ensure 2 byte alignment for IndexData16 and 4
    /// byte alignment for IndexData32").
    fn align(&mut self, n: usize) {
        while !self.0.len().is_multiple_of(n) {
            self.0.push(0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RECT: [f64; 4] = [7.5, 45.0, 7.75, 45.25];

    fn vertex(u: u16, v: u16, height: f64) -> MeshVertex {
        MeshVertex { u, v, height }
    }

    /// A `side`×`side` grid of vertices over the tile, two triangles a cell.
    fn grid(side: u32, height: impl Fn(u32, u32) -> f64) -> TerrainMesh {
        let q = |i: u32| (u64::from(i) * u64::from(QUANTIZED_MAX) / u64::from(side - 1)) as u16;
        let mut vertices = Vec::new();
        for j in 0..side {
            for i in 0..side {
                vertices.push(vertex(q(i), q(j), height(i, j)));
            }
        }
        let mut triangles = Vec::new();
        for j in 0..side - 1 {
            for i in 0..side - 1 {
                let k = j * side + i;
                triangles.push([k, k + 1, k + side + 1]);
                triangles.push([k, k + side + 1, k + side]);
            }
        }
        TerrainMesh {
            vertices,
            triangles,
        }
    }

    /// The parts of a tile these tests read back: header numbers and decoded vertices.
    struct Read {
        min: f32,
        max: f32,
        sphere: ([f64; 3], f64),
        u: Vec<u16>,
        v: Vec<u16>,
        h: Vec<u16>,
        /// Where the vertex data ends.
        end: usize,
    }

    fn read(bytes: &[u8]) -> Read {
        let f64_at = |o: usize| f64::from_le_bytes(bytes[o..o + 8].try_into().unwrap());
        let f32_at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
        let n = u32::from_le_bytes(bytes[88..92].try_into().unwrap()) as usize;
        let array = |a: usize| {
            let mut value = 0i32;
            (0..n)
                .map(|i| {
                    let o = 92 + 2 * (a * n + i);
                    let z = i32::from(u16::from_le_bytes([bytes[o], bytes[o + 1]]));
                    value += (z >> 1) ^ -(z & 1);
                    value as u16
                })
                .collect::<Vec<u16>>()
        };
        Read {
            min: f32_at(24),
            max: f32_at(28),
            sphere: ([f64_at(32), f64_at(40), f64_at(48)], f64_at(56)),
            u: array(0),
            v: array(1),
            h: array(2),
            end: 92 + 6 * n,
        }
    }

    #[test]
    fn header_bounds_contain_every_decoded_vertex() {
        let mesh = grid(5, |i, j| {
            -12.3 + f64::from(i * 37 % 11) * 101.7 + f64::from(j) * 0.01
        });
        let e = Ellipsoid::WGS84;
        let bytes = encode(&mesh, RECT, &e, &Extensions::default()).unwrap();
        let r = read(&bytes);
        let order = vertex_order(&mesh);
        let (lo, hi) = (f64::from(r.min), f64::from(r.max));
        let step = (hi - lo) / f64::from(QUANTIZED_MAX);
        let rect = Rect::new(RECT).unwrap();
        for (k, &old) in order.iter().enumerate() {
            let want = mesh.vertices[old as usize];
            assert_eq!((r.u[k], r.v[k]), (want.u, want.v));
            assert!(lo <= want.height && want.height <= hi);
            let h = lo + f64::from(r.h[k]) * step;
            assert!(
                (h - want.height).abs() <= step / 2.0 * (1.0 + 1e-9),
                "vertex {k}"
            );
            let (lon, lat) = rect.lon_lat(r.u[k], r.v[k]);
            let p = e.to_ecef(lon, lat, h);
            let c = r.sphere.0;
            let d = ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt();
            assert!(
                d <= r.sphere.1 * (1.0 + 1e-12),
                "vertex {k} outside the sphere"
            );
        }
        // The f32 bounds are the tightest that contain the heights.
        assert_eq!(r.min, f32_at_most(-12.3));
        assert!(f64::from(r.min) <= -12.3 && f64::from(r.min.next_up()) > -12.3);
        let top = mesh
            .vertices
            .iter()
            .map(|v| v.height)
            .fold(f64::MIN, f64::max);
        assert!(f64::from(r.max) >= top && f64::from(r.max.next_down()) < top);
    }

    #[test]
    fn a_flat_tile_stores_zero_heights() {
        let mesh = grid(3, |_, _| 250.0);
        let bytes = encode(&mesh, RECT, &Ellipsoid::WGS84, &Extensions::default()).unwrap();
        let r = read(&bytes);
        assert_eq!((r.min, r.max), (250.0, 250.0));
        assert!(r.h.iter().all(|&h| h == 0));
    }

    #[test]
    fn high_water_mark_codes_a_hand_made_list() {
        let indices = [0, 1, 2, 2, 1, 3, 0, 2, 4];
        let codes = high_water_mark(indices.into_iter());
        assert_eq!(codes, [0, 0, 0, 1, 2, 0, 4, 2, 0]);
        // The spec's decoder gives the list back.
        let mut highest = 0;
        let decoded: Vec<u32> = codes
            .iter()
            .map(|&c| {
                let i = highest - c;
                if c == 0 {
                    highest += 1;
                }
                i
            })
            .collect();
        assert_eq!(decoded, indices);

        // Vertices the triangles meet out of order are renumbered into first-use order,
        // and a vertex no triangle uses goes last; the tile holds those codes.
        let mesh = TerrainMesh {
            vertices: (0..6)
                .map(|i| vertex(i * 100, i * 50, f64::from(i)))
                .collect(),
            triangles: vec![[3, 0, 5], [5, 0, 1], [3, 5, 2]],
        };
        assert_eq!(vertex_order(&mesh), [3, 0, 5, 1, 2, 4]);
        let bytes = encode(&mesh, RECT, &Ellipsoid::WGS84, &Extensions::default()).unwrap();
        let at = read(&bytes).end; // 16-bit data, already 2-aligned
        assert_eq!(at % 2, 0);
        assert_eq!(u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()), 3);
        let stored: Vec<u16> = (0..9)
            .map(|i| u16::from_le_bytes([bytes[at + 4 + 2 * i], bytes[at + 5 + 2 * i]]))
            .collect();
        // Renumbered: [0, 1, 2], [2, 1, 3], [0, 2, 4].
        assert_eq!(stored, [0, 0, 0, 1, 2, 0, 4, 2, 0]);
    }

    /// Bytes of a tile without extensions for `n` vertices, `t` triangles and `e` edge
    /// vertices with `w`-byte indices.
    fn tile_len(n: usize, t: usize, e: usize, w: usize) -> usize {
        let vertex_end = HEADER_BYTES + 4 + 6 * n;
        vertex_end.next_multiple_of(w) + 4 + 3 * t * w + 16 + e * w
    }

    #[test]
    fn indices_go_32_bit_past_65536_vertices() {
        // 257² = 66049 vertices: 32-bit, and an odd count, so 2 bytes of padding.
        let mesh = grid(257, |i, j| f64::from(i + j));
        let n = mesh.vertices.len();
        let bytes = encode(&mesh, RECT, &Ellipsoid::WGS84, &Extensions::default()).unwrap();
        let edge = 4 * 257; // corners are on two edges each
        assert_eq!(bytes.len(), tile_len(n, mesh.triangles.len(), edge, 4));
        let r = read(&bytes);
        assert_eq!(r.end % 4, 2);
        assert_eq!(bytes[r.end..r.end + 2], [0, 0]);
        let at = r.end + 2;
        let t = u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
        assert_eq!(t as usize, mesh.triangles.len());
        // The first triangle's three new vertices: codes 0, 0, 0 as 32-bit words.
        assert_eq!(bytes[at + 4..at + 16], [0; 12]);

        // 256² = 65536 vertices is still 16-bit.
        let mesh = grid(256, |i, j| f64::from(i * j));
        let bytes = encode(&mesh, RECT, &Ellipsoid::WGS84, &Extensions::default()).unwrap();
        assert_eq!(
            bytes.len(),
            tile_len(65_536, mesh.triangles.len(), 4 * 256, 2)
        );
    }

    #[test]
    fn a_16_bit_code_that_does_not_fit_is_an_error() {
        // 65536 vertices in a strip, then a triangle back at the first.
        let vertices: Vec<MeshVertex> = (0..65_536u32)
            .map(|i| vertex((i % 32_768) as u16, (i / 32_768) as u16, 0.0))
            .collect();
        let mut triangles: Vec<[u32; 3]> = (0..65_534).map(|i| [i, i + 1, i + 2]).collect();
        triangles.push([65_535, 0, 1]);
        let mesh = TerrainMesh {
            vertices,
            triangles,
        };
        let err = encode(&mesh, RECT, &Ellipsoid::WGS84, &Extensions::default()).unwrap_err();
        assert!(err.contains("past 16 bits"), "{err}");
    }

    #[test]
    fn bad_input_is_an_error() {
        let e = Ellipsoid::WGS84;
        let none = Extensions::default();
        let mesh = grid(2, |_, _| 0.0);
        let empty = TerrainMesh::default();
        assert!(
            encode(&empty, RECT, &e, &none)
                .unwrap_err()
                .contains("at least one vertex")
        );
        let mut out_of_range = mesh.clone();
        out_of_range.triangles.push([0, 1, 4]);
        assert!(
            encode(&out_of_range, RECT, &e, &none)
                .unwrap_err()
                .contains("vertex 4 of 4")
        );
        for rect in [
            [7.0, 45.0, 7.0, 46.0],
            [8.0, 45.0, 7.0, 46.0],
            [7.0, 46.0, 8.0, 46.0],
            [f64::NAN, 45.0, 8.0, 46.0],
            [7.0, 45.0, f64::INFINITY, 46.0],
            [-180.0, -91.0, 0.0, 0.0],
            [-180.0, 0.0, 181.0, 10.0],
        ] {
            assert!(
                encode(&mesh, rect, &e, &none)
                    .unwrap_err()
                    .contains("degenerate"),
                "{rect:?}"
            );
        }
        let mut past = mesh.clone();
        past.vertices[1].u = 32_768;
        assert!(encode(&past, RECT, &e, &none).is_err());
        let mut nan = mesh.clone();
        nan.vertices[2].height = f64::NAN;
        assert!(encode(&nan, RECT, &e, &none).is_err());
        let mut huge = mesh.clone();
        huge.vertices[2].height = 1e300;
        assert!(encode(&huge, RECT, &e, &none).is_err());
        for json in ["[1, 2]", "{\"a\":", "\"x\""] {
            let ext = Extensions {
                normals: false,
                metadata: Some(json.into()),
            };
            assert!(
                encode(&mesh, RECT, &e, &ext)
                    .unwrap_err()
                    .contains("metadata"),
                "{json}"
            );
        }
    }

    #[test]
    fn extensions_follow_the_edges() {
        let mesh = grid(3, |i, j| f64::from(i * 10 + j));
        let e = Ellipsoid::WGS84;
        let plain = encode(&mesh, RECT, &e, &Extensions::default()).unwrap();
        let json = r#"{"available":[[{"startX":0,"startY":0,"endX":1,"endY":1}]]}"#;
        let ext = Extensions {
            normals: true,
            metadata: Some(json.into()),
        };
        let full = encode(&mesh, RECT, &e, &ext).unwrap();
        assert_eq!(full[..plain.len()], plain[..]);
        let rest = &full[plain.len()..];
        assert_eq!(rest[0], EXTENSION_OCT_NORMALS);
        assert_eq!(u32::from_le_bytes(rest[1..5].try_into().unwrap()), 18);
        // A flat-ish tile's normals point up, near the ellipsoid's normal.
        let up = e.geodetic_surface_normal(7.625, 45.125);
        for k in 0..9 {
            let n = ellipsoid::oct_decode([rest[5 + 2 * k], rest[6 + 2 * k]]);
            let cos = n[0] * up[0] + n[1] * up[1] + n[2] * up[2];
            assert!(cos > 0.99, "vertex {k}: {n:?}");
        }
        let m = &rest[23..];
        assert_eq!(m[0], EXTENSION_METADATA);
        assert_eq!(
            u32::from_le_bytes(m[1..5].try_into().unwrap()) as usize,
            4 + json.len()
        );
        assert_eq!(
            u32::from_le_bytes(m[5..9].try_into().unwrap()) as usize,
            json.len()
        );
        assert_eq!(&m[9..], json.as_bytes());
    }

    #[test]
    fn the_centre_is_the_rectangles_at_mid_height() {
        let mesh = grid(3, |i, _| f64::from(i) * 100.0);
        let e = Ellipsoid::WGS84;
        let bytes = encode(&mesh, RECT, &e, &Extensions::default()).unwrap();
        let c: Vec<f64> = (0..3)
            .map(|i| f64::from_le_bytes(bytes[8 * i..8 * i + 8].try_into().unwrap()))
            .collect();
        assert_eq!(c, e.to_ecef(7.625, 45.125, 100.0));
    }

    #[test]
    fn a_hemisphere_gets_the_far_occlusion_point() {
        let mesh = grid(3, |_, _| 10.0);
        let e = Ellipsoid::WGS84;
        let bytes = encode(
            &mesh,
            [-180.0, -90.0, 0.0, 90.0],
            &e,
            &Extensions::default(),
        )
        .unwrap();
        let p: Vec<f64> = (0..3)
            .map(|i| f64::from_le_bytes(bytes[64 + 8 * i..72 + 8 * i].try_into().unwrap()))
            .collect();
        // Along −y (longitude −90°, the equator), 1e6 out.
        assert!(p[0].abs() < 1e-3 && p[2].abs() < 1e-3, "{p:?}");
        assert!((p[1] + UNBOUNDED_HORIZON_DISTANCE).abs() < 1e-3, "{p:?}");
    }
}
