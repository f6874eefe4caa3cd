//! A GeoTIFF writer for the reader's tests: little-endian TIFFs written by hand, so
//! that every layout, compression and predictor the reader supports (and some it
//! does not, and headers that lie) can be produced without GDAL.

use super::*;
use std::io::Write;
use tiff::encoder::compression::{CompressionAlgorithm, Deflate, Lzw, Packbits};

/// A temporary file holding some bytes, removed on drop; `.0` derefs to its path.
pub(super) struct TempFile(pub(super) tempfile::TempPath);

impl TempFile {
    pub(super) fn new(name: &str, bytes: &[u8]) -> Self {
        let mut f = tempfile::Builder::new()
            .prefix("tessera-geotiff-test-")
            .suffix(&format!("-{name}"))
            .tempfile()
            .expect("create a temp file");
        f.write_all(bytes).expect("write temp file");
        Self(f.into_temp_path())
    }
}

// ---- synthetic files -----------------------------------------------------

/// A little-endian TIFF written by hand, so that every layout, compression and
/// predictor the reader supports (and some it does not) can be produced.
pub(super) struct Spec {
    pub(super) width: u32,
    pub(super) height: u32,
    pub(super) bits: u16,
    pub(super) format: u16,
    pub(super) bands: u16,
    /// `(tile_width, tile_height)`; strips when `None`.
    pub(super) tiles: Option<(u32, u32)>,
    pub(super) rows_per_strip: u32,
    pub(super) compression: u16,
    pub(super) predictor: u16,
    /// Extra tags: `(tag, type, count, value bytes)`.
    pub(super) extra: Vec<(u16, u16, u32, Vec<u8>)>,
    /// Sample values, row-major, `bands` per pixel.
    pub(super) values: Vec<f64>,
    /// Replaces every chunk's stored byte count (a header that lies).
    pub(super) byte_counts: Option<u32>,
}

impl Spec {
    pub(super) fn new(width: u32, height: u32, sample: SampleType, values: Vec<f64>) -> Self {
        let (bits, format) = match sample {
            SampleType::Int16 => (16, 2),
            SampleType::UInt16 => (16, 1),
            SampleType::Float32 => (32, 3),
        };
        Self {
            width,
            height,
            bits,
            format,
            bands: 1,
            tiles: None,
            rows_per_strip: 5,
            compression: 1,
            predictor: 1,
            extra: Vec::new(),
            values,
            byte_counts: None,
        }
    }

    pub(super) fn ascii(mut self, tag: u16, text: &str) -> Self {
        let mut b = text.as_bytes().to_vec();
        b.push(0);
        self.extra.push((tag, 2, b.len() as u32, b));
        self
    }

    pub(super) fn shorts(mut self, tag: u16, v: &[u16]) -> Self {
        let b = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        self.extra.push((tag, 3, v.len() as u32, b));
        self
    }

    pub(super) fn doubles(mut self, tag: u16, v: &[f64]) -> Self {
        let b = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        self.extra.push((tag, 12, v.len() as u32, b));
        self
    }

    /// One sample's little-endian bytes.
    pub(super) fn sample_bytes(&self, v: f64) -> Vec<u8> {
        match (self.bits, self.format) {
            (8, 1) => vec![v as u8],
            (16, 1) => (v as u16).to_le_bytes().to_vec(),
            (16, 2) => (v as i16).to_le_bytes().to_vec(),
            (32, 3) => (v as f32).to_le_bytes().to_vec(),
            (64, 3) => v.to_le_bytes().to_vec(),
            other => panic!("test writer cannot encode {other:?}"),
        }
    }

    /// Applies the predictor to one row of `n` samples of `size` bytes.
    pub(super) fn predict(&self, row: &mut [u8]) {
        let size = usize::from(self.bits / 8);
        let stride = usize::from(self.bands);
        match self.predictor {
            2 => {
                let n = row.len() / size;
                for i in (stride..n).rev() {
                    let (a, b) = (i * size, (i - stride) * size);
                    match size {
                        2 => {
                            let v = u16::from_le_bytes([row[a], row[a + 1]])
                                .wrapping_sub(u16::from_le_bytes([row[b], row[b + 1]]));
                            row[a..a + 2].copy_from_slice(&v.to_le_bytes());
                        }
                        4 => {
                            let get = |r: &[u8], at: usize| {
                                u32::from_le_bytes(r[at..at + 4].try_into().expect("4"))
                            };
                            let v = get(row, a).wrapping_sub(get(row, b));
                            row[a..a + 4].copy_from_slice(&v.to_le_bytes());
                        }
                        _ => row[a] = row[a].wrapping_sub(row[b]),
                    }
                }
            }
            3 => {
                // Byte planes, most significant first, then byte differences.
                let n = row.len() / size;
                let mut planes = vec![0u8; row.len()];
                for i in 0..n {
                    for byte in 0..size {
                        planes[byte * n + i] = row[i * size + (size - 1 - byte)];
                    }
                }
                for j in (stride..planes.len()).rev() {
                    planes[j] = planes[j].wrapping_sub(planes[j - stride]);
                }
                row.copy_from_slice(&planes);
            }
            _ => {}
        }
    }

    pub(super) fn compress(&self, raw: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        match self.compression {
            5 => Lzw.write_to(&mut out, raw),
            8 | 32946 => Deflate::default().write_to(&mut out, raw),
            32773 => Packbits.write_to(&mut out, raw),
            _ => {
                out.extend_from_slice(raw);
                Ok(0)
            }
        }
        .expect("compress");
        out
    }

