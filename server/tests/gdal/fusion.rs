//! The three-input collection the multi-grid tests fuse (DECISIONS.md "Mixed-grid
//! collections"), made by GDAL in a fresh folder: a 30″ "global" base (N46E008 warped
//! by `gdalwarp -r average`), the real 3″ N46E008 over a sub-window (cut with
//! `gdal_translate -srcwin`) and aletsch.tif (EPSG:2056, 200 m).

use super::{gdal_or_skip, path_str, run};
use std::path::PathBuf;
use tessera_shared::testdata;

/// The fine input's window of N46E008: first column, first row, width, height.
pub const FINE_WINDOW: [u64; 4] = [300, 350, 500, 400];

/// N46E008's north-west corner (its pixels are areas of 1/1200°; the mosaic on its
/// lattice starts at aletsch's west edge).
const N46E008_CORNER: [f64; 2] = [7.999_583_333_333_334, 47.000_416_666_666_666];

/// The three inputs, in a folder removed on drop.
pub struct Collection {
    _dir: tempfile::TempDir,
    pub base: PathBuf,
    pub fine: PathBuf,
    pub aletsch: PathBuf,
}

impl Collection {
    /// `None` (with `SKIPPED`) when GDAL's tools or the DEMs are not here.
    pub fn new() -> Option<Self> {
        if !gdal_or_skip() {
            return None;
        }
        let n46 = testdata::dem_or_skip("N46E008.tif")?;
        let aletsch = testdata::dem_or_skip("aletsch.tif")?;
        let dir = tempfile::tempdir().unwrap();
        let base = dir.path().join("base_30s.tif");
        let step = format!("{:.15}", 30.0 / 3600.0);
        run(
            "gdalwarp",
            &[
                "-q",
                "-r",
                "average",
                "-tr",
                &step,
                &step,
                path_str(&n46),
                path_str(&base),
            ],
        );
        let fine = dir.path().join("fine_3s.tif");
        let window = FINE_WINDOW.map(|v| v.to_string());
        run(
            "gdal_translate",
            &[
                "-q",
                "-srcwin",
                &window[0],
                &window[1],
                &window[2],
                &window[3],
                path_str(&n46),
                path_str(&fine),
            ],
        );
        Some(Self {
            _dir: dir,
            base,
            fine,
            aletsch,
        })
    }

    /// The fine window's samples `[x0, y0, x1, y1)` on a mosaic of N46E008's lattice
    /// whose geotransform is `gt`.
    pub fn fine_window_on(gt: &[f64; 6]) -> [u64; 4] {
        let x0 = ((N46E008_CORNER[0] - gt[0]) * 1200.0).round() as u64 + FINE_WINDOW[0];
        let y0 = ((gt[3] - N46E008_CORNER[1]) * 1200.0).round() as u64 + FINE_WINDOW[1];
        [x0, y0, x0 + FINE_WINDOW[2], y0 + FINE_WINDOW[3]]
    }
}
