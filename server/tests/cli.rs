//! The `tessera-server` binary on bad input: each case must give a one-line error
//! naming the file and the problem, a non-zero exit status, and no output file.
//! Also: `verify` names a corrupted tile, and a killed build leaves no output.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use tessera_shared::testdata;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tessera-server"))
}

/// A fresh directory for one test's files, removed when the test ends.
fn tmpdir(tag: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("tessera-cli-{tag}-"))
        .tempdir()
        .unwrap()
}

fn build(input: &Path, out: &Path, extra: &[&str]) -> Output {
    bin()
        .arg("build")
        .arg(input)
        .arg("-o")
        .arg(out)
        .arg("--quiet")
        .args(extra)
        .output()
        .unwrap()
}

/// Asserts the failure contract and returns the error line.
fn assert_clean_failure(o: &Output, names: &str, problem: &str, out: &Path) -> String {
    let stderr = String::from_utf8_lossy(&o.stderr).trim().to_string();
    assert!(
        !o.status.success(),
        "expected failure, got success; stderr: {stderr}"
    );
    let lines: Vec<&str> = stderr.lines().collect();
    assert_eq!(lines.len(), 1, "want exactly one line, got: {stderr}");
    let line = lines[0];
    assert!(line.starts_with("error: "), "{line}");
    assert!(line.contains(names), "error does not name {names}: {line}");
    assert!(
        line.to_lowercase().contains(&problem.to_lowercase()),
        "error does not say {problem:?}: {line}"
    );
    assert!(
        !out.exists(),
        "output {} exists after a failure",
        out.display()
    );
    if let Some(dir) = out.parent().filter(|d| d.is_dir()) {
        let leftovers: Vec<_> = std::fs::read_dir(dir)
            .map(|rd| rd.flatten().map(|e| e.file_name()).collect())
            .unwrap_or_default();
        assert!(
            leftovers
                .iter()
                .all(|n| !n.to_string_lossy().contains(".partial-")),
            "partial files left behind: {leftovers:?}"
        );
    }
    line.to_string()
}

#[test]
fn empty_file() {
    let tmp = tmpdir("empty");
    let d = tmp.path();
    let input = d.join("empty.tif");
    std::fs::write(&input, b"").unwrap();
    let out = d.join("out.tess");
    assert_clean_failure(&build(&input, &out, &[]), "empty.tif", "empty", &out);
}

#[test]
fn missing_file() {
    let tmp = tmpdir("missing");
    let d = tmp.path();
    let input = d.join("nope.png");
    let out = d.join("out.tess");
    assert_clean_failure(&build(&input, &out, &[]), "nope.png", "no such file", &out);
}

#[test]
fn unknown_format() {
    let tmp = tmpdir("unknown");
    let d = tmp.path();
    let input = d.join("notes.txt");
    std::fs::write(&input, b"just some text, not a raster").unwrap();
    let out = d.join("out.tess");
    assert_clean_failure(
        &build(&input, &out, &[]),
        "notes.txt",
        "unrecognised input format",
        &out,
    );
}

/// An 8-bit RGB image (a smooth colour photo-like gradient) is not a height map.
#[test]
fn eight_bit_rgb_png() {
    let tmp = tmpdir("rgb");
    let d = tmp.path();
    let input = d.join("photo.png");
    {
        let f = std::io::BufWriter::new(std::fs::File::create(&input).unwrap());
        let mut enc = png::Encoder::new(f, 64, 48);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc.write_header().unwrap();
        let data: Vec<u8> = (0..64 * 48)
            .flat_map(|i| [(i % 64 * 4) as u8, (i / 64 * 5) as u8, 128])
            .collect();
        w.write_image_data(&data).unwrap();
    }
    let out = d.join("out.tess");
    assert_clean_failure(
        &build(&input, &out, &[]),
        "photo.png",
        "not a 16-bit grayscale",
        &out,
    );
    // A real 8-bit RGBA image (Terrain-RGB) is refused the same way.
    if let Some(fuji) = testdata::dem_or_skip("fuji.png") {
        assert_clean_failure(
            &build(&fuji, &out, &[]),
            "fuji.png",
            "not a 16-bit grayscale",
            &out,
        );
    }
}