    /// The encoded chunks, row-major; tiles are padded with zeros.
    pub(super) fn chunks(&self) -> Vec<Vec<u8>> {
        let (w, h, bands) = (self.width, self.height, u32::from(self.bands));
        let sample = |x: u32, y: u32, b: u32| {
            if x < w && y < h {
                self.values[((y * w + x) * bands + b) as usize]
            } else {
                0.0
            }
        };
        let mut rects = Vec::new();
        if let Some((tw, th)) = self.tiles {
            for ty in 0..h.div_ceil(th) {
                for tx in 0..w.div_ceil(tw) {
                    rects.push((tx * tw, ty * th, tw, th));
                }
            }
        } else {
            let rps = self.rows_per_strip;
            for s in 0..h.div_ceil(rps) {
                rects.push((0, s * rps, w, rps.min(h - s * rps)));
            }
        }
        rects
            .into_iter()
            .map(|(x0, y0, cw, ch)| {
                let mut raw = Vec::new();
                for y in y0..y0 + ch {
                    let mut row: Vec<u8> = (x0..x0 + cw)
                        .flat_map(|x| (0..bands).map(move |b| (x, b)))
                        .flat_map(|(x, b)| self.sample_bytes(sample(x, y, b)))
                        .collect();
                    self.predict(&mut row);
                    raw.extend_from_slice(&row);
                }
                self.compress(&raw)
            })
            .collect()
    }

    pub(super) fn encode(&self) -> Vec<u8> {
        let mut out = b"II*\0\0\0\0\0".to_vec();
        let chunks = self.chunks();
        let (mut offsets, mut counts) = (Vec::new(), Vec::new());
        for c in &chunks {
            offsets.push(out.len() as u32);
            counts.push(self.byte_counts.unwrap_or(c.len() as u32));
            out.extend_from_slice(c);
        }
        let longs = |v: &[u32]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
        let short = |v: u16| v.to_le_bytes().to_vec();
        let per_band =
            |v: u16| -> Vec<u8> { (0..self.bands).flat_map(|_| v.to_le_bytes()).collect() };
        let n = chunks.len() as u32;
        let bands = u32::from(self.bands);
        let mut tags: Vec<(u16, u16, u32, Vec<u8>)> = vec![
            (256, 4, 1, longs(&[self.width])),
            (257, 4, 1, longs(&[self.height])),
            (258, 3, bands, per_band(self.bits)),
            (259, 3, 1, short(self.compression)),
            (262, 3, 1, short(if self.bands == 3 { 2 } else { 1 })),
            (277, 3, 1, short(self.bands)),
            (284, 3, 1, short(1)),
            (339, 3, bands, per_band(self.format)),
        ];
        if self.predictor != 1 {
            tags.push((317, 3, 1, short(self.predictor)));
        }
        if let Some((tw, th)) = self.tiles {
            tags.push((322, 4, 1, longs(&[tw])));
            tags.push((323, 4, 1, longs(&[th])));
            tags.push((324, 4, n, longs(&offsets)));
            tags.push((325, 4, n, longs(&counts)));
        } else {
            tags.push((273, 4, n, longs(&offsets)));
            tags.push((278, 4, 1, longs(&[self.rows_per_strip])));
            tags.push((279, 4, n, longs(&counts)));
        }
        tags.extend(self.extra.iter().cloned());
        tags.sort_by_key(|t| t.0);
        // Values longer than 4 bytes go before the directory.
        let mut fields = Vec::new();
        for (tag, ty, count, value) in tags {
            let field = if value.len() <= 4 {
                let mut v = value.clone();
                v.resize(4, 0);
                v
            } else {
                if out.len() % 2 == 1 {
                    out.push(0);
                }
                let at = (out.len() as u32).to_le_bytes().to_vec();
                out.extend_from_slice(&value);
                at
            };
            fields.push((tag, ty, count, field));
        }
        if out.len() % 2 == 1 {
            out.push(0);
        }
        let ifd = out.len() as u32;
        out[4..8].copy_from_slice(&ifd.to_le_bytes());
        out.extend_from_slice(&(fields.len() as u16).to_le_bytes());
        for (tag, ty, count, field) in fields {
            out.extend_from_slice(&tag.to_le_bytes());
            out.extend_from_slice(&ty.to_le_bytes());
            out.extend_from_slice(&count.to_le_bytes());
            out.extend_from_slice(&field);
        }
        out.extend_from_slice(&0u32.to_le_bytes());
        out
    }

    pub(super) fn write(&self, name: &str) -> TempFile {
        TempFile::new(name, &self.encode())
    }
}

/// A test surface that exercises signs, large steps and (for floats) fractions.
pub(super) fn surface(width: u32, height: u32, sample: SampleType) -> Vec<f64> {
    (0..height)
        .flat_map(|y| (0..width).map(move |x| (x, y)))
        .map(|(x, y)| {
            let v = f64::from(x * 37 + y * 101 % 4099) + f64::from((x ^ y) % 13) * 211.0;
            match sample {
                SampleType::Int16 => v - 3000.0,
                SampleType::UInt16 => v * 7.0,
                SampleType::Float32 => (v - 1500.0) * 0.125 + 0.001 * f64::from(x),
            }
        })
        .collect()
}
