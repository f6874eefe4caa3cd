//! A DEM as GDAL reads it, sampled bilinearly on its own samples: the reference
//! heights of the tests that check what a user would measure.

use std::path::Path;

/// A DEM as GDAL reads it: samples (NaN for no-data), geotransform, size, CRS.
pub struct Dem {
    pub values: Vec<f64>,
    pub width: usize,
    pub height: usize,
    pub gt: [f64; 6],
    pub epsg: String,
}

impl Dem {
    /// Reads `path` through `gdal_translate` into raw float64, the no-data as NaN.
    pub fn read(path: &Path, epsg: &str) -> Self {
        let info: serde_json::Value =
            serde_json::from_str(&super::run("gdalinfo", &["-json", super::path_str(path)]))
                .unwrap();
        let gt: Vec<f64> = info["geoTransform"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let size = info["size"].as_array().unwrap();
        let (width, height) = (
            size[0].as_u64().unwrap() as usize,
            size[1].as_u64().unwrap() as usize,
        );
        let nodata = info["bands"][0]["noDataValue"].as_f64();
        let dir = tempfile::tempdir().unwrap();
        let raw = dir.path().join("dem.bin");
        super::run(
            "gdal_translate",
            &[
                "-q",
                "-of",
                "ENVI",
                "-ot",
                "Float64",
                super::path_str(path),
                super::path_str(&raw),
            ],
        );
        let bytes = std::fs::read(&raw).unwrap();
        let values = bytes
            .chunks_exact(8)
            .map(|c| {
                let v = f64::from_le_bytes(c.try_into().unwrap());
                if Some(v) == nodata { f64::NAN } else { v }
            })
            .collect::<Vec<_>>();
        assert_eq!(values.len(), width * height);
        Self {
            values,
            width,
            height,
            gt: gt.try_into().unwrap(),
            epsg: epsg.to_string(),
        }
    }

    /// Whether the sample nearest CRS point `(x, y)` holds data: where GDAL, taking
    /// each sample for its pixel, has terrain. `false` beyond the samples.
    pub fn has_data(&self, x: f64, y: f64) -> bool {
        let x = if self.epsg == "EPSG:4326" && x < self.gt[0] {
            x + 360.0
        } else {
            x
        };
        let c = ((x - self.gt[0]) / self.gt[1]).floor();
        let r = ((y - self.gt[3]) / self.gt[5]).floor();
        c >= 0.0
            && r >= 0.0
            && (c as usize) < self.width
            && (r as usize) < self.height
            && !self.values[r as usize * self.width + c as usize].is_nan()
    }

    /// Bilinear at CRS point `(x, y)` over the four surrounding samples, `None`
    /// outside the sample grid or where any of the four is no-data.
    pub fn bilinear(&self, x: f64, y: f64) -> Option<f64> {
        // A longitude/latitude DEM east of the antimeridian: −179° is its 181°.
        let x = if self.epsg == "EPSG:4326" && x < self.gt[0] {
            x + 360.0
        } else {
            x
        };
        let c = (x - self.gt[0]) / self.gt[1] - 0.5;
        let r = (y - self.gt[3]) / self.gt[5] - 0.5;
        if !(c >= 0.0 && r >= 0.0 && c <= (self.width - 1) as f64 && r <= (self.height - 1) as f64)
        {
            return None;
        }
        let (i, j) = (
            (c.floor() as usize).min(self.width - 2),
            (r.floor() as usize).min(self.height - 2),
        );
        let (u, v) = (c - i as f64, r - j as f64);
        let at = |a: usize, b: usize| self.values[b * self.width + a];
        let (h00, h10, h01, h11) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
        if [h00, h10, h01, h11].iter().any(|h| h.is_nan()) {
            return None;
        }
        let top = h00 + u * (h10 - h00);
        let bottom = h01 + u * (h11 - h01);
        Some(top + v * (bottom - top))
    }
}
