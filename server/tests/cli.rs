//! The `tessera-server` binary on bad input: each case must give a one-line error
//! naming the file and the problem, a non-zero exit status, and no output file.
//! Also: `verify` names a corrupted tile, and a killed build leaves no output.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod cli_support;

use cli_support::{assert_clean_failure, bin, build, tmpdir};
use std::path::{Path, PathBuf};
use std::process::Command;
use tessera_shared::testdata;

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
// Build plausibility (DECISIONS.md "Build plausibility"): implausible inputs are refused
// before anything is read
