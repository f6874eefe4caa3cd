//! `build --update` (DECISIONS.md "Updates") with the real binary on a real DEM cut by
//! GDAL into 16 COG pieces: after a piece is resurveyed, the update is byte for byte
//! the whole build of the new pieces, reads only the changed piece's tiles, copies every
//! record away from it (so those tiles keep their ETag and a cache revalidates them with
//! 304 from the real server), and chains; an update that cannot be exact (a piece gone)
//! builds the whole pyramid and says why; a state that is missing,
//! of another pyramid or damaged, and other options than the old pyramid's, are
//! refused, naming it.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses its own subset
mod cli_support;
mod gdal;
#[allow(dead_code)] // the serve tests' support, of which this binary uses the server
mod serve_support;

use cli_support::{assert_same_bytes, build_args as build, text};
use gdal::pieces::{cog_pieces, resurvey};
use std::path::Path;
use tessera_shared::reader::Pyramid;
use tessera_shared::{Level, Morton, TileId};

/// `build DIR --tile-size 64 --update OLD -o NEW`.
fn update(dir: &str, old: &Path, new: &Path) -> Result<String, String> {
    build(&[
        dir,
        "--tile-size",
        "64",
        "--update",
        text(old),
        "-o",
        text(new),
    ])
}

/// The numbers of the "updated … from …" line: tiles with new bytes, tiles copied,
/// samples read, samples in all.
fn update_line(stdout: &str) -> [u64; 4] {
    let line = stdout
        .lines()
        .find(|l| l.starts_with("updated "))
        .unwrap_or_else(|| panic!("no update line: {stdout}"));
    let after = line.split_once(": ").unwrap().1;
    let n: Vec<u64> = after
        .split(|c: char| !c.is_ascii_digit() && c != '.')
        .filter_map(|t| t.parse().ok())
        .collect();
    // "N tiles with new bytes, M copied byte for byte (K finest tiles measured again);
    // read S of T input samples (P %)"
    [n[0], n[1], n[3], n[4]]
}

/// Every tile's `(level, Morton, checksum)` in a pyramid.
fn checksums(p: &Path) -> Vec<(u8, u64, u64)> {
    let p = Pyramid::open_file(p).unwrap();
    let mut out = Vec::new();
    for l in p.geometry().levels() {
        for (m, e) in p.index(l).unwrap().iter().enumerate() {
            if e.length > 0 {
                out.push((l.get(), m as u64, e.checksum));
            }
        }
    }
    out
}

/// Whether the closed footprint of tile `m` of `level` (tiles of 64 cells, 6 levels)
/// meets the window `[x0, x0 + 512) × [y0, y0 + 512)`.
fn meets(level: u8, m: u64, x0: u64, y0: u64) -> bool {
    let (x, y) = Morton::from_raw(m).decode();
    let span = 64u64 << (5 - level);
    let (tx, ty) = (u64::from(x) * span, u64::from(y) * span);
    tx <= x0 + 511 && tx + span >= x0 && ty <= y0 + 511 && ty + span >= y0
}

