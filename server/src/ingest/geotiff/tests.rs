//! The GeoTIFF reader against real DEMs and hand-written TIFFs.

use super::test_tiff::{Spec, TempFile, surface};
use super::*;
use tessera_shared::{RasterType, testdata};

// ---- helpers -------------------------------------------------------------

/// Reads every row, `chunk` rows at a time (then the remainder).
fn read_all(src: &mut GeoTiff, chunk: u32) -> Vec<f32> {
    let (w, h) = (src.info().width as usize, src.info().height as usize);
    let mut all = vec![0.0; w * h];
    for part in all.chunks_mut(chunk as usize * w) {
        src.read_rows(part).expect("read_rows");
        // Out of core: never more than one strip or row of tiles is held decoded.
        assert!(src.band.len() <= src.layout.band_height() as usize * w);
    }
    all
}

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

fn close(got: f64, want: f64, tol: f64) -> bool {
    (got - want).abs() <= tol * want.abs().max(1.0)
}

fn assert_same(got: &[f64], want: &[f64]) {
    assert!(
        got.len() == want.len() && got.iter().zip(want).all(|(g, w)| close(*g, *w, 1e-12)),
        "{got:?} vs {want:?}"
    );
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

/// Writes the GeoTIFF seeds of the fuzz target (`fuzz/corpus/geotiff/`): tiny
/// files covering each layout, compression, predictor and the georeferencing
/// tags. Run by hand when the writer changes:
/// `cargo test -p tessera-server --lib write_fuzz_seeds -- --ignored`.
#[test]
#[ignore = "writes files into fuzz/corpus"]
fn write_fuzz_seeds() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus/geotiff");
    std::fs::create_dir_all(&dir).expect("corpus dir");
    let (w, h) = (12, 9);
    let seeds: Vec<(&str, Spec)> = vec![
        (
            "seed-int16-strips",
            Spec::new(w, h, SampleType::Int16, surface(w, h, SampleType::Int16)),
        ),
        ("seed-uint16-lzw-pred2-tiled", {
            let mut s = Spec::new(w, h, SampleType::UInt16, surface(w, h, SampleType::UInt16));
            (s.compression, s.predictor, s.tiles) = (5, 2, Some((16, 16)));
            s
        }),
        ("seed-float32-deflate-pred3", {
            let mut s = Spec::new(
                w,
                h,
                SampleType::Float32,
                surface(w, h, SampleType::Float32),
            );
            (s.compression, s.predictor) = (8, 3);
            s
        }),
        ("seed-int16-packbits-tiled-geo", {
            let mut s = Spec::new(w, h, SampleType::Int16, surface(w, h, SampleType::Int16))
                .doubles(33550, &[10.0, 20.0, 0.0])
                .doubles(33922, &[0.0, 0.0, 0.0, 500_000.0, 4_000_000.0, 0.0])
                .shorts(
                    34735,
                    &[1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 2, 3072, 0, 1, 32632],
                )
                .ascii(42113, "-32768");
            (s.compression, s.tiles) = (32773, Some((16, 16)));
            s
        }),
        ("seed-float32-lzw-transform-ascii", {
            let mut s = Spec::new(
                w,
                h,
                SampleType::Float32,
                surface(w, h, SampleType::Float32),
            )
            .doubles(
                34264,
                &[
                    2.0, 0.0, 0.0, 100.0, 0.0, -2.0, 0.0, 50.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                    1.0,
                ],
            )
            .shorts(34735, &[1, 1, 0, 2, 1024, 0, 1, 2, 2049, 34737, 7, 0])
            .ascii(34737, "WGS 84|");
            (s.compression, s.rows_per_strip) = (5, 4);
            s
        }),
    ];
    for (name, spec) in seeds {
        let bytes = spec.encode();
        GeoTiff::from_reader(std::io::Cursor::new(bytes.clone())).expect(name);
        std::fs::write(dir.join(name), bytes).expect("write seed");
    }
}

