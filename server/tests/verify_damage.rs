//! `verify` checks every byte that can be checked (docs/ARCHITECTURE.md#nothing-partial):
//! damage made to look consistent — checksums recomputed after the change, as a careless
//! tool or an attacker would — must still be named, and `verify` must exit 1.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

use std::path::{Path, PathBuf};
use std::process::Command;
use tessera_server::builder::{BuildOptions, build};
use tessera_shared::format::{self, FileHeader, HEADER_LEN, INDEX_ENTRY_LEN, IndexEntry};
use tessera_shared::{Metadata, Pyramid, TileId};

/// A small pyramid (3 levels of 64-cell tiles) and its bytes.
fn pyramid(dir: &Path) -> (PathBuf, Vec<u8>) {
    let out = dir.join("s.tess");
    let opts = BuildOptions {
        tile_size: 64,
        ..BuildOptions::default()
    };
    build("synthetic:257:5", &out, &opts).unwrap();
    let bytes = std::fs::read(&out).unwrap();
    (out, bytes)
}

fn header(bytes: &[u8]) -> FileHeader {
    FileHeader::parse(&bytes[..HEADER_LEN]).unwrap()
}

/// Recomputes the header checksum over the (changed) header region.
fn rehash_header(bytes: &mut [u8]) {
    let mut h = header(bytes);
    h.checksum = h.compute_checksum(&bytes[HEADER_LEN..h.records_offset as usize]);
    bytes[..HEADER_LEN].copy_from_slice(&h.to_bytes());
}

/// Where tile `tile`'s index entry lies in the file.
fn entry_at(bytes: &[u8], tile: TileId) -> usize {
    let p = Pyramid::open(bytes.to_vec()).unwrap();
    let level = p.level_entry(tile.level()).unwrap();
    (level.index_offset + tile.morton().get() * INDEX_ENTRY_LEN as u64) as usize
}

fn edit_entry(bytes: &mut [u8], tile: TileId, f: impl FnOnce(&mut IndexEntry)) {
    let at = entry_at(bytes, tile);
    let mut e = IndexEntry::parse(&bytes[at..at + INDEX_ENTRY_LEN]);
    f(&mut e);
    bytes[at..at + INDEX_ENTRY_LEN].copy_from_slice(&e.to_bytes());
    rehash_header(bytes);
}

/// Rewrites the metadata in its reserved space and re-hashes the header.
fn edit_metadata(bytes: &mut [u8], f: impl FnOnce(&mut Metadata)) {
    let mut h = header(bytes);
    let (at, len) = (h.meta_offset as usize, h.meta_len as usize);
    let mut meta = format::decode_metadata(&bytes[at..at + len]).unwrap();
    f(&mut meta);
    let new = format::encode_metadata(&meta);
    let end = h.records_offset as usize;
    assert!(at + new.len() <= end, "metadata outgrew its reserve");
    bytes[at..end].fill(0);
    bytes[at..at + new.len()].copy_from_slice(&new);
    h.meta_len = new.len() as u64;
    bytes[..HEADER_LEN].copy_from_slice(&h.to_bytes());
    rehash_header(bytes);
}

/// Runs `tessera-server verify` on `bytes` and returns (exit code, stdout).
fn verify(dir: &Path, name: &str, bytes: &[u8]) -> (Option<i32>, String) {
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_tessera-server"))
        .arg("verify")
        .arg(&path)
        .output()
        .unwrap();
    let mut text = String::from_utf8_lossy(&o.stdout).into_owned();
    text.push_str(&String::from_utf8_lossy(&o.stderr));
    (o.status.code(), text)
}

fn assert_named(dir: &Path, name: &str, bytes: &[u8], want: &str) {
    let (code, text) = verify(dir, name, bytes);
    assert_eq!(
        code,
        Some(1),
        "{name}: verify passed damaged content:\n{text}"
    );
    assert!(
        text.contains(want),
        "{name}: verify does not say {want:?}:\n{text}"
    );
}

#[test]
fn the_undamaged_pyramid_verifies() {
    let dir = tempfile::tempdir().unwrap();
    let (_, bytes) = pyramid(dir.path());
    let (code, text) = verify(dir.path(), "ok.tess", &bytes);
    assert_eq!(code, Some(0), "{text}");
}

