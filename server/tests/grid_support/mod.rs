//! What the standard-grid tile tests share (`serve_grid_tiles.rs`,
//! `serve_grid_requests.rs`): their pyramids, built once per test binary from real
//! DEMs, and reading tiles back (PNG pixels, Terrarium heights, the XYZ scheme).

use crate::serve_support::{Server, build_pyramid};
use std::path::PathBuf;
use std::sync::OnceLock;
use tessera_shared::testdata;

/// The pyramids of this test binary, built once into a temporary folder.
pub struct Built {
    _dir: tempfile::TempDir,
    pub n46e008: PathBuf,
    pub aletsch: PathBuf,
}

pub fn built() -> Option<&'static Built> {
    static B: OnceLock<Option<Built>> = OnceLock::new();
    B.get_or_init(|| {
        let n46 = testdata::dem_or_skip("N46E008.tif")?;
        let aletsch = testdata::dem_or_skip("aletsch.tif")?;
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("N46E008.tess");
        let b = dir.path().join("aletsch.tess");
        build_pyramid(n46.to_str().unwrap(), &a, 256);
        build_pyramid(aletsch.to_str().unwrap(), &b, 64);
        Some(Built {
            _dir: dir,
            n46e008: a,
            aletsch: b,
        })
    })
    .as_ref()
}

/// RGBA pixels of a PNG.
pub fn decode_rgba(bytes: &[u8]) -> (u32, Vec<u8>) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgba, "want RGBA");
    assert_eq!(info.width, info.height);
    buf.truncate(info.buffer_size());
    (info.width, buf)
}

pub fn terrarium(p: &[u8]) -> f64 {
    f64::from(p[0]) * 256.0 + f64::from(p[1]) + f64::from(p[2]) / 256.0 - 32768.0
}

/// Web Mercator tile `(x, y)` at zoom `z` holding `(lon, lat)` — the XYZ scheme's
/// definition, written out here as an independent check of the server's grid.
pub fn xyz_tile(lon: f64, lat: f64, z: u8) -> (u32, u32) {
    let n = f64::from(1u32 << z);
    let x = (lon + 180.0) / 360.0 * n;
    let l = lat.to_radians();
    let y = (1.0 - (l.tan() + 1.0 / l.cos()).ln() / std::f64::consts::PI) / 2.0 * n;
    (x as u32, y as u32)
}

/// The `bounds` (west, south, east, north in degrees) of `dataset`'s Web Mercator
/// TileJSON on `srv`.
pub fn tilejson_bounds(srv: &Server, dataset: &str) -> Vec<f64> {
    let tj = srv
        .get(&format!("/v1/datasets/{dataset}/webmercator/tilejson.json"))
        .expect(200)
        .json();
    tj["bounds"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect()
}