#[test]
fn every_supported_encoding_reads_back_exactly() {
    let (w, h) = (37, 23);
    let mut cases = 0;
    for sample in [SampleType::Int16, SampleType::UInt16, SampleType::Float32] {
        let values = surface(w, h, sample);
        let want: Vec<f32> = values.iter().map(|&v| v as f32).collect();
        let predictors: &[u16] = if sample == SampleType::Float32 {
            &[1, 2, 3]
        } else {
            &[1, 2]
        };
        for compression in [1, 5, 8, 32946, 32773] {
            for &predictor in predictors {
                for tiles in [None, Some((16, 16)), Some((32, 8))] {
                    let mut spec = Spec::new(w, h, sample, values.clone());
                    spec.compression = compression;
                    spec.predictor = predictor;
                    spec.tiles = tiles;
                    let file = spec.write("enc.tif");
                    let case = format!(
                        "{sample:?} compression {compression} predictor {predictor} tiles {tiles:?}"
                    );
                    let mut src =
                        GeoTiff::open(&file.0).unwrap_or_else(|e| panic!("{case}: {e:#}"));
                    assert_eq!(src.info().sample_type, sample, "{case}");
                    assert_eq!(src.info().georef, None, "{case}");
                    assert_eq!(src.info().nodata, None, "{case}");
                    for chunk in [3, 23] {
                        let got = read_all(&mut GeoTiff::open(&file.0).expect("open"), chunk);
                        assert!(got == want, "{case}, {chunk} rows at a time");
                    }
                    let got = read_all(&mut src, 1);
                    assert!(got == want, "{case}");
                    cases += 1;
                }
            }
        }
    }
    assert_eq!(cases, 3 * 5 * 7);
}

#[test]
fn descriptions_name_the_encoding() {
    let values = surface(20, 10, SampleType::Int16);
    let mut spec = Spec::new(20, 10, SampleType::Int16, values);
    spec.compression = 5;
    spec.predictor = 2;
    spec.tiles = Some((16, 16));
    let d = GeoTiff::open(&spec.write("d1.tif").0)
        .expect("open")
        .info()
        .description
        .clone();
    assert_eq!(d, "GeoTIFF int16, LZW + horizontal predictor, tiled 16×16");
    spec.tiles = None;
    spec.compression = 32946;
    spec.predictor = 1;
    spec.rows_per_strip = 100;
    let d = GeoTiff::open(&spec.write("d2.tif").0)
        .expect("open")
        .info()
        .description
        .clone();
    assert_eq!(d, "GeoTIFF int16, deflate, 10 rows in one strip");
}

