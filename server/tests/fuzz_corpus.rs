//! Replays the fuzz corpus and every crash the fuzzers found (`fuzz/corpus/TARGET/*`,
//! `fuzz/artifacts/TARGET/*`) through the same entry points the fuzz targets call
//! (`tessera_server::fuzzing::TARGETS`): none may panic, and every seed (a file
//! named `seed-*`, a valid input) must be accepted. So `cargo test` checks the
//! corpus without a fuzzer; `./run fuzz` grows it.
//!
//! The seeds other than the GeoTIFF ones (written by a test in `ingest/geotiff/`)
//! come from [`write_fuzz_seeds`], run by hand:
//! `cargo test -p tessera-server --test fuzz_corpus -- --ignored`.

#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed test

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::process::Command;
use tessera_server::fuzzing::TARGETS;
use tessera_shared::format::checksum;
use tessera_shared::wire;
use tessera_shared::{Level, Morton, MortonRange, Pyramid, TileId};

fn fuzz_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz")
}

/// The files of `fuzz/KIND/TARGET/`, sorted (none when the folder is missing).
fn files(kind: &str, target: &str) -> Vec<PathBuf> {
    let Ok(rd) = std::fs::read_dir(fuzz_dir().join(kind).join(target)) else {
        return Vec::new();
    };
    let mut v: Vec<PathBuf> = rd
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_file())
        .collect();
    v.sort();
    v
}