/// Patches the value of a SHORT tag in the first IFD of a little-endian TIFF.
fn patch_tiff_tag(bytes: &mut [u8], tag: u16, value: u16) {
    assert_eq!(&bytes[0..2], b"II", "little-endian TIFF expected");
    let ifd = u32::from_le_bytes(bytes[4..8].try_into().unwrap()) as usize;
    let count = u16::from_le_bytes([bytes[ifd], bytes[ifd + 1]]) as usize;
    for e in 0..count {
        let at = ifd + 2 + 12 * e;
        if u16::from_le_bytes([bytes[at], bytes[at + 1]]) == tag {
            bytes[at + 8..at + 10].copy_from_slice(&value.to_le_bytes());
            return;
        }
    }
    panic!("tag {tag} not found");
}

#[test]
fn tiff_with_unsupported_compression() {
    let Some(src) = testdata::dem_or_skip("luxembourg_elev.tif") else {
        return;
    };
    let tmp = tmpdir("jpeg");
    let d = tmp.path();
    let mut bytes = std::fs::read(src).unwrap();
    patch_tiff_tag(&mut bytes, 259, 7); // Compression = JPEG
    let input = d.join("jpeg.tif");
    std::fs::write(&input, bytes).unwrap();
    let out = d.join("out.tess");
    assert_clean_failure(&build(&input, &out, &[]), "jpeg.tif", "compression", &out);
}

#[test]
fn truncated_tiff() {
    let Some(src) = testdata::dem_or_skip("bigtujunga.tif") else {
        return;
    };
    let tmp = tmpdir("trunc");
    let d = tmp.path();
    let bytes = std::fs::read(src).unwrap();
    let input = d.join("cut.tif");
    std::fs::write(&input, &bytes[..bytes.len() * 6 / 10]).unwrap();
    let out = d.join("out.tess");
    assert_clean_failure(&build(&input, &out, &[]), "cut.tif", "truncated", &out);
}

#[test]
fn truncated_png() {
    let Some(src) = testdata::dem_or_skip("jacksboro_fault_dem.png") else {
        return;
    };
    let tmp = tmpdir("truncpng");
    let d = tmp.path();
    let bytes = std::fs::read(src).unwrap();
    let input = d.join("cut.png");
    std::fs::write(&input, &bytes[..bytes.len() / 2]).unwrap();
    let out = d.join("out.tess");
    assert_clean_failure(&build(&input, &out, &[]), "cut.png", "png", &out);
}

/// A directory the build cannot write into: a read-only directory for ordinary users;
/// root ignores permission bits, so as root use sysfs, which refuses new files.
fn unwritable_dir(d: &Path) -> PathBuf {
    let ro = d.join("readonly");
    std::fs::create_dir_all(&ro).unwrap();
    let mut perms = std::fs::metadata(&ro).unwrap().permissions();
    std::os::unix::fs::PermissionsExt::set_mode(&mut perms, 0o555);
    std::fs::set_permissions(&ro, perms).unwrap();
    if std::fs::write(ro.join("probe"), b"x").is_ok() {
        let _ = std::fs::remove_file(ro.join("probe"));
        return PathBuf::from("/sys");
    }
    ro
}

#[test]
fn unwritable_output_directory() {
    let Some(src) = testdata::dem_or_skip("jacksboro_fault_dem.png") else {
        return;
    };
    let tmp = tmpdir("ro");
    let d = tmp.path();
    let dir = unwritable_dir(d);
    let out = dir.join("out.tess");
    let line = assert_clean_failure(
        &build(&src, &out, &[]),
        &dir.display().to_string(),
        "cannot create",
        &out,
    );
    assert!(line.contains("out.tess"), "{line}");
    // And a directory that does not exist.
    let out = d.join("no/such/dir/out.tess");
    assert_clean_failure(&build(&src, &out, &[]), "out.tess", "does not exist", &out);
}

#[test]
fn bad_flags_are_refused() {
    let tmp = tmpdir("flags");
    let d = tmp.path();
    let out = d.join("out.tess");
    let o = build(Path::new("synthetic:600"), &out, &["--tile-size", "500"]);
    assert_clean_failure(&o, "synthetic:600", "power of two", &out);
    let o = build(Path::new("synthetic:abc"), &out, &[]);
    assert_clean_failure(&o, "synthetic:abc", "size", &out);
    let o = build(Path::new("synthetic:600"), &out, &["--scale", "0"]);
    assert_clean_failure(&o, "--scale", "positive", &out);
}

