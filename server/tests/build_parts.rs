//! The distributed build (DECISIONS.md "Distributed build") with the real binary:
//! `build INPUT --part K/N -o PARTS/` for every K, then
//! `build --assemble PARTS/ -o OUT.tess`, must give the very bytes (and content hash) of
//! a single `build INPUT -o OUT.tess`, for N = 1, 4 and 16, on synthetic terrain and on
//! real DEMs, whatever order or parallelism the parts ran in. A part that died leaves
//! nothing under its name and is rerun alone; a missing, foreign, duplicate, truncated or
//! corrupt part makes assembling fail with a line naming the part file, and no output.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};
use tessera_shared::testdata;

/// Synthetic terrain small enough for a debug build: 16×16 finest tiles, so even 16
/// parts get several split-level subtrees each.
const SYNTH: &[&str] = &["synthetic:1025", "--tile-size", "64"];

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tessera-server"))
}

fn tmpdir(tag: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("tessera-parts-{tag}-"))
        .tempdir()
        .unwrap()
}

fn args(input: &[&str]) -> Vec<OsString> {
    input.iter().map(OsString::from).collect()
}

fn check(o: &Output, what: &str) -> String {
    assert!(
        o.status.success(),
        "{what} failed ({:?}): {}",
        o.status,
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn build_single(input: &[OsString], out: &Path) {
    let o = bin()
        .arg("build")
        .args(input)
        .arg("-o")
        .arg(out)
        .arg("--quiet")
        .output()
        .unwrap();
    check(&o, "single build");
}

fn part_cmd(input: &[OsString], k: u32, n: u32, dir: &Path) -> Command {
    let mut c = bin();
    c.arg("build")
        .args(input)
        .arg("--part")
        .arg(format!("{k}/{n}"))
        .arg("-o")
        .arg(dir)
        .arg("--quiet");
    c
}

fn build_part(input: &[OsString], k: u32, n: u32, dir: &Path) {
    check(
        &part_cmd(input, k, n, dir).output().unwrap(),
        &format!("part {k}/{n}"),
    );
}

fn assemble(dir: &Path, out: &Path) -> Output {
    bin()
        .arg("build")
        .arg("--assemble")
        .arg(dir)
        .arg("-o")
        .arg(out)
        .arg("--quiet")
        .output()
        .unwrap()
}

fn part_path(dir: &Path, k: u32, n: u32) -> PathBuf {
    dir.join(format!("part-{k:04}-of-{n:04}.tesspart"))
}

/// The first `content_hash` anywhere in a JSON document.
fn find(v: &serde_json::Value) -> Option<String> {
    match v {
        serde_json::Value::Object(m) => m
            .get("content_hash")
            .and_then(|h| h.as_str().map(String::from))
            .or_else(|| m.values().find_map(find)),
        serde_json::Value::Array(a) => a.iter().find_map(find),
        _ => None,
    }
}

fn content_hash(file: &Path) -> String {
    let o = bin().arg("info").arg("--json").arg(file).output().unwrap();
    let json: serde_json::Value = serde_json::from_str(&check(&o, "info")).unwrap();
    find(&json).expect("info --json has a content_hash")
}

/// `cmp`: the same bytes, and so the same content hash.
fn assert_same_file(a: &Path, b: &Path) {
    let (x, y) = (std::fs::read(a).unwrap(), std::fs::read(b).unwrap());
    if x != y {
        let at = x.iter().zip(&y).position(|(p, q)| p != q);
        panic!(
            "{} ({} bytes) and {} ({} bytes) differ (first at byte {at:?})",
            a.display(),
            x.len(),
            b.display(),
            y.len()
        );
    }
    assert_eq!(content_hash(a), content_hash(b));
}

/// Builds `n` parts one after another in `order`, assembles them and compares with
/// `single`.
fn parts_equal_single(input: &[OsString], n: u32, order: &[u32], single: &Path, tmp: &Path) {
    let dir = tmp.join(format!("parts{n}"));
    for &k in order {
        build_part(input, k, n, &dir);
    }
    let out = tmp.join(format!("assembled{n}.tess"));
    check(&assemble(&dir, &out), "assemble");
    assert_same_file(single, &out);
}

#[test]
fn synthetic_parts_assemble_to_the_single_build() {
    let tmp = tmpdir("synth");
    let input = args(SYNTH);
    let single = tmp.path().join("single.tess");
    build_single(&input, &single);
    for n in [1, 4, 16] {
        let order: Vec<u32> = (0..n).collect();
        parts_equal_single(&input, n, &order, &single, tmp.path());
    }
}

/// One tile (the split is the root, and most parts are empty) and two levels (the
/// split is the finest level).
#[test]
fn tiny_pyramids_split_too() {
    let tmp = tmpdir("tiny");
    for size in ["synthetic:65", "synthetic:66"] {
        let input = args(&[size, "--tile-size", "64"]);
        let t = tmp.path().join(size.replace(':', "-"));
        std::fs::create_dir(&t).unwrap();
        let single = t.join("single.tess");
        build_single(&input, &single);
        parts_equal_single(&input, 4, &[3, 2, 1, 0], &single, &t);
    }
}

/// A real DEM with radar voids (no-data filled, masks, counts from every part).
#[test]
fn srtm_parts_with_voids_assemble_to_the_single_build() {
    let Some(dem) = testdata::dem_or_skip("N46E008.tif") else {
        return;
    };
    let tmp = tmpdir("srtm");
    let input = vec![dem.into_os_string(), "--tile-size".into(), "64".into()];
    let single = tmp.path().join("single.tess");
    build_single(&input, &single);
    for n in [1, 4, 16] {
        let order: Vec<u32> = (0..n).rev().collect();
        parts_equal_single(&input, n, &order, &single, tmp.path());
    }
}

/// The moon mosaic needs `--offset -10000`; every part must fold it in alike.
#[test]
fn moon_parts_assemble_to_the_single_build() {
    let Some(dem) = testdata::dem_or_skip("moon_crisium_gld100_4096.png") else {
        return;
    };
    let tmp = tmpdir("moon");
    let input = vec![
        dem.into_os_string(),
        "--offset".into(),
        "-10000".into(),
        "--tile-size".into(),
        "256".into(),
    ];
    let single = tmp.path().join("single.tess");
    build_single(&input, &single);
    parts_equal_single(&input, 4, &[2, 0, 3, 1], &single, tmp.path());
}

/// Parts built in a shuffled order, and all at once in parallel processes, are the
/// same part files and assemble to the same pyramid.
#[test]
fn shuffled_and_parallel_parts_give_the_same_bytes() {
    let tmp = tmpdir("order");
    let input = args(SYNTH);
    let n = 16;
    let single = tmp.path().join("single.tess");
    build_single(&input, &single);
    let shuffled = [11, 3, 15, 0, 7, 12, 5, 9, 1, 14, 6, 2, 10, 13, 4, 8];
    parts_equal_single(&input, n, &shuffled, &single, tmp.path());
    let parallel = tmp.path().join("parallel");
    let children: Vec<_> = (0..n)
        .map(|k| part_cmd(&input, k, n, &parallel).spawn().unwrap())
        .collect();
    for (k, c) in children.into_iter().enumerate() {
        check(
            &c.wait_with_output().unwrap(),
            &format!("parallel part {k}"),
        );
    }
    for k in 0..n {
        let a = std::fs::read(part_path(&tmp.path().join("parts16"), k, n)).unwrap();
        let b = std::fs::read(part_path(&parallel, k, n)).unwrap();
        assert!(a == b, "part {k} differs between the runs");
    }
    let out = tmp.path().join("parallel.tess");
    check(&assemble(&parallel, &out), "assemble");
    assert_same_file(&single, &out);
}

/// `--part /N` takes K from JOB_COMPLETION_INDEX (a Kubernetes Indexed Job), and
/// without it says so.
#[test]
fn k_comes_from_the_job_completion_index() {
    let tmp = tmpdir("index");
    let dir = tmp.path().join("parts");
    let o = bin()
        .arg("build")
        .args(SYNTH)
        .args(["--part", "/4", "-o"])
        .arg(&dir)
        .env_remove("JOB_COMPLETION_INDEX")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(stderr.contains("JOB_COMPLETION_INDEX"), "{stderr}");
    assert!(!dir.exists(), "nothing is written without a K");
    let o = bin()
        .arg("build")
        .args(SYNTH)
        .args(["--part", "/4", "-o"])
        .arg(&dir)
        .arg("--quiet")
        .env("JOB_COMPLETION_INDEX", "2")
        .output()
        .unwrap();
    check(&o, "part /4 with JOB_COMPLETION_INDEX=2");
    let names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["part-0002-of-0004.tesspart"]);
    let o = bin()
        .arg("build")
        .args(SYNTH)
        .args(["--part", "4/4", "-o"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(!o.status.success(), "K must be below N");
    // Parts go to a folder, never to an object URL (nor to a local folder named "s3:").
    let o = bin()
        .current_dir(tmp.path())
        .arg("build")
        .args(SYNTH)
        .args(["--part", "0/4", "-o", "s3://bucket/parts"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && stderr.contains("local (or mounted) folder"),
        "{stderr}"
    );
    assert!(!tmp.path().join("s3:").exists());
}

fn partials(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".partial-"))
        .collect()
}

/// A part killed mid-build leaves nothing under its name; assembling then names it
/// as missing; rerunning that part alone (which clears the dead one's partial file)
/// completes the build, byte for byte.
#[test]
fn a_dead_part_is_rerun_alone() {
    let tmp = tmpdir("dead");
    let input = args(&["synthetic:4097", "--tile-size", "64"]);
    let (n, dead) = (4, 1);
    let dir = tmp.path().join("parts");
    let single = tmp.path().join("single.tess");
    build_single(&input, &single);
    for k in (0..n).filter(|&k| k != dead) {
        build_part(&input, k, n, &dir);
    }
    let mut child = part_cmd(&input, dead, n, &dir).spawn().unwrap();
    let t0 = Instant::now();
    while partials(&dir).is_empty() {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "no partial file appeared"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    std::thread::sleep(Duration::from_millis(50));
    let still_running = child.try_wait().unwrap().is_none();
    child.kill().unwrap();
    child.wait().unwrap();
    if still_running {
        assert!(
            !part_path(&dir, dead, n).exists(),
            "a killed part left a file under its final name"
        );
        assert_eq!(
            partials(&dir).len(),
            1,
            "the dead part's partial file stays"
        );
    } else {
        eprintln!("the part finished before it could be killed; removing it instead");
        std::fs::remove_file(part_path(&dir, dead, n)).unwrap();
    }
    let out = tmp.path().join("out.tess");
    let o = assemble(&dir, &out);
    let line = failure_line(&o, &out);
    assert!(
        line.contains(&part_path(&dir, dead, n).display().to_string()) && line.contains("missing"),
        "{line}"
    );
    // The dead part alone, again.
    build_part(&input, dead, n, &dir);
    assert!(
        partials(&dir).is_empty(),
        "the rerun removed the dead part's partial file"
    );
    check(&assemble(&dir, &out), "assemble after the rerun");
    assert_same_file(&single, &out);
}

/// The failure contract of assembling: non-zero exit, one line, no output and no
/// partial file beside it. Returns the line.
fn failure_line(o: &Output, out: &Path) -> String {
    let stderr = String::from_utf8_lossy(&o.stderr).trim().to_string();
    assert!(!o.status.success(), "assembling succeeded; want a failure");
    let lines: Vec<&str> = stderr.lines().collect();
    assert_eq!(lines.len(), 1, "want exactly one line, got: {stderr}");
    assert!(lines[0].starts_with("error: "), "{stderr}");
    assert!(!out.exists(), "{} exists after a failure", out.display());
    assert!(
        partials(out.parent().unwrap()).is_empty(),
        "a partial output was left behind"
    );
    lines[0].to_string()
}

/// Copies the good parts to a fresh folder for one damage case.
fn fresh_copy(good: &Path, tmp: &Path, tag: &str) -> PathBuf {
    let dir = tmp.join(tag);
    std::fs::create_dir(&dir).unwrap();
    for e in std::fs::read_dir(good).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), dir.join(e.file_name())).unwrap();
    }
    dir
}

