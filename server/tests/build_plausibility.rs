//! Build plausibility (DECISIONS.md "Build plausibility"): implausible builds are refused
//! up front — more samples than `--max-samples`, a spool larger than the free disk,
//! inputs that are not regular files (a FIFO named `*.vrt` used to block forever) — each
//! with one line naming the input and the figure, and nothing left behind.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod cli_support;

use cli_support::{assert_clean_failure, bin, build, tmpdir};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use tessera_shared::testdata;

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
    // A part of a distributed build spools in TMPDIR: the same refusal, naming it
    // (one part of one: a part of N spools its 1/N share at least).
    let parts = d.join("parts");
    let o = bin()
        .arg("build")
        .arg(&vrt)
        .args([
            "--part",
            "0/1",
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
