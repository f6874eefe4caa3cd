//! The reader against the real DEMs of `../shared/data/dem/` (values from its
//! README), and real files damaged.

use super::*;

/// FNV-1a over the bit patterns of the samples.
fn checksum(samples: &[f32]) -> u64 {
    samples.iter().fold(0xcbf2_9ce4_8422_2325, |h, v| {
        (h ^ u64::from(v.to_bits())).wrapping_mul(0x0100_0000_01b3)
    })
}

/// What a real file's samples look like: (min, max) over valid samples and the
/// number of no-data samples (equal to the no-data value as f32, or NaN).
fn stats(samples: &[f32], nodata: Option<f64>) -> (f64, f64, u64) {
    let nd = nodata.map(|v| v as f32);
    let (mut lo, mut hi, mut missing) = (f32::INFINITY, f32::NEG_INFINITY, 0);
    for &v in samples {
        if v.is_nan() || Some(v) == nd {
            missing += 1;
        } else {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    (f64::from(lo), f64::from(hi), missing)
}

/// What a real-file test expects beyond the shared facts.
struct Expect {
    sample_type: SampleType,
    nodata: f64,
    raster_type: RasterType,
    /// Pixel size (x, |y|) and the corner of pixel (0, 0), from the README.
    pixel: f64,
    corner: (f64, f64),
    description: &'static str,
    tolerance: f64,
}

/// Opens a README DEM, reads it 7 rows at a time and checks it against the facts.
fn check_real(name: &str, e: &Expect) -> Option<Vec<f32>> {
    let path = testdata::dem_or_skip(name)?;
    let f = testdata::facts(name);
    let mut src = GeoTiff::open(&path).expect("open");
    let info = src.info().clone();
    println!(
        "{name}: {} nodata {:?} georef {:?}",
        info.description, info.nodata, info.georef
    );
    assert_eq!((info.width, info.height), (f.width, f.height));
    assert_eq!(info.sample_type, e.sample_type);
    assert!(
        info.description.contains(e.description),
        "{:?} lacks {:?}",
        info.description,
        e.description
    );
    let nodata = info.nodata.expect("GDAL_NODATA");
    assert!(close(nodata, e.nodata, 1e-6), "nodata {nodata}");
    let g = info.georef.expect("georeferenced");
    assert_eq!(g.epsg, f.epsg);
    assert_eq!(g.raster_type, e.raster_type);
    let gt = g.geotransform;
    assert!(
        close(gt[1], e.pixel, 1e-9) && close(-gt[5], e.pixel, 1e-9),
        "{gt:?}"
    );
    assert!(gt[2] == 0.0 && gt[4] == 0.0, "{gt:?}");
    assert!(
        close(gt[0], e.corner.0, 1e-9) && close(gt[3], e.corner.1, 1e-9),
        "{gt:?}"
    );
    if let Some(want) = f.extent {
        for (got, want) in g.extent(f.width, f.height).iter().zip(want) {
            assert!(close(*got, want, 1e-9), "extent {got} vs {want}");
        }
    }

    let samples = read_all(&mut src, 7);
    let (lo, hi, missing) = stats(&samples, info.nodata);
    println!("{name}: min {lo} max {hi} nodata samples {missing}");
    assert!((lo - f.min).abs() <= e.tolerance, "min {lo} vs {}", f.min);
    assert!((hi - f.max).abs() <= e.tolerance, "max {hi} vs {}", f.max);
    assert_eq!(missing, f.nodata_count);
    // Every row has been read: one more is an error.
    let w = f.width as usize;
    assert!(src.read_rows(&mut vec![0.0; w]).is_err());
    Some(samples)
}

// ---- real files ----------------------------------------------------------

#[test]
fn reads_n46e008_pixel_is_point_with_voids() {
    let arc3 = 1.0 / 1200.0;
    check_real(
        "N46E008.tif",
        &Expect {
            sample_type: SampleType::Int16,
            nodata: -32767.0,
            raster_type: RasterType::PixelIsPoint,
            pixel: arc3,
            // The tiepoint (8 E, 47 N) is the first sample's centre.
            corner: (8.0 - arc3 / 2.0, 47.0 + arc3 / 2.0),
            description: "GeoTIFF int16, uncompressed, 1201 rows in strips of 3",
            tolerance: 0.0,
        },
    );
}

#[test]
fn reads_luxembourg_lzw_strips() {
    check_real(
        "luxembourg_elev.tif",
        &Expect {
            sample_type: SampleType::Int16,
            nodata: -32768.0,
            raster_type: RasterType::PixelIsArea,
            pixel: 1.0 / 120.0,
            corner: (5.741_666_666_666_666, 50.191_666_666_666_66),
            description: "GeoTIFF int16, LZW, 90 rows in strips of 43",
            tolerance: 0.0,
        },
    );
}

#[test]
fn reads_aletsch_float32_lv95() {
    let Some(path) = testdata::dem_or_skip("aletsch.tif") else {
        return;
    };
    check_real(
        "aletsch.tif",
        &Expect {
            sample_type: SampleType::Float32,
            nodata: -9999.0,
            raster_type: RasterType::PixelIsArea,
            pixel: 200.0,
            corner: (2_601_100.0, 1_184_500.0),
            description: "GeoTIFF float32, uncompressed, 310 rows in strips of 5",
            // The README rounds this range to 0.1 m (502.0..4216.3).
            tolerance: 0.05,
        },
    );
    let src = GeoTiff::open(&path).expect("open");
    let crs = src.info().georef.as_ref().and_then(|g| g.crs_name.clone());
    assert_eq!(crs.as_deref(), Some("CH1903+ / LV95"));
}

#[test]
fn reads_lidar_float32_tiles() {
    check_real(
        "lidar_dem_1m.tif",
        &Expect {
            sample_type: SampleType::Float32,
            // Written by an ESRI tool as "-3.4028229999999999e+038".
            nodata: -3.402_823e38,
            raster_type: RasterType::PixelIsArea,
            pixel: 1.0,
            corner: (429_252.313_370_022, 5_150_885.424_942_633),
            description: "GeoTIFF float32, uncompressed, tiled 128×128",
            tolerance: 0.01,
        },
    );
}

#[test]
fn reads_bigtujunga_int16_tiles() {
    check_real(
        "bigtujunga.tif",
        &Expect {
            sample_type: SampleType::Int16,
            nodata: 32767.0,
            raster_type: RasterType::PixelIsArea,
            pixel: 30.0,
            corner: (376_313.655_454_263_5, 3_807_917.827_628_375_5),
            description: "GeoTIFF int16, uncompressed, tiled 128×128",
            tolerance: 0.0,
        },
    );
}

#[test]
fn chunk_size_does_not_change_the_samples() {
    for name in ["bigtujunga.tif", "lidar_dem_1m.tif", "N46E008.tif"] {
        let Some(path) = testdata::dem_or_skip(name) else {
            continue;
        };
        let sums: Vec<u64> = [1, 64, 5, 1000]
            .iter()
            .map(|&chunk| checksum(&read_all(&mut GeoTiff::open(&path).expect("open"), chunk)))
            .collect();
        assert!(sums.iter().all(|&s| s == sums[0]), "{name}: {sums:x?}");
    }
}

#[test]
fn jpeg_compression_is_rejected_in_open() {
    let Some(path) = testdata::dem_or_skip("luxembourg_elev.tif") else {
        return;
    };
    let mut bytes = std::fs::read(path).expect("read");
    assert_eq!(
        &bytes[..4],
        b"II*\0",
        "the test patches a little-endian TIFF"
    );
    let u16_at = |b: &[u8], at: usize| u16::from_le_bytes([b[at], b[at + 1]]);
    let ifd = u32::from_le_bytes(bytes[4..8].try_into().expect("4 bytes")) as usize;
    let entry = (0..usize::from(u16_at(&bytes, ifd)))
        .map(|i| ifd + 2 + 12 * i)
        .find(|&at| u16_at(&bytes, at) == 259)
        .expect("a Compression entry");
    assert_eq!(u16_at(&bytes, entry + 2), 3, "Compression is a SHORT");
    bytes[entry + 8..entry + 10].copy_from_slice(&7u16.to_le_bytes());
    let file = TempFile::new("jpeg.tif", &bytes);
    let err = GeoTiff::open(&file.0)
        .expect_err("JPEG must be rejected")
        .to_string();
    assert!(
        err.contains("compression") && err.contains("JPEG (7)"),
        "{err}"
    );
}

#[test]
fn truncated_tiled_file_is_an_error_not_a_panic() {
    let Some(path) = testdata::dem_or_skip("bigtujunga.tif") else {
        return;
    };
    let bytes = std::fs::read(path).expect("read");
    let file = TempFile::new("truncated.tif", &bytes[..bytes.len() * 6 / 10]);
    match GeoTiff::open(&file.0) {
        Err(e) => {
            let e = e.to_string();
            assert!(e.starts_with("truncated TIFF"), "{e}");
        }
        Ok(mut src) => {
            let w = src.info().width as usize;
            let mut buf = vec![0.0; w * 7];
            let failed = (0..src.info().height / 7).any(|_| src.read_rows(&mut buf).is_err());
            assert!(failed, "all rows of a truncated file were read");
        }
    }
}
