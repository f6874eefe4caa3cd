//! `--memory` bounds every allocation of a build
//! (docs/ARCHITECTURE.md#bad-input-is-an-error), measured by counting every byte this
//! test process allocates while a build runs.
//!
//! Each test holds `SERIAL` so only one build is counted at a time.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use tessera_server::builder::{BuildOptions, build, build_inputs};
use tessera_server::ingest::InputSpec;

/// The system allocator, counting live bytes and their peak.
struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
static SERIAL: Mutex<()> = Mutex::new(());

// SAFETY: every call is forwarded unchanged to the system allocator; the counters
// are plain atomics and never allocate.
#[allow(unsafe_code)]
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let now = LIVE.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
            let now = LIVE.fetch_add(new_size, Ordering::Relaxed) + new_size;
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Runs `f` and returns its result with the peak of bytes allocated during it
/// (above what was live before).
fn peak_during<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let out = f();
    (out, PEAK.load(Ordering::Relaxed) - base)
}

/// Writes a 16-bit grayscale PNG of gentle slopes, row by row.
fn write_png(path: &Path, width: u32, height: u32) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut enc = png::Encoder::new(file, width, height);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Sixteen);
    let mut w = enc.write_header().unwrap();
    let mut stream = w.stream_writer().unwrap();
    let mut row = vec![0u8; width as usize * 2];
    for y in 0..height {
        for (x, px) in row.chunks_exact_mut(2).enumerate() {
            let v = 1000 + (x as u32 / 7 + y * 3) % 2000;
            px.copy_from_slice(&(v as u16).to_be_bytes());
        }
        std::io::Write::write_all(&mut stream, &row).unwrap();
    }
    stream.finish().unwrap();
}

fn leftovers(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| {
            n.contains(".partial-")
                || Path::new(n)
                    .extension()
                    .is_some_and(|e| e.eq_ignore_ascii_case("tess"))
        })
        .collect()
}

/// A DEM far wider than tall fills a small corner of a huge tile grid: 2048 × 1
/// finest tiles of 64 cells in a 2048 × 2048 grid. The old writer kept a dense
/// index of every slot in memory (4.2 M slots, 179 MB); within a 64 MiB budget the
/// whole build, index included, must now stay inside the budget.
#[test]
fn a_sparse_tile_grid_builds_inside_the_memory_budget() {
    let _one = SERIAL
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("wide.png");
    write_png(&input, 131_073, 65);
    let out = dir.path().join("wide.tess");
    let budget = 64u64 << 20;
    let opts = BuildOptions {
        tile_size: 64,
        memory_budget: budget,
        ..BuildOptions::default()
    };
    let (report, peak) = peak_during(|| build(input.to_str().unwrap(), &out, &opts));
    let report = report.unwrap();
    assert_eq!(
        (report.metadata.width, report.metadata.height),
        (131_073, 65)
    );
    assert!(
        peak as u64 <= budget,
        "the build allocated {peak} bytes at its peak, over the {budget}-byte budget"
    );
    // And the result is a whole, correct pyramid.
    let v = tessera_server::verify::verify(&out).unwrap();
    assert!(v.is_ok(), "{:?} {:?}", v.problems, v.bad);
    assert_eq!(v.tiles, report.tiles);
}

/// The distributed build holds no more than a whole one: each part of the sparse
/// grid above and their assembly stay inside 64 MiB, and the assembly is the single
/// build's file.
#[test]
fn parts_and_their_assembly_stay_inside_the_memory_budget() {
    use tessera_server::builder::parts::{PartSpec, assemble, build_part};
    let _one = SERIAL
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("wide.png");
    write_png(&input, 131_073, 65);
    let budget = 64u64 << 20;
    let opts = BuildOptions {
        tile_size: 64,
        memory_budget: budget,
        ..BuildOptions::default()
    };
    let spec = InputSpec::one(input.to_str().unwrap());
    let parts = dir.path().join("parts");
    for k in 0..4 {
        let (report, peak) = peak_during(|| build_part(&spec, &parts, PartSpec { k, n: 4 }, &opts));
        report.unwrap();
        assert!(
            peak as u64 <= budget,
            "part {k} allocated {peak} bytes at its peak, over the {budget}-byte budget"
        );
    }
    let out = dir.path().join("assembled.tess");
    let (report, peak) = peak_during(|| assemble(&parts, &out, &opts));
    report.unwrap();
    assert!(
        peak as u64 <= budget,
        "assembling allocated {peak} bytes at its peak, over the {budget}-byte budget"
    );
    let single = dir.path().join("single.tess");
    build_inputs(&spec, &single, &opts).unwrap();
    assert!(
        std::fs::read(&single).unwrap() == std::fs::read(&out).unwrap(),
        "the assembled pyramid differs from the single build's"
    );
}

