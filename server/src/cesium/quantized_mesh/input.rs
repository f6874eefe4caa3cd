//! What [`super::encode`] checks and derives from its input: the tile's rectangle,
//! the mesh's indices and positions, the metadata's JSON, and the header's height
//! range with the quantization to it.

use super::{EncodeError, MeshVertex, QUANTIZED_MAX, TerrainMesh};

/// A tile's rectangle in degrees, checked.
#[derive(Debug, Clone, Copy)]
pub(super) struct Rect {
    west: f64,
    south: f64,
    east: f64,
    north: f64,
}

impl Rect {
    pub(super) fn new([west, south, east, north]: [f64; 4]) -> Result<Self, EncodeError> {
        let bad = |why: &'static str| {
            Err(EncodeError::DegenerateRect {
                rect: [west, south, east, north],
                why,
            })
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
    pub(super) fn lon_lat(&self, u: u16, v: u16) -> (f64, f64) {
        let t = |q: u16| f64::from(q) / f64::from(QUANTIZED_MAX);
        (
            self.west + t(u) * (self.east - self.west),
            self.south + t(v) * (self.north - self.south),
        )
    }

    pub(super) fn centre(&self) -> (f64, f64) {
        (
            f64::midpoint(self.west, self.east),
            f64::midpoint(self.south, self.north),
        )
    }
}

pub(super) fn check_mesh(mesh: &TerrainMesh) -> Result<(), EncodeError> {
    let n = mesh.vertices.len();
    if n == 0 {
        return Err(EncodeError::NoVertices);
    }
    if u32::try_from(n).is_err() || u32::try_from(mesh.triangles.len()).is_err() {
        return Err(EncodeError::TooLarge {
            vertices: n,
            triangles: mesh.triangles.len(),
        });
    }
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.u > QUANTIZED_MAX || v.v > QUANTIZED_MAX {
            return Err(EncodeError::VertexPast {
                vertex: i,
                u: v.u,
                v: v.v,
            });
        }
        if !v.height.is_finite() {
            return Err(EncodeError::HeightNotFinite {
                vertex: i,
                height: v.height,
            });
        }
    }
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if let Some(&i) = tri.iter().find(|&&i| i as usize >= n) {
            return Err(EncodeError::NoSuchVertex {
                triangle: t,
                indices: *tri,
                vertex: i,
                vertices: n,
            });
        }
    }
    Ok(())
}

pub(super) fn check_metadata(json: &str) -> Result<(), EncodeError> {
    match serde_json::from_str::<serde_json::Value>(json) {
        Ok(serde_json::Value::Object(_)) if u32::try_from(json.len() + 4).is_ok() => Ok(()),
        Ok(serde_json::Value::Object(_)) => Err(EncodeError::MetadataTooLong),
        Ok(_) => Err(EncodeError::MetadataNotAnObject),
        Err(e) => Err(EncodeError::MetadataNotJson(e)),
    }
}

/// The header's height range and the quantization between its ends.
#[derive(Debug, Clone, Copy)]
pub(super) struct HeightRange {
    pub(super) min: f32,
    pub(super) max: f32,
}

impl HeightRange {
    pub(super) fn of(vertices: &[MeshVertex]) -> Result<Self, EncodeError> {
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
            return Err(EncodeError::NoF32Bounds { lo, hi });
        }
        Ok(Self { min, max })
    }

    fn span(self) -> f64 {
        f64::from(self.max) - f64::from(self.min)
    }

    pub(super) fn middle(self) -> f64 {
        f64::midpoint(f64::from(self.min), f64::from(self.max))
    }

    /// The code whose decoded height is nearest `h`.
    pub(super) fn quantize(self, h: f64) -> u16 {
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
    pub(super) fn decode(self, q: u16) -> f64 {
        f64::from(self.min) + f64::from(q) / f64::from(QUANTIZED_MAX) * self.span()
    }
}

/// The greatest f32 not above `x`.
pub(super) fn f32_at_most(x: f64) -> f32 {
    let f = x as f32;
    if f64::from(f) > x { f.next_down() } else { f }
}

/// The least f32 not below `x`.
fn f32_at_least(x: f64) -> f32 {
    let f = x as f32;
    if f64::from(f) < x { f.next_up() } else { f }
}
