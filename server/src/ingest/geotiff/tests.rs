//! The GeoTIFF reader against real DEMs and hand-written TIFFs.

mod real_files;

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

fn close(got: f64, want: f64, tol: f64) -> bool {
    (got - want).abs() <= tol * want.abs().max(1.0)
}

fn assert_same(got: &[f64], want: &[f64]) {
    assert!(
        got.len() == want.len() && got.iter().zip(want).all(|(g, w)| close(*g, *w, 1e-12)),
        "{got:?} vs {want:?}"
    );
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
