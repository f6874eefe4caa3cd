//! The mosaic over in-memory rasters served by a test opener.
use super::*;
use std::collections::HashMap;
use std::sync::{Mutex, MutexGuard};

/// In-memory rasters the test opener serves by path.
static RASTERS: Mutex<Option<HashMap<PathBuf, Mem>>> = Mutex::new(None);
/// Tests share `RASTERS`: one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

#[derive(Clone, Debug)]
struct Mem {
    info: SourceInfo,
    values: Vec<f32>,
    next: usize,
}

impl RowSource for Mem {
    fn info(&self) -> &SourceInfo {
        &self.info
    }
    fn read_rows(&mut self, out: &mut [f32]) -> anyhow::Result<()> {
        out.copy_from_slice(&self.values[self.next..self.next + out.len()]);
        self.next += out.len();
        Ok(())
    }
    fn buffer_bytes(&self) -> u64 {
        1000
    }
}

fn mem_open(path: &Path) -> anyhow::Result<(Box<dyn RowSource>, &'static str)> {
    let guard = RASTERS.lock().unwrap();
    let m = guard
        .as_ref()
        .and_then(|r| r.get(path))
        .with_context(|| format!("{}: no such raster", path.display()))?;
    Ok((Box::new(m.clone()), "Mem"))
}

/// Some EPSG:4326 georeferencing (an SRTM tile's header; nothing is read).
fn hgt_georef() -> GeoRef {
    crate::ingest::hgt::Hgt::from_reader("N00E000", 2_884_802, std::io::empty())
        .unwrap()
        .info()
        .georef
        .clone()
        .unwrap()
}

/// A raster at lattice cell `(col, row)` of a 1-unit grid, filled by `f(x, y)`.
fn put(name: &str, col: i32, row: i32, w: u32, h: u32, f: impl Fn(u32, u32) -> f32) -> PathBuf {
    let values = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| f(x, y))
        .collect();
    let georef = GeoRef {
        geotransform: [
            100.0 + f64::from(col),
            1.0,
            0.0,
            200.0 - f64::from(row),
            0.0,
            -1.0,
        ],
        ..hgt_georef()
    };
    let m = Mem {
        info: SourceInfo {
            width: w,
            height: h,
            sample_type: SampleType::Int16,
            nodata: Some(-99.0),
            georef: Some(georef),
            description: String::new(),
        },
        values,
        next: 0,
    };
    let path = PathBuf::from(name);
    RASTERS
        .lock()
        .unwrap()
        .get_or_insert_with(HashMap::new)
        .insert(path.clone(), m);
    path
}

fn serial() -> MutexGuard<'static, ()> {
    let g = SERIAL
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    *RASTERS.lock().unwrap() = None;
    g
}

fn read_all(m: &mut Mosaic) -> anyhow::Result<Vec<f32>> {
    let mut out = vec![0f32; (m.info.width * m.info.height) as usize];
    m.read_rows(&mut out)?;
    Ok(out)
}

#[test]
fn pieces_sharing_borders_read_as_one_raster_with_gaps_missing() {
    let _g = serial();
    // A 5×3 raster of x + 10·y cut into a left 3×3 and a right 3×2 piece sharing
    // column 2; the right piece's missing bottom row is a gap.
    let a = put("a", 0, 0, 3, 3, |x, y| (x + 10 * y) as f32);
    let b = put("b", 2, 0, 3, 2, |x, y| (x + 2 + 10 * y) as f32);
    let mut m = Mosaic::open(&[a, b], None, Overlap::Error, mem_open).unwrap();
    assert_eq!((m.info.width, m.info.height), (5, 3));
    assert_eq!(m.info.georef.as_ref().unwrap().geotransform[0], 100.0);
    let v = read_all(&mut m).unwrap();
    assert_eq!(&v[..10], &[0., 1., 2., 3., 4., 10., 11., 12., 13., 14.]);
    assert_eq!(&v[10..13], &[20., 21., 22.]);
    assert!(v[13].is_nan() && v[14].is_nan());
    assert_eq!(m.open_count(), 0);
    assert_eq!(m.info.description, "mosaic of 2 Mem int16 inputs");
    assert_eq!(m.source_name(), "a and 1 more");
}

