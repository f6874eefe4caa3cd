//! A quantized-mesh-1.0 decoder of our own for the end-to-end tests (DECISIONS.md "Cesium
//! terrain"), written from the spec (CesiumGS/quantized-mesh, README) and sharing nothing
//! with the server's encoder, so that a round trip checks the encoder against the format
//! rather than against itself.
//!
//! It is strict where the spec is definite (lengths, index ranges, the high-water
//! mark, u/v/height within 0..=32767) and returns `Err` for anything short or
//! inconsistent; it never panics on any input.

/// The largest quantized value (spec: 32767 is the tile's east/north edge and the
/// header's maximum height).
const TOP: u16 = 32767;

/// The fixed header (spec, "QuantizedMeshHeader").
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    /// ECEF, metres.
    pub center: [f64; 3],
    pub minimum_height: f32,
    pub maximum_height: f32,
    /// ECEF, metres.
    pub bounding_sphere_center: [f64; 3],
    pub bounding_sphere_radius: f64,
    /// In the ellipsoid-scaled frame.
    pub horizon_occlusion_point: [f64; 3],
}

/// One extension as found: its id and its bytes (after the 5-byte extension header).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Extension {
    pub id: u8,
    pub data: Vec<u8>,
}

/// A decoded tile.
#[derive(Debug, Clone, PartialEq)]
pub struct Decoded {
    pub header: Header,
    /// Per vertex, after undoing the delta and zig-zag coding: 0..=32767.
    pub u: Vec<u16>,
    pub v: Vec<u16>,
    pub height: Vec<u16>,
    /// 2 or 4: the width of the index data and edge lists.
    pub index_bytes: usize,
    /// After undoing the high-water-mark coding.
    pub triangles: Vec<[u32; 3]>,
    pub west: Vec<u32>,
    pub south: Vec<u32>,
    pub east: Vec<u32>,
    pub north: Vec<u32>,
    /// In the order found.
    pub extensions: Vec<Extension>,
    /// Extension 1, unit vectors, when present.
    pub normals: Option<Vec<[f64; 3]>>,
    /// Extension 4's JSON text, when present.
    pub metadata: Option<String>,
}

impl Decoded {
    /// Each vertex's longitude, latitude (degrees) and height (metres) over the tile
    /// rectangle `rect` = [west, south, east, north]: linear between the edges and
    /// between the header's heights (spec, the VertexData table).
    pub fn positions(&self, rect: [f64; 4]) -> Vec<[f64; 3]> {
        let [west, south, east, north] = rect;
        let lo = f64::from(self.header.minimum_height);
        let hi = f64::from(self.header.maximum_height);
        let frac = |q: u16| f64::from(q) / f64::from(TOP);
        (0..self.u.len())
            .map(|i| {
                [
                    west + (east - west) * frac(self.u[i]),
                    south + (north - south) * frac(self.v[i]),
                    lo + (hi - lo) * frac(self.height[i]),
                ]
            })
            .collect()
    }
}