#[test]
fn corpus_and_artifacts_replay_without_panics() {
    let mut failures = Vec::new();
    let mut replayed = 0;
    for &(target, entry) in TARGETS {
        let seeds = files("corpus", target)
            .into_iter()
            .filter(|p| {
                p.file_name()
                    .unwrap()
                    .to_string_lossy()
                    .starts_with("seed-")
            })
            .count();
        assert!(
            seeds >= 3,
            "fuzz/corpus/{target} has {seeds} seeds, want a few"
        );
        for path in files("corpus", target)
            .into_iter()
            .chain(files("artifacts", target))
        {
            let data = std::fs::read(&path).unwrap();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            replayed += 1;
            match catch_unwind(AssertUnwindSafe(|| entry(&data))) {
                Err(_) => failures.push(format!("{target}/{name}: panicked")),
                Ok(Err(e)) if name.starts_with("seed-") => {
                    failures.push(format!("{target}/{name}: a valid seed was rejected: {e}"));
                }
                Ok(_) => {}
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert!(replayed >= 3 * TARGETS.len());
}

/// Writes the seeds of every target but `geotiff` into `fuzz/corpus/`.
#[test]
#[ignore = "writes files into fuzz/corpus"]
fn write_fuzz_seeds() {
    let put = |target: &str, name: &str, bytes: &[u8]| {
        let dir = fuzz_dir().join("corpus").join(target);
        std::fs::create_dir_all(&dir).unwrap();
        assert!(
            bytes.len() < 50_000,
            "{target}/{name} is {} bytes",
            bytes.len()
        );
        std::fs::write(dir.join(format!("seed-{name}")), bytes).unwrap();
    };

    // Pyramids built by the server itself: one synthetic tile; two levels and a
    // ragged one (absent tiles) from smooth PNG ramps, which compress to a few KB.
    let tmp = std::env::temp_dir().join(format!("tessera-fuzz-seeds-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let mut pyramids = Vec::new();
    for (name, size) in [
        ("one-tile", None),
        ("two-levels", Some((129, 129))),
        ("ragged", Some((129, 40))),
    ] {
        let input = match size {
            None => "synthetic:65:1".to_owned(),
            Some((w, h)) => {
                let path = tmp.join(format!("{name}.png"));
                std::fs::write(&path, png16(w, h, 1 << 20, |x, y| 1000 + 3 * x + 5 * y)).unwrap();
                path.to_string_lossy().into_owned()
            }
        };
        let out = tmp.join(format!("{name}.tess"));
        let o = Command::new(env!("CARGO_BIN_EXE_tessera-server"))
            .args(["build", &input, "--tile-size", "64", "--quiet", "-o"])
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let bytes = std::fs::read(&out).unwrap();
        put("pyramid", name, &bytes);
        pyramids.push(bytes);
    }

    // Tile streams as the range endpoint sends them, from the two-level pyramid.
    let p = Pyramid::open(pyramids[1].clone()).unwrap();
    let level = Level::new(1).unwrap();
    let mut tiles = Vec::new();
    for m in 0..2u64 {
        let tile = TileId::from_morton(level, Morton::from_raw(m)).unwrap();
        let e = *p.entry(tile).unwrap();
        let record = p.read_record(tile).unwrap().unwrap();
        let mut frame =
            wire::tile_header(level, tile.morton(), e.checksum, e.min, e.max, e.length).to_vec();
        frame.extend_from_slice(&record);
        tiles.push((frame, record, e));
    }
    let outside = [MortonRange::new(Morton::from_raw(2), Morton::from_raw(3)).unwrap()];
    let mut s = tiles[0].0.clone();
    s.extend_from_slice(&tiles[1].0);
    s.extend(wire::trailer_frame(level, 2, 0, &outside));
    put("wire", "tiles", &s);
    let (_, record, e) = &tiles[0];
    let table = &record[..tessera_shared::ErrorTable::byte_len(p.geometry().tile_log2())];
    let mut s = wire::error_table_frame(level, Morton::from_raw(0), e.min, e.max, table);
    s.extend(wire::error_frame(
        level,
        Morton::from_raw(1),
        checksum(b"x"),
        "checksum mismatch",
    ));
    s.extend(wire::trailer_frame(level, 0, 1, &[]));
    put("wire", "table-and-error", &s);
    put(
        "wire",
        "empty",
        &wire::trailer_frame(Level::ROOT, 0, 0, &[]),
    );

    // 16-bit grayscale PNGs: a gradient, one row, and one with several IDAT chunks.
    put(
        "png16",
        "gradient",
        &png16(9, 7, 1 << 20, |x, y| x * 2741 + y * 977),
    );
    put(
        "png16",
        "one-row",
        &png16(33, 1, 1 << 20, |x, _| 65535 - x * 3),
    );
    put(
        "png16",
        "split-idat",
        &png16(16, 16, 64, |x, y| (x ^ y) * 4099),
    );

    // SRTM tiles: mode 1 repeats the samples to a whole 1201² tile (see `fuzzing::hgt`).
    let row: Vec<u8> = (0..1201i16)
        .flat_map(|v| (v * 7 - 500).to_be_bytes())
        .collect();
    put(
        "hgt",
        "n44w072-ramp",
        &[b"N44W072\n\x01".as_slice(), &row].concat(),
    );
    put(
        "hgt",
        "s12e130-voids",
        &[b"s12e130\n\x01".as_slice(), &[0x80, 0, 0x12, 0x34]].concat(),
    );
    put("hgt", "default-name", b"\x01\x01\x02\x03\x04\x05\x06");

    // GDAL VRTs: gdalbuildvrt's shape with a simple and a complex source, and a
    // point-sampled single-source one.
    let source = |kind: &str, file: &str, x: u32| {
        format!(
            "<{kind}><SourceFilename relativeToVRT=\"1\">{file}</SourceFilename><SourceBand>1</SourceBand>\
             <SrcRect xOff=\"0\" yOff=\"0\" xSize=\"301\" ySize=\"301\"/>\
             <DstRect xOff=\"{x}\" yOff=\"0\" xSize=\"301\" ySize=\"301\"/></{kind}>"
        )
    };
    let vrt = |w: u32, sources: &str, extra: &str| {
        format!(
            "<VRTDataset rasterXSize=\"{w}\" rasterYSize=\"301\"><SRS dataAxisToSRSAxisMapping=\"2,1\">EPSG:4326</SRS>\
             <GeoTransform>8.0, 0.000833, 0.0, 47.0, 0.0, -0.000833</GeoTransform>{extra}\
             <VRTRasterBand dataType=\"Int16\" band=\"1\"><NoDataValue>-32767</NoDataValue>{sources}</VRTRasterBand></VRTDataset>"
        )
    };
    put(
        "vrt",
        "two-pieces",
        vrt(
            601,
            &(source("SimpleSource", "a.tif", 0) + &source("ComplexSource", "b.tif", 300)),
            "",
        )
        .as_bytes(),
    );
    put(
        "vrt",
        "one-piece",
        vrt(301, &source("SimpleSource", "a.tif", 0), "").as_bytes(),
    );
    put(
        "vrt",
        "point",
        vrt(
            301,
            &source("SimpleSource", "sub/a.tif", 0),
            "<Metadata><MDI key=\"AREA_OR_POINT\">Point</MDI></Metadata>",
        )
        .as_bytes(),
    );

    // Range grammars.
    put("ranges", "single", b"\x030-63");
    put("ranges", "list", b"\x050-3,7,20-30,1000");
    put("ranges", "root", b"\x000");
    put("http_range", "simple", b"\xe8\x03\0\0\0\0\0\0bytes=0-499");
    put(
        "http_range",
        "suffix-and-open",
        b"\xe8\x03\0\0\0\0\0\0bytes=-100, 900-",
    );
    put(
        "http_range",
        "many",
        b"\x00\x00\x01\0\0\0\0\0bytes=0-0,10-20,,-5,\t100-",
    );
    let _ = std::fs::remove_dir_all(&tmp);
}

/// A `w × h` 16-bit grayscale PNG of `f(x, y)`, its IDAT chunks at most `idat` bytes.
fn png16(w: u32, h: u32, idat: usize, f: impl Fn(u32, u32) -> u32) -> Vec<u8> {
    let mut bytes = Vec::new();
    let mut enc = png::Encoder::new(&mut bytes, w, h);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Sixteen);
    let mut writer = enc.write_header().unwrap();
    let samples: Vec<u8> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .flat_map(|(x, y)| (f(x, y) as u16).to_be_bytes())
        .collect();
    let mut stream = writer.stream_writer_with_size(idat).unwrap();
    std::io::Write::write_all(&mut stream, &samples).unwrap();
    stream.finish().unwrap();
    writer.finish().unwrap();
    bytes
}