#[test]
fn an_update_is_the_whole_build_and_copies_what_did_not_change() {
    let tmp = tempfile::tempdir().unwrap();
    let Some(_) = cog_pieces(tmp.path()) else {
        return;
    };
    let dir = format!("{}/", tmp.path().display());
    let old = tmp.path().join("old.tess");
    build(&[&dir, "--tile-size", "64", "--state", "-o", text(&old)]).unwrap();
    assert!(tmp.path().join("old.tess.state").is_file());

    // A new survey of the piece at row 1, column 2: samples 1024..1536 × 512..1024.
    resurvey(&tmp.path().join("p12.tif"));
    let whole = tmp.path().join("whole.tess");
    build(&[&dir, "--tile-size", "64", "-o", text(&whole)]).unwrap();
    let new = tmp.path().join("new.tess");
    let stdout = update(&dir, &old, &new).unwrap();
    assert_same_bytes(&whole, &new);
    let [rewritten, copied, read, all] = update_line(&stdout);
    // The piece is 1/16 of the samples; its tiles' windows reach one sample past it.
    assert!(read > 0 && read * 10 < all, "{stdout}");
    assert!(rewritten > 0 && copied > rewritten, "{stdout}");

    // Exactly the tiles over the piece changed; every other keeps its checksum.
    let before = checksums(&old);
    let after = checksums(&new);
    assert_eq!(before.len(), after.len());
    let mut changed = 0;
    for (b, a) in before.iter().zip(&after) {
        assert_eq!((b.0, b.1), (a.0, a.1));
        // A tile's bytes change exactly when its footprint meets the piece.
        let differs = b.2 != a.2;
        assert_eq!(
            differs,
            meets(a.0, a.1, 1024, 512),
            "tile {a:?}: new bytes {differs}"
        );
        changed += u64::from(differs);
    }
    assert_eq!(changed, rewritten);

    // Served: a tile away from the piece answers 304 to the old tile's ETag; one on it
    // answers 200 with a new ETag.
    let server = serve_support::Server::start(&[&new], &[]);
    let etag = |p: &Path, l: u8, m: u64| {
        let pyr = Pyramid::open_file(p).unwrap();
        let tile = TileId::from_morton(Level::new(l).unwrap(), Morton::from_raw(m)).unwrap();
        format!("\"{:016x}\"", pyr.entry(tile).unwrap().checksum)
    };
    let far = TileId::from_morton(Level::new(5).unwrap(), Morton::from_raw(0)).unwrap();
    let near = TileId::new(Level::new(5).unwrap(), 20, 10).unwrap();
    let path = |t: TileId| format!("/v1/datasets/new/tiles/5/{}/{}", t.x(), t.y());
    let r = server.get_with(
        &path(far),
        &[("If-None-Match", etag(&old, 5, far.morton().get()).as_str())],
    );
    assert_eq!(r.status, 304, "an unchanged tile is revalidated");
    let r = server.get_with(
        &path(near),
        &[("If-None-Match", etag(&old, 5, near.morton().get()).as_str())],
    );
    assert_eq!(r.status, 200, "a changed tile is sent again");
    assert_eq!(r.must("etag"), etag(&new, 5, near.morton().get()));
    drop(server);

    // Updates chain: the update wrote its own state.
    resurvey(&tmp.path().join("p30.tif"));
    build(&[&dir, "--tile-size", "64", "-o", text(&whole)]).unwrap();
    let newer = tmp.path().join("newer.tess");
    let stdout = update(&dir, &new, &newer).unwrap();
    assert!(stdout.contains("updated "), "{stdout}");
    assert_same_bytes(&whole, &newer);

    // Nothing changed: everything copied, nothing read.
    let same = tmp.path().join("same.tess");
    let stdout = update(&dir, &newer, &same).unwrap();
    let [rewritten, _, read, _] = update_line(&stdout);
    assert_eq!((rewritten, read), (0, 0), "{stdout}");
    assert_same_bytes(&newer, &same);
}

#[test]
fn other_options_are_refused_and_an_inexact_update_builds_whole() {
    let tmp = tempfile::tempdir().unwrap();
    let Some(pieces) = cog_pieces(tmp.path()) else {
        return;
    };
    let dir = format!("{}/", tmp.path().display());
    let old = tmp.path().join("old.tess");
    build(&[&dir, "--tile-size", "64", "--state", "-o", text(&old)]).unwrap();

    // Other options than the old pyramid's: an error naming it, and nothing written.
    let out = tmp.path().join("other.tess");
    for (flags, says) in [
        (
            &["--tile-size", "128"][..],
            "built with --tile-size 64, this build asks for 128",
        ),
        (
            &["--tile-size", "64", "--offset", "-10000"][..],
            "(--scale, --offset, --height-range)",
        ),
        (
            &["--tile-size", "64", "--vertical-datum", "egm96"][..],
            "(--vertical-datum, --to-vertical)",
        ),
    ] {
        let args: Vec<&str> = [dir.as_str()]
            .into_iter()
            .chain(flags.iter().copied())
            .chain(["--update", text(&old), "-o", text(&out)])
            .collect();
        let e = build(&args).unwrap_err();
        assert!(
            e.contains("old.tess: ") && e.contains(says),
            "{flags:?}: {e}"
        );
        assert_eq!(
            e.trim().lines().filter(|l| l.starts_with("error")).count(),
            1,
            "{e}"
        );
        assert!(!out.exists() && !tmp.path().join("other.tess.state").exists());
    }
    let names: Vec<String> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains("partial"))
        .collect();
    assert!(names.is_empty(), "left behind: {names:?}");

    // A piece gone: its samples become no-data, filled from across the input.
    std::fs::rename(&pieces[10], tmp.path().join("away.tif.bak")).unwrap();
    let out = tmp.path().join("gone.tess");
    let stdout = update(&dir, &old, &out).unwrap();
    assert!(
        stdout.contains("built the whole pyramid, not an update: its share holds no-data"),
        "{stdout}"
    );
    let whole = tmp.path().join("whole-gone.tess");
    build(&[&dir, "--tile-size", "64", "-o", text(&whole)]).unwrap();
    assert_same_bytes(&whole, &out);
    assert!(
        tmp.path().join("gone.tess.state").is_file(),
        "a whole build by --update writes a state"
    );
}