/// Reads a tile, uncompressed.
pub fn decode(bytes: &[u8]) -> Result<Decoded, String> {
    let mut r = Reader { bytes, at: 0 };
    let header = Header {
        center: r.vec3("header centre")?,
        minimum_height: r.f32("minimum height")?,
        maximum_height: r.f32("maximum height")?,
        bounding_sphere_center: r.vec3("bounding sphere centre")?,
        bounding_sphere_radius: r.f64("bounding sphere radius")?,
        horizon_occlusion_point: r.vec3("horizon occlusion point")?,
    };

    let count = r.u32("vertex count")? as usize;
    // Three arrays (u, v, height) of `count` u16 each.
    let entries = count.checked_mul(3).ok_or("vertex count overflows")?;
    let block = r.take(entries, 2, "vertex data")?;
    let mut arrays = [Vec::new(), Vec::new(), Vec::new()];
    for (a, array) in arrays.iter_mut().enumerate() {
        // Each array runs from zero; every entry is the zig-zagged step from the last.
        let mut running: i32 = 0;
        for i in 0..count {
            let o = 2 * (a * count + i);
            let z = i32::from(u16::from_le_bytes([block[o], block[o + 1]]));
            let step = if z & 1 == 0 { z / 2 } else { -(z + 1) / 2 };
            running += step;
            let value = u16::try_from(running)
                .ok()
                .filter(|&q| q <= TOP)
                .ok_or_else(|| format!("vertex {i}: array {a} decodes to {running}"))?;
            array.push(value);
        }
    }
    let [u, v, height] = arrays;

    // Index data: 32-bit past 64 Ki vertices, preceded by padding to its width.
    let index_bytes = if count > 65_536 { 4 } else { 2 };
    let misaligned = r.at % index_bytes;
    if misaligned != 0 {
        r.take(index_bytes - misaligned, 1, "index padding")?;
    }
    let triangle_count = r.u32("triangle count")? as usize;
    let corners = triangle_count
        .checked_mul(3)
        .ok_or("triangle count overflows")?;
    let codes = r.indices(corners, index_bytes, "triangle indices")?;
    let mut triangles = Vec::with_capacity(triangle_count);
    // The next vertex never seen before; a code says how far below it an index is.
    let mut fresh: u64 = 0;
    let mut corner = [0u32; 3];
    for (k, code) in codes.into_iter().enumerate() {
        let code = u64::from(code);
        if code > fresh {
            return Err(format!(
                "index code {code} at {k} is above the mark {fresh}"
            ));
        }
        let index = fresh - code;
        if index >= count as u64 {
            return Err(format!("index {index} at {k} past {count} vertices"));
        }
        if code == 0 {
            fresh += 1;
        }
        corner[k % 3] = index as u32;
        if k % 3 == 2 {
            triangles.push(corner);
        }
    }

    let mut edge = |name: &str| -> Result<Vec<u32>, String> {
        let n = r.u32(name)? as usize;
        let list = r.indices(n, index_bytes, name)?;
        match list.iter().find(|&&i| i as usize >= count) {
            Some(i) => Err(format!("{name}: index {i} past {count} vertices")),
            None => Ok(list),
        }
    };
    let west = edge("west edge")?;
    let south = edge("south edge")?;
    let east = edge("east edge")?;
    let north = edge("north edge")?;

    let mut extensions = Vec::new();
    let mut normals = None;
    let mut metadata = None;
    while r.at < bytes.len() {
        let id = r.u8("extension id")?;
        let len = r.u32("extension length")? as usize;
        let data = r.take(len, 1, "extension data")?.to_vec();
        if extensions.iter().any(|e: &Extension| e.id == id) {
            return Err(format!("extension {id} appears twice"));
        }
        match id {
            1 => {
                if len != 2 * count {
                    return Err(format!("normals: {len} bytes for {count} vertices"));
                }
                normals = Some(data.chunks_exact(2).map(|c| unoct(c[0], c[1])).collect());
            }
            4 => {
                let head: [u8; 4] = data
                    .get(..4)
                    .and_then(|h| h.try_into().ok())
                    .ok_or("metadata: no length")?;
                let n = u32::from_le_bytes(head) as usize;
                let text = data
                    .get(4..)
                    .and_then(|t| t.get(..n))
                    .ok_or("metadata: JSON longer than its extension")?;
                let text = std::str::from_utf8(text).map_err(|e| format!("metadata: {e}"))?;
                metadata = Some(text.to_string());
            }
            _ => {}
        }
        extensions.push(Extension { id, data });
    }

    Ok(Decoded {
        header,
        u,
        v,
        height,
        index_bytes,
        triangles,
        west,
        south,
        east,
        north,
        extensions,
        normals,
        metadata,
    })
}

/// An oct-encoded normal (spec, extension 1; Cigolle et al. 2014), each byte mapping
/// 0..=255 onto [−1, 1]. Off the octahedron's upper half (z < 0) a point is folded
/// back by moving each coordinate towards zero by the overshoot, then normalised.
fn unoct(a: u8, b: u8) -> [f64; 3] {
    let unit = |c: u8| f64::from(c) * (2.0 / 255.0) - 1.0;
    let (mut x, mut y) = (unit(a), unit(b));
    let z = 1.0 - x.abs() - y.abs();
    let overshoot = (-z).max(0.0);
    x += if x >= 0.0 { -overshoot } else { overshoot };
    y += if y >= 0.0 { -overshoot } else { overshoot };
    let len = (x * x + y * y + z * z).sqrt();
    [x / len, y / len, z / len]
}

/// Little-endian reads that fail, naming the field, instead of running off the end.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    /// `count` items of `size` bytes.
    fn take(&mut self, count: usize, size: usize, what: &str) -> Result<&'a [u8], String> {
        let len = count
            .checked_mul(size)
            .ok_or_else(|| format!("{what}: {count} items overflow"))?;
        let end = self
            .at
            .checked_add(len)
            .filter(|&e| e <= self.bytes.len())
            .ok_or_else(|| {
                format!(
                    "{what}: {len} bytes at {} but the tile has {}",
                    self.at,
                    self.bytes.len()
                )
            })?;
        let slice = &self.bytes[self.at..end];
        self.at = end;
        Ok(slice)
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], String> {
        let s = self.take(N, 1, what)?;
        s.try_into().map_err(|_| format!("{what}: short"))
    }

    fn u8(&mut self, what: &str) -> Result<u8, String> {
        Ok(self.array::<1>(what)?[0])
    }

    fn u32(&mut self, what: &str) -> Result<u32, String> {
        self.array(what).map(u32::from_le_bytes)
    }

    fn f32(&mut self, what: &str) -> Result<f32, String> {
        self.array(what).map(f32::from_le_bytes)
    }

    fn f64(&mut self, what: &str) -> Result<f64, String> {
        self.array(what).map(f64::from_le_bytes)
    }

    fn vec3(&mut self, what: &str) -> Result<[f64; 3], String> {
        Ok([self.f64(what)?, self.f64(what)?, self.f64(what)?])
    }

    /// `n` indices of `width` bytes (2 or 4).
    fn indices(&mut self, n: usize, width: usize, what: &str) -> Result<Vec<u32>, String> {
        let raw = self.take(n, width, what)?;
        Ok(if width == 4 {
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
