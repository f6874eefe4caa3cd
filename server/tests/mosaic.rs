//! Mosaics (DECISIONS.md "Mosaics") with the real binary on real data: N46E008.tif
//! (1201², int16, EPSG:4326, PixelIsPoint, real voids) cut by GDAL into 16 GeoTIFFs of
//! 301² that share their border rows and columns, as SRTM tiles do. Built as 16 files, a
//! directory, a glob, a list and a `gdalbuildvrt` VRT, the pyramid must equal the
//! single-file build sample for sample; inputs that do not fit together must fail with
//! one line naming both files and leave no output.
//!
//! Needs GDAL's command-line tools (`gdal_translate`, `gdalbuildvrt`; Debian's
//! `gdal-bin`, which `./run test` installs): without them these tests print `SKIPPED`,
//! or fail when `CI` is set.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

mod gdal;
mod raster_support;

use gdal::gdal_or_skip;
use raster_support::finest_samples;

use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use tessera_shared::{Pyramid, TileId, testdata};
use tiff::tags::Tag;

/// Pieces per side, and their step in samples: piece `(r, c)` is samples
/// `[300c, 300c + 300] × [300r, 300r + 300]` of the 1201² whole.
const PIECES: u32 = 4;
const STEP: u32 = 300;
const SIDE: u32 = STEP + 1;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tessera-server"))
}

