//! A real DEM cut by GDAL into Cloud-Optimized GeoTIFF pieces: the collection the
//! distributed-build and update tests read (DECISIONS.md "Distributed build",
//! "Updates").

use super::{gdal_or_skip, path_str, run};
use std::path::{Path, PathBuf};
use tessera_shared::testdata;

/// 16 COG pieces of 512² (256² tiles, deflate, overviews) of the moon mosaic's
/// north-west 2048², in `dir`: `p{row}{col}.tif`.
pub fn cog_pieces(dir: &Path) -> Option<Vec<PathBuf>> {
    let png = testdata::dem_or_skip("moon_crisium_gld100_4096.png")?;
    if !gdal_or_skip() {
        return None;
    }
    let whole = dir.join("whole.tif");
    // 236.9 m samples (the data README); any georeferencing on one grid will do.
    run(
        "gdal_translate",
        &[
            "-q",
            "-srcwin",
            "0",
            "0",
            "2048",
            "2048",
            "-a_ullr",
            "0",
            "485171.2",
            "485171.2",
            "0",
            path_str(&png),
            path_str(&whole),
        ],
    );
    let mut pieces = Vec::new();
    for r in 0..4 {
        for c in 0..4 {
            let p = dir.join(format!("p{r}{c}.tif"));
            let (x, y) = ((c * 512).to_string(), (r * 512).to_string());
            run(
                "gdal_translate",
                &[
                    "-q",
                    "-of",
                    "COG",
                    "-co",
                    "BLOCKSIZE=256",
                    "-co",
                    "COMPRESS=DEFLATE",
                    "-srcwin",
                    &x,
                    &y,
                    "512",
                    "512",
                    path_str(&whole),
                    path_str(&p),
                ],
            );
            pieces.push(p);
        }
    }
    std::fs::remove_file(whole).unwrap();
    Some(pieces)
}

/// A new survey of `piece`: its heights rescaled by GDAL (`-scale`: 0..65535 to
/// 0..60000, a change everywhere), its georeferencing and COG layout kept, written
/// beside it and renamed over it.
pub fn resurvey(piece: &Path) {
    let new = piece.with_extension("new.tif");
    run(
        "gdal_translate",
        &[
            "-q",
            "-of",
            "COG",
            "-co",
            "BLOCKSIZE=256",
            "-co",
            "COMPRESS=DEFLATE",
            "-ot",
            "UInt16",
            "-scale",
            "0",
            "65535",
            "0",
            "60000",
            path_str(piece),
            path_str(&new),
        ],
    );
    std::fs::rename(&new, piece).unwrap();
}
