//! Helpers of the Cesium terrain tests over HTTP (serve_cesium.rs, serve_cesium_water.rs):
//! the pyramids they serve, and quantized-mesh tiles read back.

use crate::serve_support::bin;
use std::path::PathBuf;
use std::process::Command;
use std::sync::OnceLock;
use tessera_server::cesium::tiling::CesiumTile;
use tessera_shared::testdata;

pub const ACCEPT_ALL: &str = "application/vnd.quantized-mesh;extensions=octvertexnormals-watermask-metadata,application/octet-stream;q=0.9,*/*;q=0.01";

pub struct Built {
    _dir: tempfile::TempDir,
    pub srtm: PathBuf,
    pub synthetic: PathBuf,
}

pub fn built() -> Option<&'static Built> {
    static B: OnceLock<Option<Built>> = OnceLock::new();
    B.get_or_init(|| {
        let dem = testdata::dem_or_skip("N46E008.tif")?;
        let dir = tempfile::tempdir().unwrap();
        let srtm = dir.path().join("N46E008.tess");
        let synthetic = dir.path().join("synthetic.tess");
        for (input, out, extra) in [
            (
                dem.to_str().unwrap(),
                &srtm,
                &["--vertical-datum", "egm96"][..],
            ),
            ("synthetic:257", &synthetic, &[][..]),
        ] {
            let o = bin()
                .args(["build", input, "-o"])
                .arg(out)
                .args(["--tile-size", "256", "--quiet"])
                .args(extra)
                .output()
                .unwrap();
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        }
        Some(Built {
            _dir: dir,
            srtm,
            synthetic,
        })
    })
    .as_ref()
}

/// The extensions of a quantized-mesh tile: `(id, bytes)` in order.
pub fn extensions_of(tile: &[u8]) -> Vec<(u8, Vec<u8>)> {
    let u32_at = |p: usize| u32::from_le_bytes(tile[p..p + 4].try_into().unwrap()) as usize;
    let mut p = 88;
    let n = u32_at(p);
    p += 4 + 6 * n;
    let width = if n > 65_536 { 4 } else { 2 };
    p = p.next_multiple_of(width);
    let triangles = u32_at(p);
    p += 4 + 3 * triangles * width;
    for _ in 0..4 {
        let k = u32_at(p);
        p += 4 + k * width;
    }
    let mut out = Vec::new();
    while p < tile.len() {
        let id = tile[p];
        let len = u32_at(p + 1);
        out.push((id, tile[p + 5..p + 5 + len].to_vec()));
        p += 5 + len;
    }
    out
}

/// The metadata extension's JSON.
pub fn metadata_of(tile: &[u8]) -> serde_json::Value {
    let (_, m) = extensions_of(tile)
        .into_iter()
        .find(|(id, _)| *id == 4)
        .expect("a metadata extension");
    serde_json::from_slice(&m[4..]).unwrap()
}

/// Whether a tile's `available` ranges (one level) hold `(x, y)`.
pub fn listed(ranges: &serde_json::Value, x: u32, y: u32) -> bool {
    ranges.as_array().unwrap().iter().any(|r| {
        let v = |k: &str| r[k].as_u64().unwrap() as u32;
        (v("startX")..=v("endX")).contains(&x) && (v("startY")..=v("endY")).contains(&y)
    })
}

/// The zoom-`z` tile holding a point.
pub fn tile_at(z: u8, lon: f64, lat: f64) -> CesiumTile {
    let span = CesiumTile::span(z);
    CesiumTile::new(
        z,
        ((lon + 180.0) / span) as u32,
        ((lat + 90.0) / span) as u32,
    )
    .unwrap()
}

pub fn run(cmd: &mut Command) {
    let o = cmd.output().unwrap();
    assert!(
        o.status.success(),
        "{cmd:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

pub fn gdal() -> bool {
    Command::new("gdal_translate")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
}