#[test]
fn bad_parts_are_refused_naming_the_file() {
    let tmp = tmpdir("bad");
    let t = tmp.path();
    let input = args(SYNTH);
    let n = 4;
    let good = t.join("good");
    for k in 0..n {
        build_part(&input, k, n, &good);
    }
    let outdir = t.join("out");
    std::fs::create_dir(&outdir).unwrap();
    let out = outdir.join("out.tess");
    let expect = |dir: &Path, names: &Path, problem: &str| {
        let line = failure_line(&assemble(dir, &out), &out);
        let name = names.display().to_string();
        assert!(line.contains(&name), "does not name {name}: {line}");
        assert!(line.contains(problem), "does not say {problem:?}: {line}");
    };

    // Missing.
    let dir = fresh_copy(&good, t, "missing");
    std::fs::remove_file(part_path(&dir, 2, n)).unwrap();
    expect(&dir, &part_path(&dir, 2, n), "missing");

    // A part of another input (another seed) in place of part 1.
    let other = t.join("other");
    build_part(
        &args(&["synthetic:1025:7", "--tile-size", "64"]),
        1,
        n,
        &other,
    );
    let dir = fresh_copy(&good, t, "foreign");
    std::fs::copy(part_path(&other, 1, n), part_path(&dir, 1, n)).unwrap();
    expect(&dir, &part_path(&dir, 1, n), "another input");

    // Other options (another --tile-size) in place of part 3.
    let other = t.join("other-options");
    build_part(
        &args(&["synthetic:1025", "--tile-size", "128"]),
        3,
        n,
        &other,
    );
    let dir = fresh_copy(&good, t, "options");
    std::fs::copy(part_path(&other, 3, n), part_path(&dir, 3, n)).unwrap();
    expect(&dir, &part_path(&dir, 3, n), "--tile-size");

    // A part of a 2-part build lying among them.
    let other = t.join("other-n");
    build_part(&input, 0, 2, &other);
    let dir = fresh_copy(&good, t, "stray");
    std::fs::copy(part_path(&other, 0, 2), part_path(&dir, 0, 2)).unwrap();
    expect(&dir, &part_path(&dir, 0, 2), "2-part build");

    // A duplicate under another name.
    let dir = fresh_copy(&good, t, "duplicate");
    let copy = dir.join("copy-of-part-1.tesspart");
    std::fs::copy(part_path(&dir, 1, n), &copy).unwrap();
    expect(&dir, &copy, "duplicate part 1");

    // Truncated.
    let dir = fresh_copy(&good, t, "truncated");
    let p = part_path(&dir, 3, n);
    let len = std::fs::metadata(&p).unwrap().len();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&p)
        .unwrap()
        .set_len(len - 1000)
        .unwrap();
    expect(&dir, &p, "truncated");

    // A flipped byte inside a record: found while copying, after the output was
    // begun, which must vanish all the same.
    let dir = fresh_copy(&good, t, "corrupt");
    let p = part_path(&dir, 2, n);
    let mut bytes = std::fs::read(&p).unwrap();
    bytes[64 + 32 + 100] ^= 0x55;
    std::fs::write(&p, &bytes).unwrap();
    expect(&dir, &p, "checksum");

    // A flipped byte in the trailer.
    let dir = fresh_copy(&good, t, "corrupt-trailer");
    let p = part_path(&dir, 0, n);
    let mut bytes = std::fs::read(&p).unwrap();
    let last = bytes.len() - 10;
    bytes[last] ^= 0x01;
    std::fs::write(&p, &bytes).unwrap();
    expect(&dir, &p, "checksum");

    // An empty folder, and one that is not there.
    let empty = t.join("empty");
    std::fs::create_dir(&empty).unwrap();
    expect(&empty, &empty, "no part files");
    expect(&t.join("nowhere"), &t.join("nowhere"), "not a folder");

    // And the good parts still assemble.
    check(&assemble(&good, &out), "assemble the good parts");
}

/// `--assemble` takes its options from the parts: flags that shape a pyramid, or an
/// INPUT, are refused by the command line.
#[test]
fn assemble_refuses_build_options() {
    let tmp = tmpdir("flags");
    for extra in [&["--tile-size", "128"][..], &["synthetic:65"][..]] {
        let o = bin()
            .arg("build")
            .arg("--assemble")
            .arg(tmp.path())
            .arg("-o")
            .arg(tmp.path().join("x.tess"))
            .args(extra)
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{extra:?} is a usage error");
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(stderr.contains("cannot be used with"), "{stderr}");
    }
}
