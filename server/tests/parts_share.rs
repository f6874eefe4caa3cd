//! Each part of a distributed build reads only its share of the input (DECISIONS.md
//! "Distributed build"), with the real binary on real data cut by GDAL: a mosaic of
//! Cloud-Optimized GeoTIFF pieces is read about once across all parts, a part whose
//! share holds no-data (a gap in the collection) reads the whole input and says so,
//! floating-point samples read their share with `--height-range`; and whatever each part
//! read, the assembled pyramid is byte for byte the single build's.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses its own subset
mod cli_support;
mod gdal;

use cli_support::{assert_same_bytes, build_args as build, text};
use gdal::pieces::cog_pieces;

use std::path::Path;
use std::process::Command;
use tessera_shared::testdata;

/// How a part's stdout says it read: `Some((samples, of))` for its share, `None` for the
/// whole input (the line must say why).
fn share_read(stdout: &str) -> Option<(u64, u64)> {
    if let Some(line) = stdout
        .lines()
        .find(|l| l.starts_with("read the whole input: "))
    {
        assert!(
            line.len() > "read the whole input: ".len() + 10,
            "no reason: {line}"
        );
        return None;
    }
    let line = stdout
        .lines()
        .find_map(|l| l.strip_prefix("read its share of the input: "))
        .unwrap_or_else(|| panic!("no line on what the part read: {stdout}"));
    let words: Vec<&str> = line.split_whitespace().collect();
    Some((words[0].parse().unwrap(), words[2].parse().unwrap()))
}

/// Builds parts `0..n` of `input` (plus `flags`) into `dir` and assembles them into
/// `out`; what each part's stdout says it read.
fn parts(
    input: &[&str],
    flags: &[&str],
    n: u32,
    dir: &Path,
    out: &Path,
) -> Vec<Option<(u64, u64)>> {
    let reads = (0..n)
        .map(|k| {
            let spec = format!("{k}/{n}");
            let args: Vec<&str> = input
                .iter()
                .chain(flags)
                .copied()
                .chain(["--part", &spec, "-o", text(dir)])
                .collect();
            share_read(&build(&args).unwrap())
        })
        .collect();
    build(&["--assemble", text(dir), "-o", text(out)]).unwrap();
    reads
}

#[test]
fn a_cog_mosaic_is_read_about_once_across_its_parts() {
    let tmp = tempfile::tempdir().unwrap();
    let Some(_) = cog_pieces(tmp.path()) else {
        return;
    };
    let folder = format!("{}/", tmp.path().display());
    let flags = ["--tile-size", "64"];
    let single = tmp.path().join("single.tess");
    build(&[&folder, "--tile-size", "64", "-o", text(&single)]).unwrap();
    let out = tmp.path().join("assembled.tess");
    let reads = parts(&[&folder], &flags, 16, &tmp.path().join("parts"), &out);
    let whole = 2048 * 2048;
    let mut total = 0;
    for (k, r) in reads.iter().enumerate() {
        let (samples, of) = r.unwrap_or_else(|| panic!("part {k} read the whole input"));
        assert_eq!(of, whole);
        // A sixteenth, plus its windows' shared edges and a few coarse corners.
        assert!(samples < whole / 16 + whole / 64, "part {k} read {samples}");
        total += samples;
    }
    // Across the parts: the DEM once, plus the edges two windows share.
    assert!(
        total >= whole && total * 100 <= whole * 102,
        "{total} of {whole}"
    );
    assert_same_bytes(&single, &out);
}

#[test]
fn parts_over_a_gap_in_the_collection_read_the_whole_input() {
    let tmp = tempfile::tempdir().unwrap();
    let Some(pieces) = cog_pieces(tmp.path()) else {
        return;
    };
    // Fifteen pieces: the one at row 1, column 2 missing leaves a hole of no-data
    // inside the mosaic, filled from its nearest valid samples across the input.
    let list = tmp.path().join("list.txt");
    let names: Vec<String> = pieces
        .iter()
        .filter(|p| !p.ends_with("p12.tif"))
        .map(|p| p.display().to_string())
        .collect();
    std::fs::write(&list, names.join("\n")).unwrap();
    let input = ["--inputs", text(&list)];
    let single = tmp.path().join("single.tess");
    build(&[
        "--inputs",
        text(&list),
        "--tile-size",
        "64",
        "-o",
        text(&single),
    ])
    .unwrap();
    let out = tmp.path().join("assembled.tess");
    let reads = parts(
        &input,
        &["--tile-size", "64"],
        16,
        &tmp.path().join("parts"),
        &out,
    );
    let whole = reads.iter().filter(|r| r.is_none()).count();
    // The hole is 512² of the 2048² mosaic: the parts whose 512² share meets it,
    // with its one-sample edge or a coarse corner, read everything; the others do not.
    assert!(
        (1..=4).contains(&whole),
        "{whole} of 16 parts read the whole input"
    );
    assert!(reads.iter().filter(|r| r.is_some()).count() >= 12);
    assert_same_bytes(&single, &out);
}