#[test]
fn a_missing_foreign_or_damaged_state_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let Some(_) = cog_pieces(tmp.path()) else {
        return;
    };
    let dir = format!("{}/", tmp.path().display());
    let (a, b) = (tmp.path().join("a.tess"), tmp.path().join("b.tess"));
    build(&[&dir, "--tile-size", "64", "--state", "-o", text(&a)]).unwrap();
    build(&[&dir, "--tile-size", "128", "-o", text(&b)]).unwrap();
    let out = tmp.path().join("out.tess");
    let update = |old: &Path| {
        build(&[
            &dir,
            "--tile-size",
            "64",
            "--update",
            text(old),
            "-o",
            text(&out),
        ])
    };

    let e = update(&b).unwrap_err();
    assert!(e.contains("b.tess.state") && e.contains("--state"), "{e}");
    // The state of another pyramid.
    std::fs::copy(
        tmp.path().join("a.tess.state"),
        tmp.path().join("b.tess.state"),
    )
    .unwrap();
    let e = update(&b).unwrap_err();
    assert!(
        e.contains("b.tess.state: the state of another pyramid"),
        "{e}"
    );
    // A damaged byte.
    let state = tmp.path().join("a.tess.state");
    let mut bytes = std::fs::read(&state).unwrap();
    bytes[100] ^= 0x40;
    std::fs::write(&state, &bytes).unwrap();
    let e = update(&a).unwrap_err();
    assert!(
        e.contains("a.tess.state") && e.contains("checksum does not match"),
        "{e}"
    );
    assert!(!out.exists() && !tmp.path().join("out.tess.state").exists());
}

/// A DEM of `1 + 16 · 64` samples a side: its last column and row are the last
/// tiles' shared edge, where no tile starts; an update that measures tiles against
/// corners there reads them from those tiles.
#[test]
fn an_update_of_a_dem_ending_on_a_tile_edge() {
    let Some(png) = tessera_shared::testdata::dem_or_skip("moon_crisium_gld100_4096.png") else {
        return;
    };
    if !gdal::gdal_or_skip() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let whole_tif = t.join("whole.tif");
    gdal::run(
        "gdal_translate",
        &[
            "-q", "-srcwin", "0", "0", "1025", "1025", "-a_ullr", "0", "242822.5", "242822.5", "0",
        ]
        .into_iter()
        .chain([text(&png), text(&whole_tif)])
        .collect::<Vec<_>>(),
    );
    std::fs::create_dir(t.join("pieces")).unwrap();
    for (name, x, w) in [("a.tif", "0", "512"), ("b.tif", "512", "513")] {
        let out = t.join("pieces").join(name);
        gdal::run(
            "gdal_translate",
            &[
                "-q",
                "-of",
                "COG",
                "-co",
                "BLOCKSIZE=256",
                "-srcwin",
                x,
                "0",
                w,
                "1025",
            ]
            .into_iter()
            .chain([text(&whole_tif), text(&out)])
            .collect::<Vec<_>>(),
        );
    }
    let dir = format!("{}/", t.join("pieces").display());
    let old = t.join("old.tess");
    build(&[&dir, "--tile-size", "64", "--state", "-o", text(&old)]).unwrap();
    resurvey(&t.join("pieces").join("a.tif"));
    let whole = t.join("whole.tess");
    build(&[&dir, "--tile-size", "64", "-o", text(&whole)]).unwrap();
    let new = t.join("new.tess");
    let stdout = update(&dir, &old, &new).unwrap();
    assert!(stdout.contains("updated "), "{stdout}");
    assert_same_bytes(&whole, &new);
}