/// Builds a small pyramid, flips one byte inside one tile record, and expects
/// `verify` to exit 1 naming exactly that tile.
#[test]
fn verify_names_a_corrupted_tile() {
    let tmp = tmpdir("corrupt");
    let d = tmp.path();
    let out = d.join("s.tess");
    let o = build(Path::new("synthetic:700:3"), &out, &["--tile-size", "128"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ok = bin().arg("verify").arg(&out).output().unwrap();
    assert!(ok.status.success());
    let p = tessera_shared::Pyramid::open_file(&out).unwrap();
    let g = *p.geometry();
    let victim = g.present_tiles(g.finest()).nth(5).unwrap();
    let e = *p.entry(victim).unwrap();
    drop(p);
    let mut bytes = std::fs::read(&out).unwrap();
    bytes[(e.offset + u64::from(e.length) / 2) as usize] ^= 0x40;
    std::fs::write(&out, bytes).unwrap();
    let bad = bin().arg("verify").arg(&out).output().unwrap();
    assert_eq!(bad.status.code(), Some(1));
    let stdout = String::from_utf8_lossy(&bad.stdout);
    let lines: Vec<&str> = stdout.lines().filter(|l| l.starts_with("bad ")).collect();
    assert_eq!(lines, [format!("bad {victim}: checksum mismatch")]);
}

/// `kill -9` during a build leaves nothing at the output path.
#[test]
fn killed_build_leaves_no_output() {
    let tmp = tmpdir("kill");
    let d = tmp.path();
    let out = d.join("big.tess");
    // A build far too long to finish before the kill (minutes), killed once its
    // partial file exists: the test never passes by default.
    let mut child = start_long_build(d, &out);
    child.kill().unwrap(); // SIGKILL
    let status = child.wait().unwrap();
    assert_eq!(
        std::os::unix::process::ExitStatusExt::signal(&status),
        Some(9),
        "the build was not killed: {status:?}"
    );
    assert!(!out.exists(), "a killed build left {}", out.display());
    // The next build of the same output removes the dead build's partial file and
    // leaves no partial of its own.
    let o = build(Path::new("synthetic:300"), &out, &["--tile-size", "64"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.exists());
    let partials: Vec<_> = std::fs::read_dir(d)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().contains(".partial-"))
        .map(|e| e.file_name())
        .collect();
    assert!(partials.is_empty(), "partial files remain: {partials:?}");
}

#[test]
fn help_explains_itself() {
    let o = bin().args(["build", "--help"]).output().unwrap();
    let s = String::from_utf8_lossy(&o.stdout);
    for want in [
        "synthetic:SIZE",
        "--tile-size",
        "--memory",
        "--offset",
        "GeoTIFF",
    ] {
        assert!(s.contains(want), "build --help lacks {want}");
    }
}

/// The PNG chunks of `bytes`: `(start of the length field, type, data length)`.
fn png_chunks(bytes: &[u8]) -> Vec<(usize, [u8; 4], usize)> {
    let mut out = Vec::new();
    let mut at = 8;
    while at + 12 <= bytes.len() {
        let len = u32::from_be_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
        out.push((at, bytes[at + 4..at + 8].try_into().unwrap(), len));
        at += 12 + len;
    }
    out
}

/// A real DEM PNG with one flipped bit in its last IDAT chunk; with `fix_crc` the
/// chunk's CRC is recomputed, so only the zlib stream's Adler-32 can tell.
fn damaged_png(d: &Path, name: &str, fix_crc: bool) -> Option<PathBuf> {
    let src = testdata::dem_or_skip("jacksboro_fault_dem.png")?;
    let mut bytes = std::fs::read(src).unwrap();
    let (at, _, len) = *png_chunks(&bytes)
        .iter()
        .rev()
        .find(|c| &c.1 == b"IDAT")
        .unwrap();
    let data = at + 8;
    if fix_crc {
        // The Adler-32 is the zlib stream's last four bytes: flip one of its bits so
        // every decoded sample is still right and only the checksum is wrong.
        bytes[data + len - 1] ^= 0x01;
        let crc = crc32fast::hash(&bytes[at + 4..data + len]);
        bytes[data + len..data + len + 4].copy_from_slice(&crc.to_be_bytes());
    } else {
        bytes[data + len / 2] ^= 0x10;
    }
    let path = d.join(name);
    std::fs::write(&path, bytes).unwrap();
    Some(path)
}

/// One flipped bit inside IDAT used to build with exit 0 and heights of 44 km:
/// the chunk CRC and the zlib Adler-32 must both be checked.
#[test]
fn damaged_png_is_an_error_not_a_pyramid() {
    let tmp = tmpdir("damaged-png");
    let d = tmp.path();
    let out = d.join("out.tess");
    let Some(bad_crc) = damaged_png(d, "flipped.png", false) else {
        return;
    };
    assert_clean_failure(&build(&bad_crc, &out, &[]), "flipped.png", "png", &out);
    let bad_adler = damaged_png(d, "adler.png", true).unwrap();
    let line = assert_clean_failure(&build(&bad_adler, &out, &[]), "adler.png", "corrupt", &out);
    assert!(
        line.to_lowercase().contains("adler") || line.contains("checksum"),
        "{line}"
    );
}

/// Starts a long build and returns it once its partial file exists.
fn start_long_build(d: &Path, out: &Path) -> std::process::Child {
    let mut child = bin()
        .args(["build", "synthetic:65537", "--quiet", "-o"])
        .arg(out)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let started = std::time::Instant::now();
    while !std::fs::read_dir(d)
        .unwrap()
        .flatten()
        .any(|e| e.file_name().to_string_lossy().contains(".partial-"))
    {
        assert!(child.try_wait().unwrap().is_none(), "the build ended early");
        assert!(
            started.elapsed().as_secs() < 120,
            "no partial file appeared"
        );
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    child
}

/// SIGINT or SIGTERM during a build used to leave `.x.tess.partial-*` behind.
/// Now the build removes it and exits with the shell's 128 + signal status.
#[test]
fn interrupted_build_removes_its_partial_file() {
    for (sig, code) in [("TERM", 143), ("INT", 130)] {
        let tmp = tmpdir(&format!("sig{sig}"));
        let d = tmp.path();
        let out = d.join("big.tess");
        let child = start_long_build(d, &out);
        let kill = Command::new("kill")
            .arg(format!("-{sig}"))
            .arg(child.id().to_string())
            .status()
            .unwrap();
        assert!(kill.success());
        let o = child.wait_with_output().unwrap();
        assert_eq!(o.status.code(), Some(code), "SIG{sig}: {o:?}");
        assert_clean_failure(&o, &format!("SIG{sig}"), "interrupted", &out);
    }
}

/// A full disk (here: a file-size limit, which used to kill the build with SIGXFSZ
/// and leave its partial file) is a clear error that leaves nothing.
#[test]
fn full_disk_is_a_clear_error_that_leaves_nothing() {
    let tmp = tmpdir("fsize");
    let d = tmp.path();
    let out = d.join("big.tess");
    let o = Command::new("sh")
        .arg("-c")
        // 4 MiB (in 1 KiB blocks): far below the pyramid of a 4097² terrain.
        .arg("ulimit -f 4096 && exec \"$0\" build synthetic:4097 --quiet -o \"$1\"")
        .arg(env!("CARGO_BIN_EXE_tessera-server"))
        .arg(&out)
        .output()
        .unwrap();
    assert_clean_failure(&o, "big.tess", "too large", &out);
}

/// `preview` used to leave its picture private (mode 0600, the temporary file's).
#[test]
fn preview_writes_an_ordinary_file() {
    let tmp = tmpdir("preview");
    let d = tmp.path();
    let out = d.join("p.tess");
    let o = build(Path::new("synthetic:300"), &out, &["--tile-size", "64"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let png = d.join("relief.png");
    let o = bin()
        .arg("preview")
        .arg(&out)
        .arg("-o")
        .arg(&png)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mode =
        std::os::unix::fs::PermissionsExt::mode(&std::fs::metadata(&png).unwrap().permissions());
    assert_eq!(mode & 0o777, 0o644, "preview wrote mode {:o}", mode & 0o777);
}

// ---------------------------------------------------------------------------
// Issue 32 item 5: implausible inputs are refused before anything is read

/// A VRT of `width × height` samples whose one source is the real SRTM tile: what a
/// typo in `rasterYSize` (or a hostile file) makes of 300 bytes.
fn vrt_over_n46(d: &Path, name: &str, width: u32, height: u32) -> Option<PathBuf> {
    let src = testdata::dem_or_skip("N46E008.tif")?;
    let path = d.join(name);
    std::fs::write(
        &path,
        format!(
            "<VRTDataset rasterXSize=\"{width}\" rasterYSize=\"{height}\">\n  \
             <VRTRasterBand dataType=\"Int16\" band=\"1\">\n    <SimpleSource>\n      \
             <SourceFilename relativeToVRT=\"0\">{}</SourceFilename>\n      \
             <SourceBand>1</SourceBand>\n    </SimpleSource>\n  </VRTRasterBand>\n\
             </VRTDataset>\n",
            src.display()
        ),
    )
    .unwrap();
    Some(path)
}

/// Runs `tessera-server ARGS`; a run still going after a generous bound (a build
/// blocked on a FIFO waits forever) is killed and fails the test.
fn run_bounded(args: &[&std::ffi::OsStr]) -> Output {
    let mut child = bin()
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let started = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if started.elapsed().as_secs() > 60 {
            child.kill().unwrap();
            let o = child.wait_with_output().unwrap();
            panic!(
                "tessera-server {args:?} still ran after 60 s (blocked?); stderr: {}",
                String::from_utf8_lossy(&o.stderr)
            );
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// A 300-byte VRT declaring more samples than the disk can spool used to spool
/// no-data at disk speed until the disk filled: now it is refused before a sample is
/// read, naming the VRT, the raster's size, the spool it needs and the space free.
#[test]
fn a_vrt_declaring_more_than_the_disk_holds_is_refused_before_spooling() {
    let tmp = tmpdir("vrt-disk");
    let d = tmp.path();
    let st = rustix::fs::statvfs(d).unwrap();
    let free = st.f_bavail * st.f_frsize;
    // Twice the free space at 4 bytes a sample, so the refusal cannot depend on
    // what other processes write meanwhile; past u32 rows, the disk is too big to test.
    let Ok(height) = u32::try_from((2 * free).div_ceil(4 * 1201)) else {
        eprintln!("SKIPPED: {free} bytes free is more than a VRT of 1201 columns can exceed");
        return;
    };
    let Some(vrt) = vrt_over_n46(d, "tiles.vrt", 1201, height.max(2)) else {
        return;
    };
    let out = d.join("o.tess");
    let o = build(&vrt, &out, &["--max-samples", &u64::MAX.to_string()]);
    let line = assert_clean_failure(&o, "tiles.vrt", "are free there", &out);
    assert!(
        line.contains(&format!("declares 1201 × {} samples (", height.max(2))),
        "{line}"
    );
    assert!(line.contains("spooling them writes "), "{line}");
    assert!(line.contains(&d.display().to_string()), "{line}");
    // A part of a distributed build spools in TMPDIR: the same refusal, naming it.
    let parts = d.join("parts");
    let o = bin()
        .arg("build")
        .arg(&vrt)
        .args([
            "--part",
            "0/2",
            "--quiet",
            "--max-samples",
            &u64::MAX.to_string(),
            "-o",
        ])
        .arg(&parts)
        .env("TMPDIR", d)
        .output()
        .unwrap();
    let line = assert_clean_failure(&o, "tiles.vrt", "are free there", &parts.join("x"));
    assert!(
        line.contains(&format!("to {} (", d.display())) && line.contains("TMPDIR"),
        "{line}"
    );
}

/// `--max-samples` (default 2^40) refuses a raster larger than any DEM, naming the
/// input and its size; before it, such a VRT failed with "x/o.tess: Invalid argument
/// (os error 22)", naming neither.
#[test]
fn more_samples_than_max_samples_are_refused_naming_the_input() {
    let tmp = tmpdir("vrt-samples");
    let d = tmp.path();
    let Some(vrt) = vrt_over_n46(d, "huge.vrt", 1201, 4_000_000_000) else {
        return;
    };
    let out = d.join("o.tess");
    let line = assert_clean_failure(&build(&vrt, &out, &[]), "huge.vrt", "--max-samples", &out);
    assert!(
        line.contains("declares 1201 × 4000000000 samples (4.8 T samples)")
            && line.contains("1099511627776"),
        "{line}"
    );
    // The limit is the flag's: the real tile passes under a limit it fits, not under
    // one it does not.
    let tif = testdata::dem_or_skip("N46E008.tif").unwrap();
    let line = assert_clean_failure(
        &build(&tif, &out, &["--max-samples", "1000000"]),
        "N46E008.tif",
        "more than --max-samples 1000000",
        &out,
    );
    assert!(
        line.contains("1201 × 1201 samples (1.4 M samples)"),
        "{line}"
    );
    let o = build(&tif, &out, &["--max-samples", "1442401"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

fn mkfifo(path: &Path) {
    let s = Command::new("mkfifo").arg(path).status().unwrap();
    assert!(s.success(), "mkfifo {}", path.display());
}

/// A FIFO named `*.vrt` blocked `build` forever (opening a pipe for reading waits
/// for a writer). Every input kind refuses what is not a regular file before opening
/// it for reading, naming it: as the input, as a VRT's source, as the `--inputs`
/// list or a line of it; a symlink to a real DEM still builds.
#[test]
fn inputs_that_are_not_regular_files_are_refused_without_blocking() {
    let tmp = tmpdir("fifo");
    let d = tmp.path();
    let out = d.join("o.tess");
    let Some(dem) = testdata::dem_or_skip("jacksboro_fault_dem.png") else {
        return;
    };
    for name in ["tiles.vrt", "dem.tif", "N46E008.hgt", "dem.png", "dem"] {
        mkfifo(&d.join(name));
    }
    std::fs::create_dir(d.join("dir.tif")).unwrap();
    let source_fifo = d.join("source.vrt");
    std::fs::write(
        &source_fifo,
        "<VRTDataset rasterXSize=\"10\" rasterYSize=\"10\"><VRTRasterBand band=\"1\">\
         <SimpleSource><SourceFilename relativeToVRT=\"1\">dem.tif</SourceFilename>\
         </SimpleSource></VRTRasterBand></VRTDataset>",
    )
    .unwrap();
    let source_dir = d.join("dirsource.vrt");
    std::fs::write(
        &source_dir,
        std::fs::read_to_string(&source_fifo)
            .unwrap()
            .replace("dem.tif", "dir.tif"),
    )
    .unwrap();
    mkfifo(&d.join("list.txt"));
    std::fs::write(
        d.join("names-fifo.txt"),
        format!("{}\ndem.png\n", dem.display()),
    )
    .unwrap();
    let os = |p: &Path| p.as_os_str().to_owned();
    let cases: Vec<(Vec<std::ffi::OsString>, &str, &str)> = vec![
        (vec![os(&d.join("tiles.vrt"))], "tiles.vrt", "a FIFO"),
        (vec![os(&d.join("dem.tif"))], "dem.tif", "a FIFO"),
        (vec![os(&d.join("N46E008.hgt"))], "N46E008.hgt", "a FIFO"),
        (vec![os(&d.join("dem.png"))], "dem.png", "a FIFO"),
        // No extension: the VRT sniffing must not open it either.
        (vec![os(&d.join("dem"))], "dem", "a FIFO"),
        (vec![os(&source_fifo)], "source.vrt: names", "a FIFO"),
        (vec![os(&source_dir)], "dirsource.vrt: names", "a directory"),
        (vec![os(&dem), os(&d.join("dem.png"))], "dem.png", "a FIFO"),
        (
            vec!["--inputs".into(), os(&d.join("list.txt"))],
            "list.txt",
            "a FIFO",
        ),
        (
            vec!["--inputs".into(), os(&d.join("names-fifo.txt"))],
            "dem.png",
            "a FIFO",
        ),
        (vec!["/dev/zero".into()], "/dev/zero", "a character device"),
    ];
    for (inputs, names, kind) in cases {
        let mut args: Vec<std::ffi::OsString> = vec!["build".into()];
        args.extend(inputs.iter().cloned());
        args.extend(["--quiet".into(), "-o".into(), os(&out)]);
        let args: Vec<&std::ffi::OsStr> = args.iter().map(std::ffi::OsString::as_os_str).collect();
        let line = assert_clean_failure(&run_bounded(&args), names, kind, &out);
        assert!(line.contains("not a regular file"), "{inputs:?}: {line}");
    }
    // A symlink to a regular file is a regular input.
    let link = d.join("link.png");
    std::os::unix::fs::symlink(&dem, &link).unwrap();
    let o = build(&link, &out, &["--tile-size", "64"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}