/// A PNG whose header claims 120 × 16 777 215 samples in a 14 KB file: the old
/// build allocated 34 GB for the claim and aborted. Nothing may be allocated on the
/// header's word; the error names the file and says the size is implausible.
#[test]
fn a_png_header_that_lies_about_its_size_is_refused_before_allocating() {
    let _one = SERIAL
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let dir = tempfile::tempdir().unwrap();
    let honest = dir.path().join("honest.png");
    write_png(&honest, 120, 4000);
    let mut bytes = std::fs::read(&honest).unwrap();
    // IHDR data starts at byte 16: width, height (big-endian), then its CRC at 29.
    bytes[20..24].copy_from_slice(&16_777_215u32.to_be_bytes());
    let crc = crc32fast::hash(&bytes[12..29]);
    bytes[29..33].copy_from_slice(&crc.to_be_bytes());
    let liar = dir.path().join("liar.png");
    std::fs::write(&liar, &bytes).unwrap();
    let out = dir.path().join("liar.tess");
    let budget = 256u64 << 20;
    let opts = BuildOptions {
        memory_budget: budget,
        ..BuildOptions::default()
    };
    let (result, peak) = peak_during(|| build(liar.to_str().unwrap(), &out, &opts));
    let err = format!("{:#}", result.unwrap_err());
    assert!(err.contains("liar.png"), "{err}");
    assert!(err.contains("implausible"), "{err}");
    assert!(
        peak as u64 <= budget,
        "allocated {peak} bytes on a lying header"
    );
    assert!(
        leftovers(dir.path()).is_empty(),
        "{:?}",
        leftovers(dir.path())
    );
}

/// Writes SRTM tile `N{lat}E010.hgt` (1201², big-endian int16) of a terrain defined
/// on the whole column of tiles, so neighbours agree on their shared border row.
fn write_hgt(dir: &Path, lat: u32, tiles: u32) -> std::path::PathBuf {
    let path = dir.join(format!("N{lat:02}E010.hgt"));
    let mut bytes = Vec::with_capacity(1201 * 1201 * 2);
    for y in 0..1201u32 {
        // Rows run north to south; the northernmost tile's first row is row 0.
        let g = (tiles - 1 - lat) * 1200 + y;
        for x in 0..1201u32 {
            let v = 100 + ((x * 3 + g * 5) % 1000) as i16;
            bytes.extend_from_slice(&v.to_be_bytes());
        }
    }
    std::fs::write(&path, bytes).unwrap();
    path
}

/// A mosaic's inputs are opened only while the rows being read cross them, so its
/// memory does not grow with their number: 8 SRTM tiles in a column (1201 × 9601
/// samples, 23 MB of input), built from their directory within 64 MiB.
#[test]
fn a_mosaic_of_many_tiles_stays_inside_the_budget() {
    let _serial = SERIAL
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let dir = tempfile::tempdir().unwrap();
    let tiles = dir.path().join("tiles");
    std::fs::create_dir(&tiles).unwrap();
    for lat in 0..8 {
        write_hgt(&tiles, lat, 8);
    }
    let out = dir.path().join("column.tess");
    let budget = 64u64 << 20;
    let opts = BuildOptions {
        memory_budget: budget,
        ..BuildOptions::default()
    };
    let inputs = InputSpec {
        args: vec![tiles.to_string_lossy().into_owned()],
        list: None,
    };
    let (report, peak) = peak_during(|| build_inputs(&inputs, &out, &opts));
    let report = report.unwrap();
    assert_eq!(
        (report.metadata.width, report.metadata.height),
        (1201, 9601)
    );
    assert_eq!(report.metadata.nodata_count, 0, "the tiles leave no gap");
    assert_eq!(
        report.metadata.vertical_datum,
        tessera_shared::VerticalDatum::Egm96,
        "SRTM tiles state EGM96, and so does their mosaic"
    );
    assert!(
        report
            .metadata
            .source
            .starts_with("mosaic of 8 SRTM .hgt int16 inputs"),
        "{}",
        report.metadata.source
    );
    assert!(
        peak as u64 <= budget,
        "the mosaic build allocated {peak} bytes at its peak, over the {budget}-byte budget"
    );
}