#[test]
fn georeferencing_follows_gdal() {
    let values = surface(10, 8, SampleType::Float32);
    let base = || Spec::new(10, 8, SampleType::Float32, values.clone());
    let open = |spec: Spec| {
        let file = spec.write("geo.tif");
        GeoTiff::open(&file.0).expect("open").info().clone()
    };

    // No georeferencing tags at all.
    assert_eq!(open(base()).georef, None);

    // Projected, PixelIsPoint: the corner is half a pixel north-west of the tiepoint.
    let info = open(
        base()
            .doubles(33550, &[10.0, 20.0, 0.0])
            .doubles(33922, &[0.0, 0.0, 0.0, 500_000.0, 4_000_000.0, 0.0])
            .shorts(
                34735,
                &[
                    1, 1, 0, 4, 1024, 0, 1, 1, 1025, 0, 1, 2, 1026, 34737, 22, 0, 3072, 0, 1, 32632,
                ],
            )
            .ascii(34737, "WGS 84 / UTM zone 32N|")
            .ascii(42113, " -9999 "),
    );
    assert_eq!(info.nodata, Some(-9999.0));
    let g = info.georef.expect("georef");
    assert_eq!(g.epsg, Some(32632));
    assert_eq!(g.crs_name.as_deref(), Some("WGS 84 / UTM zone 32N"));
    assert_eq!(g.raster_type, RasterType::PixelIsPoint);
    assert_same(
        &g.geotransform,
        &[499_995.0, 10.0, 0.0, 4_000_010.0, 0.0, -20.0],
    );

    // A tiepoint at pixel (2, 3); geographic model, user-defined projected code ignored.
    let g = open(
        base()
            .doubles(33550, &[0.5, 0.25, 0.0])
            .doubles(33922, &[2.0, 3.0, 0.0, 10.0, 50.0, 0.0])
            .shorts(
                34735,
                &[
                    1, 1, 0, 3, 1024, 0, 1, 2, 2048, 0, 1, 4326, 3072, 0, 1, 32767,
                ],
            ),
    )
    .georef
    .expect("georef");
    assert_eq!(g.epsg, Some(4326));
    assert_eq!(g.raster_type, RasterType::PixelIsArea);
    assert_same(&g.geotransform, &[9.0, 0.5, 0.0, 50.75, 0.0, -0.25]);
    assert_same(&g.extent(10, 8), &[9.0, 48.75, 14.0, 50.75]);

    // User-defined projected CRS: no EPSG code.
    let g = open(
        base()
            .doubles(33550, &[1.0, 1.0, 0.0])
            .doubles(33922, &[0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
            .shorts(34735, &[1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, 32767]),
    )
    .georef
    .expect("georef");
    assert_eq!(g.epsg, None);

    // A north-up ModelTransformationTag.
    let m = [
        2.0, 0.0, 0.0, 100.0, 0.0, -3.0, 0.0, 200.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
    ];
    let g = open(base().doubles(34264, &m)).georef.expect("georef");
    assert_same(&g.geotransform, &[100.0, 2.0, 0.0, 200.0, 0.0, -3.0]);
    assert_eq!(g.epsg, None);

    // A rotated one is ignored (with a warning); the samples are still readable.
    let mut rotated = m;
    rotated[1] = 0.5;
    assert_eq!(open(base().doubles(34264, &rotated)).georef, None);
}

#[test]
fn a_geotiff_is_a_sendable_row_source() {
    fn boxed<T: RowSource + fmt::Debug + 'static>() -> Option<Box<dyn RowSource>> {
        None::<Box<T>>.map(|b| b as Box<dyn RowSource>)
    }
    assert!(boxed::<GeoTiff>().is_none());
}

#[test]
fn gdal_nodata_strings_parse_as_text() {
    assert_eq!(parse_nodata("-32767\0"), Some(-32767.0));
    assert_eq!(parse_nodata("32767"), Some(32767.0));
    assert_eq!(parse_nodata(" -9999 \0\0"), Some(-9999.0));
    assert_eq!(parse_nodata("-3.402823e+38"), Some(-3.402_823e38));
    assert_eq!(
        parse_nodata("-3.4028229999999999e+038"),
        Some(-3.402_823e38)
    );
    assert!(parse_nodata("nan").is_some_and(f64::is_nan));
    assert_eq!(parse_nodata(""), None);
    assert_eq!(parse_nodata("none"), None);
    // As the builder compares: the f32 of the nodata equals the f32 sample.
    assert_eq!(
        parse_nodata("-3.4028229999999999e+038").map(|v| v as f32),
        Some(-3.402_823e38_f32)
    );
}

#[test]
fn unsupported_files_fail_in_open_with_a_clear_message() {
    let open_err = |spec: &Spec| {
        let file = spec.write("bad.tif");
        GeoTiff::open(&file.0)
            .expect_err("must be rejected")
            .to_string()
    };
    let int16 = || Spec::new(8, 4, SampleType::Int16, vec![1.0; 32]);

    let mut s = int16();
    s.compression = 34712;
    let e = open_err(&s);
    assert_eq!(
        e,
        "unsupported TIFF compression JPEG 2000 (34712); supported: none, deflate, LZW, PackBits"
    );

    let mut s = int16();
    s.bits = 8;
    s.format = 1;
    let e = open_err(&s);
    assert_eq!(
        e,
        "unsupported sample type uint8; supported: int16, uint16, float32"
    );

    let mut s = int16();
    s.bits = 64;
    s.format = 3;
    assert!(open_err(&s).contains("unsupported sample type float64"));

    let mut s = Spec::new(8, 4, SampleType::UInt16, vec![1.0; 96]);
    s.bands = 3;
    let e = open_err(&s);
    assert!(e.contains("3 bands") && e.contains("single-band"), "{e}");

    let mut s = int16();
    s.predictor = 3;
    assert!(open_err(&s).contains("floating-point predictor"));
}

/// Chunks whose stored bytes could not hold what the header says they decode to
/// (here: uncompressed strips of 128 bytes said to be stored in 1 byte each) are
/// refused in `open`, before any band is allocated for them.
#[test]
fn a_header_claiming_more_than_its_chunks_can_hold_is_implausible() {
    let mut s = Spec::new(64, 64, SampleType::UInt16, vec![7.0; 64 * 64]);
    s.rows_per_strip = 1;
    let honest = s.write("honest.tif");
    assert!(GeoTiff::open(&honest.0).is_ok());
    s.byte_counts = Some(1);
    let liar = s.write("liar.tif");
    let e = GeoTiff::open(&liar.0)
        .expect_err("must be rejected")
        .to_string();
    assert!(e.contains("implausible TIFF header"), "{e}");
    assert!(e.contains("64 strips"), "{e}");
}

#[test]
fn decoding_errors_are_errors() {
    let (w, h) = (40, 30);
    let values = surface(w, h, SampleType::Int16);
    let mut spec = Spec::new(w, h, SampleType::Int16, values);
    spec.compression = 8;
    spec.tiles = Some((16, 16));
    let mut bytes = spec.encode();
    // Scramble the compressed data of the first tile (it starts at byte 8).
    for b in &mut bytes[10..40] {
        *b = 0xA5;
    }
    let file = TempFile::new("corrupt.tif", &bytes);
    let mut src = GeoTiff::open(&file.0).expect("the header is intact");
    let err = src
        .read_rows(&mut vec![0.0; w as usize])
        .expect_err("corrupt data");
    let msg = format!("{err:#}");
    assert!(msg.contains("tile 0") && msg.contains("deflate"), "{msg}");
    // The source stays failed.
    assert!(src.read_rows(&mut vec![0.0; w as usize]).is_err());

    // Past the end, and buffers that are not whole rows.
    spec.compression = 1;
    let file = spec.write("end.tif");
    let mut src = GeoTiff::open(&file.0).expect("open");
    assert!(src.read_rows(&mut vec![0.0; w as usize + 1]).is_err());
    assert!(
        src.read_rows(&mut vec![0.0; (w * (h + 1)) as usize])
            .is_err()
    );
    read_all(&mut src, 4);
    let err = src
        .read_rows(&mut vec![0.0; w as usize])
        .expect_err("past the end");
    assert!(err.to_string().contains("past the last row"), "{err}");
}

#[test]
fn sparse_tiles_read_as_nodata() {
    let (w, h) = (20, 20);
    let values = surface(w, h, SampleType::Int16);
    let mut spec = Spec::new(w, h, SampleType::Int16, values.clone()).ascii(42113, "-32768");
    spec.tiles = Some((16, 16));
    let mut bytes = spec.encode();
    // Zero the byte count of tile 1 (the top-right one), as GDAL's SPARSE_OK writes it.
    let ifd = u32::from_le_bytes(bytes[4..8].try_into().expect("4")) as usize;
    let n = usize::from(u16::from_le_bytes([bytes[ifd], bytes[ifd + 1]]));
    let entry = (0..n)
        .map(|i| ifd + 2 + 12 * i)
        .find(|&at| u16::from_le_bytes([bytes[at], bytes[at + 1]]) == 325)
        .expect("TileByteCounts");
    let counts = u32::from_le_bytes(bytes[entry + 8..entry + 12].try_into().expect("4")) as usize;
    bytes[counts + 4..counts + 8].copy_from_slice(&0u32.to_le_bytes());
    let file = TempFile::new("sparse.tif", &bytes);
    let got = read_all(&mut GeoTiff::open(&file.0).expect("open"), 6);
    for (i, (&g, &v)) in got.iter().zip(&values).enumerate() {
        let (x, y) = (i as u32 % w, i as u32 / w);
        let want = if x >= 16 && y < 16 {
            -32768.0
        } else {
            v as f32
        };
        assert!(g.to_bits() == want.to_bits(), "({x}, {y}): {g} vs {want}");
    }
}