#[test]
fn index_summaries_that_disagree_with_their_records_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let (path, bytes) = pyramid(dir.path());
    let p = Pyramid::open_file(&path).unwrap();
    let g = *p.geometry();
    let tile = g.present_tiles(g.finest()).nth(3).unwrap();
    let (lo, hi) = {
        let e = p.entry(tile).unwrap();
        (e.min, e.max)
    };
    // min above max (`info` then showed min 6191.9 > max −2000).
    let mut b = bytes.clone();
    edit_entry(&mut b, tile, |e| {
        (e.min, e.max) = (hi.saturating_add(500), lo);
    });
    assert_named(
        dir.path(),
        "minmax.tess",
        &b,
        &format!("bad {tile}: index says heights"),
    );
    // A NaN and an infinity as the index's error.
    for (name, v) in [("nan.tess", f32::NAN), ("inf.tess", f32::INFINITY)] {
        let mut b = bytes.clone();
        edit_entry(&mut b, tile, |e| e.full_res_error = v);
        assert_named(dir.path(), name, &b, "not a finite non-negative");
    }
    // Reserved flags.
    let mut b = bytes.clone();
    edit_entry(&mut b, tile, |e| e.flags = 4);
    assert_named(dir.path(), "flags.tess", &b, "reserved index flags");
}

#[test]
fn a_nan_in_an_error_table_under_a_recomputed_checksum_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let (path, mut bytes) = pyramid(dir.path());
    let p = Pyramid::open_file(&path).unwrap();
    let tile = TileId::new(p.geometry().finest(), 1, 1).unwrap();
    let e = *p.entry(tile).unwrap();
    // The error table is the record's first bytes, f32 little-endian: poison one.
    let at = e.offset as usize + 4 * 70;
    bytes[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let checksum = format::checksum(&bytes[e.offset as usize..e.end() as usize]);
    edit_entry(&mut bytes, tile, |e| e.checksum = checksum);
    assert_named(
        dir.path(),
        "table.tess",
        &bytes,
        &format!("bad {tile}: error table holds 1"),
    );
}

#[test]
fn metadata_damage_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let (_, bytes) = pyramid(dir.path());
    // The quantization offset moved by 512 m: every height moves.
    let mut b = bytes.clone();
    edit_metadata(&mut b, |m| m.quantization.offset -= 512.0);
    assert_named(
        dir.path(),
        "offset.tess",
        &b,
        "does not match the file's content",
    );
    // ... even when the content hash is recomputed to match.
    let mut b = bytes.clone();
    edit_metadata(&mut b, |m| {
        m.quantization.offset -= 512.0;
        let p = Pyramid::open(bytes.clone()).unwrap();
        let sums: Vec<u64> = p
            .geometry()
            .levels()
            .flat_map(|l| p.index(l).unwrap().iter().filter(|e| e.is_present()))
            .map(|e| e.checksum)
            .collect();
        m.content_hash = format::content_hash(m, format::VERSION, sums.iter());
    });
    assert_named(
        dir.path(),
        "offset-rehashed.tess",
        &b,
        "disagree with the quantized records",
    );
    // A content hash with a control character, and one that is not hex.
    for (name, hash) in [
        ("ctl.tess", "0123456789ab\r\ncd"),
        ("hex.tess", "zzzzzzzzzzzzzzzz"),
    ] {
        let mut b = bytes.clone();
        edit_metadata(&mut b, |m| m.content_hash = hash.into());
        assert_named(dir.path(), name, &b, "not 16 lowercase hex digits");
    }
    // Reserved header flags.
    let mut b = bytes.clone();
    let mut h = header(&b);
    h.flags = 1;
    b[..HEADER_LEN].copy_from_slice(&h.to_bytes());
    rehash_header(&mut b);
    assert_named(dir.path(), "hflags.tess", &b, "reserved header flags");
}

/// FORMAT.md says `records_offset` is a multiple of 4096; `verify` did not check it.
/// Moved 8 bytes back into the padding (header checksum recomputed) the file still
/// opens and reads, and `verify` must name the problem.
#[test]
fn a_records_offset_off_the_page_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let (_, mut bytes) = pyramid(dir.path());
    let mut h = header(&bytes);
    assert_eq!(h.records_offset % 4096, 0);
    let end = h.records_offset as usize;
    assert!(bytes[end - 8..end].iter().all(|b| *b == 0), "padding");
    h.records_offset -= 8;
    bytes[..HEADER_LEN].copy_from_slice(&h.to_bytes());
    rehash_header(&mut bytes);
    Pyramid::open(bytes.clone()).expect("the file still opens");
    assert_named(
        dir.path(),
        "offset.tess",
        &bytes,
        &format!(
            "bad file: records_offset {} is not a multiple of 4096",
            end - 8
        ),
    );
}