#[test]
fn float_samples_read_their_share_given_a_height_range() {
    let Some(dem) = testdata::dem_or_skip("aletsch.tif") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let dem = text(&dem).to_string();
    // aletsch.tif is float32, heights 502.0 .. 4216.3 m (the data README).
    let flags = ["--tile-size", "64", "--height-range", "500,4500"];
    let single = tmp.path().join("single.tess");
    let args: Vec<&str> = [dem.as_str()]
        .into_iter()
        .chain(flags)
        .chain(["-o", text(&single)])
        .collect();
    build(&args).unwrap();
    let out = tmp.path().join("assembled.tess");
    let reads = parts(&[&dem], &flags, 4, &tmp.path().join("parts"), &out);
    assert!(reads.iter().all(Option::is_some), "{reads:?}");
    assert_same_bytes(&single, &out);

    // Without the range, each part reads the whole input to learn it, and says so.
    let stdout = build(&[
        &dem,
        "--tile-size",
        "64",
        "--part",
        "0/4",
        "-o",
        text(&tmp.path().join("p2")),
    ])
    .unwrap();
    let line = stdout
        .lines()
        .find(|l| l.starts_with("read the whole input"))
        .unwrap();
    assert!(
        line.contains("floating-point") && line.contains("--height-range"),
        "{line}"
    );

    // A range that leaves heights out is refused, naming it, and leaves no part.
    let dir = tmp.path().join("p3");
    for k in 0..4 {
        let spec = format!("{k}/4");
        let e = build(&[
            &dem,
            "--tile-size",
            "64",
            "--height-range",
            "1000,4500",
            "--part",
            &spec,
            "-o",
            text(&dir),
        ])
        .unwrap_err();
        assert!(e.contains("outside --height-range 1000,4500"), "{e}");
        assert!(e.contains("aletsch.tif"), "{e}");
    }
    let left: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
    assert!(left.is_empty(), "{left:?}");
    let e = build(&[
        &dem,
        "--height-range",
        "4500,1000",
        "-o",
        text(&tmp.path().join("x.tess")),
    ])
    .unwrap_err();
    assert!(e.contains("MIN (4500) must be below MAX (1000)"), "{e}");
}

/// `(bytes fetched)` from a build's "read N bytes of inputs from object storage" line.
fn fetched_bytes(stdout: &str) -> u64 {
    let line = stdout
        .lines()
        .find(|l| l.starts_with("read ") && l.contains("bytes of inputs"))
        .unwrap_or_else(|| panic!("no fetched-bytes line in {stdout:?}"));
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

/// The pieces in a real S3 server (moto): 4 parts together fetch well under what 4
/// whole reads would (each part about its quarter, plus the COG tiles its edges and
/// coarse corners reach into), and assemble to the build that read the pieces whole.
#[test]
fn parts_fetch_their_share_from_object_storage() {
    let tmp = tempfile::tempdir().unwrap();
    let Some(pieces) = cog_pieces(tmp.path()) else {
        return;
    };
    let Some(s3) = tessera_shared::s3_server::S3Server::start_or_skip() else {
        return;
    };
    s3.create_bucket("dem");
    for p in &pieces {
        let name = p.file_name().unwrap().to_str().unwrap();
        s3.put("dem", &format!("pieces/{name}"), &std::fs::read(p).unwrap());
    }
    let env = s3.env();
    let run = |args: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_tessera-server"))
            .arg("build")
            .args(args)
            .arg("--quiet")
            .envs(env.iter().map(|(k, v)| (k.as_str(), v.as_str())))
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        String::from_utf8(o.stdout).unwrap()
    };
    let single = tmp.path().join("single.tess");
    let whole = fetched_bytes(&run(&[
        "s3://dem/pieces/",
        "--tile-size",
        "64",
        "-o",
        text(&single),
    ]));
    let dir = tmp.path().join("parts");
    let mut sum = 0;
    for k in 0..4 {
        let spec = format!("{k}/4");
        let stdout = run(&[
            "s3://dem/pieces/",
            "--tile-size",
            "64",
            "--part",
            &spec,
            "-o",
            text(&dir),
        ]);
        assert!(share_read(&stdout).is_some(), "part {k}: {stdout}");
        let b = fetched_bytes(&stdout);
        eprintln!("part {k}/4 fetched {b} bytes");
        sum += b;
    }
    eprintln!(
        "4 parts fetched {sum} bytes against the whole build's {whole} ({:.3}×)",
        sum as f64 / whole as f64
    );
    // A part fetches its quarter of the COG tiles, plus the column and row of tiles
    // its shared edge reaches into (5 × 5 of 8 × 8 tiles: 39 %) and a tile for each
    // coarse corner beyond it; four whole reads would fetch 4×.
    assert!(sum >= whole && sum < 2 * whole, "{sum} against {whole}");
    let out = tmp.path().join("assembled.tess");
    run(&["--assemble", text(&dir), "-o", text(&out)]);
    assert_same_bytes(&single, &out);
}