fn run(cmd: &mut Command) {
    let o = cmd.output().unwrap();
    assert!(
        o.status.success(),
        "{cmd:?} failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

fn gdal_translate(args: &[&str], src: &Path, dst: &Path) {
    run(Command::new("gdal_translate")
        .arg("-q")
        .args(args)
        .arg(src)
        .arg(dst));
}

/// N46E008.tif and its 16 pieces, cut by `gdal_translate -srcwin` into a fresh folder.
struct Cut {
    dir: tempfile::TempDir,
    whole: PathBuf,
    /// `dir/tiles/N46E008_r{r}_c{c}.tif`, row by row (also their sorted order).
    pieces: Vec<PathBuf>,
}

impl Cut {
    fn new() -> Option<Self> {
        if !gdal_or_skip() {
            return None;
        }
        let whole = testdata::dem_or_skip("N46E008.tif")?;
        let dir = tempfile::Builder::new()
            .prefix("tessera-mosaic-")
            .tempdir()
            .unwrap();
        let tiles = dir.path().join("tiles");
        std::fs::create_dir(&tiles).unwrap();
        let mut pieces = Vec::new();
        for r in 0..PIECES {
            for c in 0..PIECES {
                let piece = tiles.join(format!("N46E008_r{r}_c{c}.tif"));
                let win = [c * STEP, r * STEP, SIDE, SIDE].map(|v| v.to_string());
                let mut args = vec!["-srcwin"];
                args.extend(win.iter().map(String::as_str));
                gdal_translate(&args, &whole, &piece);
                pieces.push(piece);
            }
        }
        Some(Self { dir, whole, pieces })
    }

    fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    fn tiles(&self) -> PathBuf {
        self.path("tiles")
    }

    fn piece(&self, r: u32, c: u32) -> &Path {
        &self.pieces[(r * PIECES + c) as usize]
    }
}

fn build(inputs: &[&Path], out: &Path, extra: &[&str]) -> Output {
    bin()
        .arg("build")
        .args(inputs)
        .arg("-o")
        .arg(out)
        .args(["--tile-size", "256", "--quiet"])
        .args(extra)
        .output()
        .unwrap()
}

fn build_ok(inputs: &[&Path], out: &Path, extra: &[&str]) {
    let o = build(inputs, out, extra);
    assert!(
        o.status.success(),
        "build {inputs:?} failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The failure contract: exit 1, one line naming `names`, and no output or partial file.
fn assert_clean_failure(o: &Output, names: &[&str], problem: &str, out: &Path) -> String {
    let stderr = String::from_utf8_lossy(&o.stderr).trim().to_string();
    assert_eq!(o.status.code(), Some(1), "want exit 1; stderr: {stderr}");
    let lines: Vec<&str> = stderr.lines().collect();
    assert_eq!(lines.len(), 1, "want exactly one line, got: {stderr}");
    let line = lines[0];
    assert!(line.starts_with("error: "), "{line}");
    for n in names {
        assert!(line.contains(n), "error does not name {n}: {line}");
    }
    assert!(
        line.contains(problem),
        "error does not say {problem:?}: {line}"
    );
    assert!(!out.exists(), "{} exists after a failure", out.display());
    let dir = out.parent().unwrap();
    let partial = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .any(|e| e.file_name().to_string_lossy().contains(".partial-"));
    assert!(!partial, "a partial file was left in {}", dir.display());
    line.to_string()
}

fn name(p: &Path) -> String {
    p.file_name().unwrap().to_string_lossy().into_owned()
}

/// Asserts that two pyramids hold the same tiles: every level's index entries (min,
/// max, full-resolution error, flags, checksum) and every record's bytes (so every
/// decoded height and error table), and the same metadata but for `source` and
/// `sources`, which name the inputs (a mosaic says "mosaic of 16 …" and lists the 16),
/// and `content_hash`, which hashes the metadata too and so differs only because they
/// do.
fn assert_same_pyramid(want: &Path, got: &Path) {
    let a = Pyramid::open_file(want).unwrap();
    let b = Pyramid::open_file(got).unwrap();
    let strip = |m: &tessera_shared::Metadata| {
        let mut m = m.clone();
        m.source.clear();
        m.sources.clear();
        m.content_hash.clear();
        m
    };
    assert_eq!(
        strip(a.metadata()),
        strip(b.metadata()),
        "{} vs {}",
        want.display(),
        got.display()
    );
    let mut tiles = 0;
    for level in a.geometry().levels() {
        let (ia, ib) = (a.index(level).unwrap(), b.index(level).unwrap());
        assert_eq!(ia.len(), ib.len());
        for (m, (ea, eb)) in ia.iter().zip(ib).enumerate() {
            let tile =
                TileId::from_morton(level, tessera_shared::Morton::from_raw(m as u64)).unwrap();
            assert_eq!(ea.is_present(), eb.is_present(), "{tile}");
            if !ea.is_present() {
                continue;
            }
            assert_eq!(
                (ea.min, ea.max, ea.full_res_error, ea.flags, ea.checksum),
                (eb.min, eb.max, eb.full_res_error, eb.flags, eb.checksum),
                "{tile} of {}",
                got.display()
            );
            assert_eq!(
                a.read_record(tile).unwrap(),
                b.read_record(tile).unwrap(),
                "{tile}"
            );
            tiles += 1;
        }
    }
    assert!(tiles > 20, "only {tiles} tiles compared");
}

/// The height in metres of finest-grid sample `(x, y)` of a pyramid.
fn height_at(p: &Path, x: u32, y: u32) -> f64 {
    let pyr = Pyramid::open_file(p).unwrap();
    let g = pyr.geometry();
    let t = g.tile_size();
    let tile = TileId::new(g.finest(), x / t, y / t).unwrap();
    let rec = pyr.read_tile(tile).unwrap().unwrap();
    let q = rec.heights[((y % t) * (t + 1) + x % t) as usize];
    let quant = pyr.metadata().quantization;
    quant.offset + quant.scale * f64::from(q)
}

/// Where each int16 sample of an uncompressed, striped, little-endian GeoTIFF (what
/// `gdal_translate` writes by default) lies in the file, for reading and patching
/// samples without rewriting the georeferencing.
fn sample_offsets(bytes: &[u8]) -> (u32, u32, impl Fn(u32, u32) -> usize + use<>) {
    assert_eq!(&bytes[..2], b"II", "little-endian TIFF expected");
    let mut dec = tiff::decoder::Decoder::new(Cursor::new(bytes)).unwrap();
    let (w, h) = dec.dimensions().unwrap();
    assert_eq!(dec.get_tag_u32(Tag::Compression).unwrap(), 1);
    assert_eq!(dec.get_tag_u32(Tag::BitsPerSample).unwrap(), 16);
    let strips = dec.get_tag_u64_vec(Tag::StripOffsets).unwrap();
    let rows = dec.get_tag_u32(Tag::RowsPerStrip).unwrap_or(h);
    let at = move |x: u32, y: u32| {
        strips[(y / rows) as usize] as usize + (((y % rows) * w + x) * 2) as usize
    };
    (w, h, at)
}

fn sample(path: &Path, x: u32, y: u32) -> i16 {
    let bytes = std::fs::read(path).unwrap();
    let (_, _, at) = sample_offsets(&bytes);
    let i = at(x, y);
    i16::from_le_bytes([bytes[i], bytes[i + 1]])
}

/// Rewrites every sample of `path` through `f(x, y, value)`.
fn patch(path: &Path, f: impl Fn(u32, u32, i16) -> i16) {
    let mut bytes = std::fs::read(path).unwrap();
    let (w, h, at) = sample_offsets(&bytes);
    for y in 0..h {
        for x in 0..w {
            let i = at(x, y);
            let v = f(x, y, i16::from_le_bytes([bytes[i], bytes[i + 1]]));
            bytes[i..i + 2].copy_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn sixteen_pieces_as_files_a_directory_a_glob_and_a_list_build_the_whole_files_pyramid() {
    let Some(cut) = Cut::new() else { return };
    let reference = cut.path("whole.tess");
    build_ok(&[&cut.whole], &reference, &[]);

    let files = cut.path("files.tess");
    let pieces: Vec<&Path> = cut.pieces.iter().map(PathBuf::as_path).collect();
    build_ok(&pieces, &files, &[]);
    assert_same_pyramid(&reference, &files);
    let m = Pyramid::open_file(&files).unwrap().metadata().clone();
    assert_eq!(
        m.source,
        "mosaic of 16 GeoTIFF int16 inputs (N46E008_r0_c0.tif and 15 more)"
    );
    let o = bin().arg("verify").arg(&files).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stdout));

    // The same 16 in another order only moves the argument order, not the samples.
    let reversed = cut.path("reversed.tess");
    let back: Vec<&Path> = pieces.iter().rev().copied().collect();
    build_ok(&back, &reversed, &[]);
    assert_same_pyramid(&reference, &reversed);

    let dir = cut.path("dir.tess");
    let mut tiles_dir = cut.tiles().into_os_string();
    tiles_dir.push("/");
    std::fs::write(cut.tiles().join("README.txt"), "not a DEM").unwrap();
    build_ok(&[Path::new(&tiles_dir)], &dir, &[]);
    assert_same_pyramid(&reference, &dir);

    // A quoted pattern: the binary expands it, not a shell.
    let glob = cut.path("glob.tess");
    build_ok(&[&cut.tiles().join("N46E008_r?_c*.tif")], &glob, &[]);
    assert_same_pyramid(&reference, &glob);

    // A list beside the output, naming the pieces relative to itself.
    let list = cut.path("inputs.txt");
    let lines: Vec<String> = cut
        .pieces
        .iter()
        .map(|p| format!("tiles/{}", name(p)))
        .collect();
    std::fs::write(&list, format!("# the 16 pieces\n{}\n", lines.join("\n"))).unwrap();
    let listed = cut.path("list.tess");
    let o = bin()
        .arg("build")
        .arg("--inputs")
        .arg(&list)
        .arg("-o")
        .arg(&listed)
        .args(["--tile-size", "256", "--quiet"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_same_pyramid(&reference, &listed);
}

#[test]
fn a_gdalbuildvrt_vrt_of_the_pieces_builds_the_whole_files_pyramid() {
    let Some(cut) = Cut::new() else { return };
    let reference = cut.path("whole.tess");
    build_ok(&[&cut.whole], &reference, &[]);
    let vrt = cut.path("pieces.vrt");
    run(Command::new("gdalbuildvrt")
        .arg("-q")
        .arg(&vrt)
        .args(&cut.pieces));
    let out = cut.path("vrt.tess");
    build_ok(&[&vrt], &out, &[]);
    assert_same_pyramid(&reference, &out);
    let m = Pyramid::open_file(&out).unwrap().metadata().clone();
    assert_eq!(
        m.source,
        "VRT mosaic of 16 GeoTIFF int16 inputs (pieces.vrt: N46E008_r0_c0.tif and 15 more)"
    );
}

#[test]
fn one_input_named_through_a_directory_builds_the_same_file_byte_for_byte() {
    let Some(whole) = testdata::dem_or_skip("N46E008.tif") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let only = dir.path().join("only");
    std::fs::create_dir(&only).unwrap();
    std::fs::copy(&whole, only.join("N46E008.tif")).unwrap();
    let (a, b) = (dir.path().join("a.tess"), dir.path().join("b.tess"));
    build_ok(&[&whole], &a, &[]);
    build_ok(&[&only], &b, &[]);
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
}

#[test]
fn pieces_with_their_own_nodata_values_mix() {
    let Some(cut) = Cut::new() else { return };
    // A piece with voids (-32767) gets another no-data value, in its samples and its tag.
    let (r, c) = (0..PIECES * PIECES)
        .map(|i| (i / PIECES, i % PIECES))
        .find(|&(r, c)| {
            let p = cut.piece(r, c);
            (0..SIDE).any(|y| (0..SIDE).any(|x| sample(p, x, y) == -32767))
        })
        .expect("N46E008 has voids");
    let piece = cut.piece(r, c).to_path_buf();
    let staged = cut.path("staged.tif");
    std::fs::copy(&piece, &staged).unwrap();
    patch(&staged, |_, _, v| if v == -32767 { -9999 } else { v });
    gdal_translate(&["-a_nodata", "-9999"], &staged, &piece);
    let reference = cut.path("whole.tess");
    build_ok(&[&cut.whole], &reference, &[]);
    let out = cut.path("mixed.tess");
    build_ok(&[&cut.tiles()], &out, &[]);
    assert_same_pyramid(&reference, &out);
}

/// The finest samples of `out` over the window of `w × h` samples at `(x0, y0)`.
fn window(out: &Path, x0: u32, y0: u32, w: u32, h: u32) -> Vec<f32> {
    let p = Pyramid::open_file(out).unwrap();
    let all = finest_samples(&p);
    let width = p.metadata().width;
    (y0..y0 + h)
        .flat_map(|y| (x0..x0 + w).map(move |x| (x, y)))
        .map(|(x, y)| all[(y * width + x) as usize])
        .collect()
}

/// A piece labelled ETRS89 (EPSG:4258) beside one in WGS 84: another CRS, so it is
/// resampled onto the first's grid. PROJ's ETRS89 → WGS 84 is the null
/// transformation, so every sample lands on itself and the mosaic equals the one of
/// the two original pieces.
#[test]
fn a_piece_in_another_crs_is_resampled_onto_the_first_grid() {
    let Some(cut) = Cut::new() else { return };
    let other = cut.path("etrs89.tif");
    gdal_translate(&["-a_srs", "EPSG:4258"], cut.piece(0, 1), &other);
    let (mixed, same) = (cut.path("mixed.tess"), cut.path("same.tess"));
    build_ok(&[cut.piece(0, 0), &other], &mixed, &[]);
    build_ok(&[cut.piece(0, 0), cut.piece(0, 1)], &same, &[]);
    let (a, b) = (
        window(&mixed, 0, 0, 601, 301),
        window(&same, 0, 0, 601, 301),
    );
    let q = Pyramid::open_file(&mixed)
        .unwrap()
        .metadata()
        .quantization
        .max_error
        + Pyramid::open_file(&same)
            .unwrap()
            .metadata()
            .quantization
            .max_error;
    let worst = a
        .iter()
        .zip(&b)
        .filter(|(x, y)| !x.is_nan() && !y.is_nan())
        .map(|(x, y)| (x - y).abs())
        .fold(0f32, f32::max);
    assert!(
        f64::from(worst) <= q + 1e-3,
        "{worst} m apart (quantization {q})"
    );
}

/// A coarser piece (0.001°) beside a 3″ one: the mosaic is on the 3″ grid, the fine
/// piece copied sample for sample (it wins where they overlap), the coarse one
/// resampled.
#[test]
fn a_coarser_piece_is_resampled_and_the_finer_wins() {
    let Some(cut) = Cut::new() else { return };
    let coarse = cut.path("coarse.tif");
    gdal_translate(&["-tr", "0.001", "0.001"], cut.piece(0, 1), &coarse);
    let out = cut.path("out.tess");
    build_ok(&[&coarse, cut.piece(0, 0)], &out, &[]);
    let p = Pyramid::open_file(&out).unwrap();
    let gt = p.metadata().georef.as_ref().unwrap().geotransform;
    assert!((gt[1] - 1.0 / 1200.0).abs() < 1e-15, "{gt:?}");
    let alone = cut.path("alone.tess");
    build_ok(&[cut.piece(0, 0)], &alone, &[]);
    // Piece (0, 0) is the mosaic's west part, its column 300 shared with the coarse.
    let x0 = ((7.999_583_333_333_334 - gt[0]) * 1200.0).round() as u32;
    let y0 = ((gt[3] - 47.000_416_666_666_666) * 1200.0).round() as u32;
    let (a, b) = (
        window(&out, x0, y0, SIDE, SIDE),
        window(&alone, 0, 0, SIDE, SIDE),
    );
    let q = p.metadata().quantization.max_error
        + Pyramid::open_file(&alone)
            .unwrap()
            .metadata()
            .quantization
            .max_error;
    // Where the fine piece has data it is copied; in its voids the coarse one may show.
    for (i, (x, y)) in a.iter().zip(&b).enumerate() {
        assert!(
            y.is_nan() || f64::from((x - y).abs()) <= q + 1e-4,
            "sample {i}: {x} vs {y}"
        );
    }
}

/// A piece whose origin is half a cell off the first's lattice is resampled onto it:
/// a sample between two of its samples is their mean (bilinear).
#[test]
fn a_piece_off_the_lattice_is_resampled_onto_it() {
    let Some(cut) = Cut::new() else { return };
    // Piece (0, 1) moved east by half a cell.
    let cell = 1.0 / 1200.0;
    let west = 8.0 - cell / 2.0 + f64::from(STEP) * cell + cell / 2.0;
    let north = 47.0 + cell / 2.0;
    let bounds = [
        west,
        north,
        west + f64::from(SIDE) * cell,
        north - f64::from(SIDE) * cell,
    ]
    .map(|v| format!("{v:.12}"));
    let mut args = vec!["-a_ullr"];
    args.extend(bounds.iter().map(String::as_str));
    let shifted = cut.path("shifted.tif");
    gdal_translate(&args, cut.piece(0, 1), &shifted);
    let out = cut.path("out.tess");
    build_ok(&[cut.piece(0, 0), &shifted], &out, &["--overlap", "first"]);
    let p = Pyramid::open_file(&out).unwrap();
    let q = p.metadata().quantization.max_error;
    let (_, _, src) = raster_support::read_raster(&shifted);
    // Mosaic column 300 + c + 1 lies between the shifted piece's columns c and c + 1.
    let (row, c) = (100u32, 150u32);
    let a = src[(row * SIDE + c) as usize];
    let b = src[(row * SIDE + c + 1) as usize];
    let got = window(&out, STEP + c + 1, row, 1, 1)[0];
    assert!(!a.is_nan() && !b.is_nan());
    assert!(
        f64::from((got - f32::midpoint(a, b)).abs()) <= q + 1e-3,
        "{got} vs mean of {a} and {b}"
    );
}

/// Inputs on different grids need each CRS identified: an engineering CRS (GDAL's
/// LOCAL_CS) cannot be resampled onto the other's grid.
#[test]
fn an_unidentified_crs_on_another_grid_is_a_one_line_error() {
    let Some(cut) = Cut::new() else { return };
    let local = cut.path("local.tif");
    gdal_translate(
        &["-a_srs", "LOCAL_CS[\"arbitrary\"]", "-tr", "0.001", "0.001"],
        cut.piece(0, 1),
        &local,
    );
    let out = cut.path("out.tess");
    let o = build(&[cut.piece(0, 0), &local], &out, &[]);
    assert_clean_failure(&o, &["local.tif"], "cannot be identified", &out);
}

#[test]
fn disagreeing_overlaps_stop_the_build_unless_overlap_picks_a_file() {
    let Some(cut) = Cut::new() else { return };
    // Column 0 of piece (0, 1) is column 300 of piece (0, 0). Change one valid sample
    // of it, on a row shared by no other piece.
    let row = (1..STEP)
        .find(|&y| sample(&cut.whole, STEP, y) != -32767)
        .unwrap();
    let v = sample(&cut.whole, STEP, row);
    patch(
        cut.piece(0, 1),
        |x, y, s| if (x, y) == (0, row) { v + 7 } else { s },
    );
    let out = cut.path("out.tess");
    let o = build(&[&cut.tiles()], &out, &[]);
    let line = assert_clean_failure(
        &o,
        &[
            &cut.piece(0, 0).display().to_string(),
            &cut.piece(0, 1).display().to_string(),
        ],
        &format!("disagree at sample (col {STEP}, row {row}) (EPSG:4326 "),
        &out,
    );
    // The sample's coordinates (its centre: longitude 8.25, and its latitude) and the
    // value each file holds.
    let coords: Vec<f64> = line
        .split("(EPSG:4326 ")
        .nth(1)
        .and_then(|r| r.split(')').next())
        .unwrap()
        .split(", ")
        .map(|c| c.parse().unwrap())
        .collect();
    let lat = 47.0 - f64::from(row) / 1200.0;
    assert!(
        (coords[0] - 8.25).abs() < 1e-9 && (coords[1] - lat).abs() < 1e-9,
        "{line}: want (8.25, {lat})"
    );
    assert!(line.contains(&format!(": {v} vs {}", v + 7)), "{line}");
    assert!(line.contains("--overlap"), "{line}");

    // Files are in sorted order: (0, 0) first, (0, 1) last.
    build_ok(&[&cut.tiles()], &out, &["--overlap", "first"]);
    assert_eq!(height_at(&out, STEP, row), f64::from(v));
    assert_eq!(
        height_at(&out, STEP + 1, row),
        f64::from(sample(&cut.whole, STEP + 1, row))
    );
    std::fs::remove_file(&out).unwrap();
    build_ok(&[&cut.tiles()], &out, &["--overlap", "last"]);
    assert_eq!(height_at(&out, STEP, row), f64::from(v + 7));
    // The order is the arguments': listed the other way round, first is (0, 1).
    std::fs::remove_file(&out).unwrap();
    build_ok(
        &[cut.piece(0, 1), cut.piece(0, 0)],
        &out,
        &["--overlap", "first"],
    );
    assert_eq!(height_at(&out, STEP, row), f64::from(v + 7));
}

#[test]
fn a_vrt_naming_a_missing_file_is_a_one_line_error() {
    let Some(cut) = Cut::new() else { return };
    let vrt = cut.path("pieces.vrt");
    run(Command::new("gdalbuildvrt")
        .arg("-q")
        .arg(&vrt)
        .args(&cut.pieces));
    let gone = cut.piece(2, 3).to_path_buf();
    std::fs::remove_file(&gone).unwrap();
    let out = cut.path("out.tess");
    let o = build(&[&vrt], &out, &[]);
    assert_clean_failure(
        &o,
        &["pieces.vrt", "N46E008_r2_c3.tif"],
        "cannot be read",
        &out,
    );
}