#[test]
fn each_inputs_nodata_is_missing_and_does_not_conflict() {
    let _g = serial();
    // `a` says -99 (its no-data) where `b` has 7.
    let a = put("a", 0, 0, 2, 1, |x, _| if x == 1 { -99.0 } else { 1.0 });
    let b = put("b", 1, 0, 2, 1, |_, _| 7.0);
    let mut m = Mosaic::open(&[a.clone(), b.clone()], None, Overlap::Error, mem_open).unwrap();
    assert_eq!(read_all(&mut m).unwrap(), vec![1.0, 7.0, 7.0]);
    // --nodata 7 overrides: b's 7s are missing, a's -99 is a value.
    let mut m = Mosaic::open(&[a, b], Some(7.0), Overlap::Error, mem_open).unwrap();
    let v = read_all(&mut m).unwrap();
    assert_eq!(&v[..2], &[1.0, -99.0]);
    assert!(v[2].is_nan());
}

#[test]
fn disagreeing_overlaps_follow_the_overlap_rule() {
    let _g = serial();
    let a = put("a", 0, 0, 2, 2, |_, _| 1.0);
    let b = put("b", 1, 1, 2, 2, |_, _| 2.0);
    let both = [a, b];
    let mut m = Mosaic::open(&both, None, Overlap::First, mem_open).unwrap();
    assert_eq!(read_all(&mut m).unwrap()[4], 1.0);
    let mut m = Mosaic::open(&both, None, Overlap::Last, mem_open).unwrap();
    assert_eq!(read_all(&mut m).unwrap()[4], 2.0);
    let mut m = Mosaic::open(&both, None, Overlap::Error, mem_open).unwrap();
    let e = read_all(&mut m).unwrap_err().to_string();
    assert!(
        e.contains("a and b disagree at sample (col 1, row 1) (EPSG:4326 101.5, 198.5): 1 vs 2"),
        "{e}"
    );
}

#[test]
fn only_inputs_crossing_the_row_are_open_and_memory_counts_them() {
    let _g = serial();
    // A column of 4 pieces, each 2 rows, sharing a row with the next.
    let paths: Vec<PathBuf> = (0..4)
        .map(|i| put(&format!("p{i}"), 0, i, 2, 2, |_, _| 5.0))
        .collect();
    let mut m = Mosaic::open(&paths, None, Overlap::Error, mem_open).unwrap();
    assert_eq!(m.info.height, 5);
    let per = 1000 + 2 * 4 + OPEN_INPUT_BYTES;
    assert_eq!(
        peak_open_bytes(&m.pieces),
        2 * per,
        "two pieces share each border row"
    );
    assert!(m.buffer_bytes() > 2 * per, "the table of pieces counts too");
    let mut row = [0f32; 2];
    let mut most = 0;
    for _ in 0..5 {
        m.read_rows(&mut row).unwrap();
        most = most.max(m.open_count());
        assert_eq!(row, [5.0, 5.0]);
    }
    assert!(most <= 2, "{most} open at once");
    assert_eq!(m.open_count(), 0);
}

#[test]
fn different_grids_are_refused_naming_both_files() {
    let _g = serial();
    let a = put("a", 0, 0, 2, 2, |_, _| 1.0);
    let b = put("b", 1, 0, 2, 2, |_, _| 1.0);
    // Off the lattice by half a cell.
    {
        let mut r = RASTERS.lock().unwrap();
        let m = r.as_mut().unwrap().get_mut(&b).unwrap();
        m.info.georef.as_mut().unwrap().geotransform[0] += 0.5;
    }
    let e = Mosaic::open(&[a.clone(), b.clone()], None, Overlap::Error, mem_open)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("a and b: origins are not on the same lattice"),
        "{e}"
    );
    {
        let mut r = RASTERS.lock().unwrap();
        let m = r.as_mut().unwrap().get_mut(&b).unwrap();
        let g = m.info.georef.as_mut().unwrap();
        g.geotransform[0] -= 0.5;
        g.geotransform[1] = 2.0;
    }
    let e = Mosaic::open(&[a.clone(), b.clone()], None, Overlap::Error, mem_open)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("a and b: different spacing (1 × 1 vs 2 × 1)"),
        "{e}"
    );
    {
        let mut r = RASTERS.lock().unwrap();
        let m = r.as_mut().unwrap().get_mut(&b).unwrap();
        let g = m.info.georef.as_mut().unwrap();
        g.geotransform[1] = 1.0;
        g.epsg = Some(32632);
    }
    let e = Mosaic::open(&[a, b], None, Overlap::Error, mem_open)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("a and b: different CRS (EPSG:4326 vs EPSG:32632)"),
        "{e}"
    );
}
