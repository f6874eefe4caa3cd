//! `tessera-server serve` end to end, the tile endpoints: Morton-range streams
//! (`/levels/{level}/tiles`), their trailers, `/errors`, single tiles, and corrupt
//! records in each (API.md).
//!
//! Pyramids are shared by every test (`serve_support`); every test starts its own
//! server on an ephemeral port (killed when the test ends) and checks responses
//! against the pyramid file read independently with the shared reader.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{
    Server, decode_stream, etag_is_strong, fixtures, level, open, present, split_trailer,
};
use std::collections::BTreeSet;
use tessera_shared::wire::Frame;
use tessera_shared::{ErrorTable, Level, Morton, MortonRange, TileId, codec};

/// Splits a level's Morton codes into `n` contiguous ranges (fewer for small levels).
fn split_level(level: Level, n: u64) -> Vec<MortonRange> {
    let slots = level.tile_slots();
    let n = n.min(slots);
    (0..n)
        .map(|i| {
            MortonRange::new(
                Morton::from_raw(slots * i / n),
                Morton::from_raw(slots * (i + 1) / n - 1),
            )
            .unwrap()
        })
        .collect()
}

fn ranges_param(ranges: &[MortonRange]) -> String {
    ranges
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(",")
}

// ---------------------------------------------------------------------------
// Range streams

/// Every level of `synth`, each in a few ranges: every frame is the stored record,
/// in Morton order, with the index entry's checksum and min/max.
#[test]
fn range_stream_carries_the_stored_records_in_morton_order() {
    let f = fixtures();
    let p = open(&f.synth);
    let srv = Server::start(&[&f.synth], &[]);
    for l in p.geometry().levels() {
        let ranges = split_level(l, 3);
        let r = srv.get(&format!(
            "/v1/datasets/synth/levels/{l}/tiles?ranges={}",
            ranges_param(&ranges)
        ));
        let frames = decode_stream(&r);
        let (body, tiles, errors, outside) = split_trailer(&frames);
        let want: Vec<u64> = ranges
            .iter()
            .flat_map(|r| r.iter())
            .map(Morton::get)
            .collect();
        let got: Vec<u64> = body
            .iter()
            .map(|f| match f {
                Frame::Tile {
                    level,
                    morton,
                    checksum,
                    min,
                    max,
                    record,
                } => {
                    assert_eq!(*level, l);
                    let tile = TileId::from_morton(l, *morton).unwrap();
                    let e = p.entry(tile).unwrap();
                    assert_eq!(*checksum, e.checksum, "{tile}");
                    assert_eq!((*min, *max), (e.min, e.max), "{tile}");
                    assert_eq!(
                        *record,
                        p.read_record(tile).unwrap().unwrap(),
                        "{tile}: record differs from the file"
                    );
                    morton.get()
                }
                other => panic!("level {l}: unexpected frame {other:?}"),
            })
            .collect();
        assert_eq!(got, want, "level {l}: frames not in requested Morton order");
        assert_eq!(tiles, want.len() as u64, "trailer tile count");
        assert_eq!(errors, 0);
        assert!(outside.is_empty(), "synth has no absent tiles: {outside:?}");
    }

    // Ranges given out of order come back sorted; a single code is a range.
    let r = srv.get("/v1/datasets/synth/levels/3/tiles?ranges=40-41,7,20-22");
    let frames = decode_stream(&r);
    let (body, tiles, _, _) = split_trailer(&frames);
    let got: Vec<u64> = body
        .iter()
        .map(|f| match f {
            Frame::Tile { morton, .. } => morton.get(),
            other => panic!("{other:?}"),
        })
        .collect();
    assert_eq!(got, [7, 20, 21, 22, 40, 41]);
    assert_eq!(tiles, 6);
}

/// Once every record of a request has passed its checksum, the server reads each
/// record while it writes the response (into a reused buffer) instead of all of
/// them up front: the second response to the same request must be the first one
/// byte for byte, headers included, with absent tiles and gaps between ranges
/// (bigtujunga, where present) and over many ranges at once.
#[test]
fn a_stream_of_checked_records_is_byte_for_byte_the_first() {
    let f = fixtures();
    let mut sets = vec![(f.synth.clone(), "synth")];
    if let Some(b) = &f.bigtujunga {
        sets.push((b.clone(), "bigtujunga"));
    }
    for (path, name) in sets {
        let p = open(&path);
        let srv = Server::start(&[&path], &[]);
        for l in p.geometry().levels() {
            let slots = l.tile_slots();
            let mut requests = vec![split_level(l, 5)];
            if slots >= 16 {
                requests.push(vec![
                    MortonRange::new(Morton::from_raw(1), Morton::from_raw(slots / 4)).unwrap(),
                    MortonRange::single(Morton::from_raw(slots / 2 + 1)),
                    MortonRange::new(Morton::from_raw(slots - 5), Morton::from_raw(slots - 1))
                        .unwrap(),
                ]);
            }
            for ranges in requests {
                let url = format!(
                    "/v1/datasets/{name}/levels/{l}/tiles?ranges={}",
                    ranges_param(&ranges)
                );
                let first = srv.get(&url).expect(200);
                for _ in 0..2 {
                    let again = srv.get(&url).expect(200);
                    assert!(again.body == first.body, "{url}: the bodies differ");
                    for h in ["content-length", "etag", "cache-control", "content-type"] {
                        assert_eq!(again.header(h), first.header(h), "{url}: {h}");
                    }
                }
                assert_eq!(
                    first.must("content-length"),
                    first.body.len().to_string(),
                    "{url}"
                );
                // And it is the stream of the stored records.
                let frames = decode_stream(&first);
                let (body, tiles, errors, _) = split_trailer(&frames);
                assert_eq!((tiles, errors), (body.len() as u64, 0), "{url}");
                for fr in body {
                    let Frame::Tile { morton, record, .. } = fr else {
                        panic!("{url}: {fr:?}");
                    };
                    let t = TileId::from_morton(l, *morton).unwrap();
                    assert_eq!(*record, p.read_record(t).unwrap().unwrap(), "{url}: {t}");
                }
            }
        }
    }
}

/// On a non-square DEM, the trailer names exactly the requested codes without a tile.
#[test]
fn trailer_reports_exactly_the_absent_codes() {
    let f = fixtures();
    let Some(path) = f.bigtujunga.as_deref() else {
        return;
    };
    let p = open(path);
    let srv = Server::start(&[path], &[]);
    let name = "bigtujunga";
    for l in p.geometry().levels() {
        let pres = present(&p, l);
        if l.get() > 0 {
            assert!(
                pres.contains(&false) && pres.contains(&true),
                "fixture: level {l} should have both present and absent tiles"
            );
        }
        // The whole level in a few ranges, and a sparse request with gaps.
        let slots = l.tile_slots();
        let mut requests = vec![split_level(l, 4)];
        if slots >= 16 {
            requests.push(vec![
                MortonRange::new(Morton::from_raw(1), Morton::from_raw(slots / 4)).unwrap(),
                MortonRange::new(Morton::from_raw(slots / 2), Morton::from_raw(slots / 2 + 3))
                    .unwrap(),
                MortonRange::single(Morton::from_raw(slots - 1)),
            ]);
        }
        for ranges in requests {
            let r = srv.get(&format!(
                "/v1/datasets/{name}/levels/{l}/tiles?ranges={}",
                ranges_param(&ranges)
            ));
            let frames = decode_stream(&r);
            let (body, tiles, errors, outside) = split_trailer(&frames);
            let requested: Vec<u64> = ranges
                .iter()
                .flat_map(|r| r.iter())
                .map(Morton::get)
                .collect();
            let want_present: Vec<u64> = requested
                .iter()
                .copied()
                .filter(|&m| pres[m as usize])
                .collect();
            let want_absent: BTreeSet<u64> = requested
                .iter()
                .copied()
                .filter(|&m| !pres[m as usize])
                .collect();
            let got_present: Vec<u64> = body
                .iter()
                .map(|f| match f {
                    Frame::Tile { morton, record, .. } => {
                        let t = TileId::from_morton(l, *morton).unwrap();
                        assert_eq!(*record, p.read_record(t).unwrap().unwrap(), "{t}");
                        morton.get()
                    }
                    other => panic!("{other:?}"),
                })
                .collect();
            assert_eq!(got_present, want_present, "level {l} {ranges:?}");
            assert_eq!(tiles, want_present.len() as u64);
            assert_eq!(errors, 0);
            // Outside ranges: sorted, disjoint, within the request, and covering
            // exactly the absent codes.
            let mut covered = BTreeSet::new();
            for w in outside.windows(2) {
                assert!(
                    w[0].end() < w[1].start(),
                    "unsorted/overlapping {outside:?}"
                );
            }
            for o in &outside {
                for m in o.iter() {
                    assert!(covered.insert(m.get()));
                }
            }
            assert_eq!(
                covered,
                want_absent,
                "level {l}, ranges {}: trailer outside {outside:?}",
                ranges_param(&ranges)
            );
        }
    }
}

/// `/errors`: only the leading error table of each record, with the entry's min/max.
#[test]
fn errors_endpoint_sends_error_tables() {
    let f = fixtures();
    let p = open(&f.synth);
    let table_len = ErrorTable::byte_len(p.geometry().tile_log2());
    let srv = Server::start(&[&f.synth], &[]);
    for l in [level(2), level(4)] {
        let ranges = split_level(l, 3);
        let r = srv.get(&format!(
            "/v1/datasets/synth/levels/{l}/errors?ranges={}",
            ranges_param(&ranges)
        ));
        let frames = decode_stream(&r);
        let (body, tiles, errors, _) = split_trailer(&frames);
        assert_eq!(body.len() as u64, l.tile_slots());
        assert_eq!(tiles, l.tile_slots());
        assert_eq!(errors, 0);
        for (i, fr) in body.iter().enumerate() {
            let Frame::ErrorTable {
                level,
                morton,
                min,
                max,
                table,
            } = fr
            else {
                panic!("not an error-table frame: {fr:?}");
            };
            assert_eq!(*level, l);
            assert_eq!(morton.get(), i as u64, "Morton order");
            let t = TileId::from_morton(l, *morton).unwrap();
            let e = p.entry(t).unwrap();
            assert_eq!((*min, *max), (e.min, e.max), "{t}");
            let rec = p.read_record(t).unwrap().unwrap();
            assert_eq!(table.len(), table_len, "{t}");
            assert_eq!(table[..], rec[..table_len], "{t}");
            // And it parses as the table the reader finds.
            assert_eq!(
                codec::decode_error_table(table, p.geometry().tile_log2()).unwrap(),
                p.read_error_table(t).unwrap().unwrap()
            );
        }
    }
}

// ---------------------------------------------------------------------------
// Single tiles

#[test]
fn single_tile_endpoint() {
    let f = fixtures();
    let p = open(&f.synth);
    let srv = Server::start(&[&f.synth], &[]);
    let t = TileId::new(level(4), 3, 5).unwrap();
    let r = srv.get("/v1/datasets/synth/tiles/4/3/5").expect(200);
    assert_eq!(r.body, p.read_record(t).unwrap().unwrap());
    assert_eq!(
        r.must("content-length").parse::<usize>().unwrap(),
        r.body.len()
    );
    let etag = r.must("etag").to_string();
    etag_is_strong(&etag);

    let nm = srv.get_with(
        "/v1/datasets/synth/tiles/4/3/5",
        &[("if-none-match", &etag)],
    );
    assert_eq!(nm.status, 304, "{}", nm.text());
    assert!(nm.body.is_empty());
    assert_eq!(nm.must("etag"), etag);
    // Another tile has another ETag and is not 304 for this one's.
    let other = srv.get_with(
        "/v1/datasets/synth/tiles/4/5/3",
        &[("if-none-match", &etag)],
    );
    assert_eq!(other.status, 200);
    assert_ne!(other.must("etag"), etag);
    assert_eq!(
        other.body,
        p.read_record(TileId::new(level(4), 5, 3).unwrap())
            .unwrap()
            .unwrap()
    );

    // Out of range x / y, and non-numbers.
    for bad in ["4/16/0", "4/0/16", "0/1/0", "4/x/0", "4/-1/0"] {
        let e = srv
            .get(&format!("/v1/datasets/synth/tiles/{bad}"))
            .error(404);
        assert!(e.contains("tile") || e.contains("level"), "{bad}: {e}");
    }

    // An absent tile (beyond the DEM).
    if let Some(path) = f.bigtujunga.as_deref() {
        let bp = open(path);
        let srv = Server::start(&[path], &[]);
        let finest = bp.geometry().finest();
        let absent = (0..finest.tile_slots())
            .map(|m| TileId::from_morton(finest, Morton::from_raw(m)).unwrap())
            .find(|t| bp.entry(*t).is_none())
            .unwrap();
        let e = srv
            .get(&format!(
                "/v1/datasets/bigtujunga/tiles/{finest}/{}/{}",
                absent.x(),
                absent.y()
            ))
            .error(404);
        assert!(e.contains("outside"), "{e}");
    }
}

// ---------------------------------------------------------------------------
// Corrupt records

#[test]
fn corrupt_record_is_reported_not_served() {
    let f = fixtures();
    let p = open(&f.synth);
    let c = f.corrupt_tile;
    let l = c.level();
    let m = c.morton().get();
    let srv = Server::start(&[&f.synth, &f.corrupt], &[]);
    let path = format!(
        "/v1/datasets/synth-corrupt/levels/{l}/tiles?ranges={}-{}",
        m - 3,
        m + 3
    );
    // Twice: the server remembers a bad record, and must keep reporting it.
    for _ in 0..2 {
        let frames = decode_stream(&srv.get(&path));
        let (body, tiles, errors, outside) = split_trailer(&frames);
        assert_eq!((tiles, errors), (6, 1));
        assert!(outside.is_empty());
        assert_eq!(body.len(), 7);
        for (k, fr) in body.iter().enumerate() {
            let want = m - 3 + k as u64;
            match fr {
                Frame::Error {
                    level,
                    morton,
                    message,
                } => {
                    assert_eq!(
                        (*level, morton.get()),
                        (l, m),
                        "error frame for the wrong tile"
                    );
                    assert!(!message.is_empty());
                }
                Frame::Tile { morton, record, .. } => {
                    assert_eq!(morton.get(), want);
                    assert_ne!(want, m, "the corrupt record was sent as a tile");
                    let t = TileId::from_morton(l, *morton).unwrap();
                    assert_eq!(*record, p.read_record(t).unwrap().unwrap());
                }
                other => panic!("{other:?}"),
            }
            if let Frame::Error { .. } = fr {
                assert_eq!(want, m);
            }
        }
    }
    let single = format!("/v1/datasets/synth-corrupt/tiles/{l}/{}/{}", c.x(), c.y());
    let e = srv.get(&single).error(500);
    assert!(e.to_lowercase().contains("checksum"), "{e}");
    // Everything else still serves.
    let (nx, ny) = Morton::from_raw(m + 1).decode();
    let ok = srv
        .get(&format!("/v1/datasets/synth-corrupt/tiles/{l}/{nx}/{ny}"))
        .expect(200);
    assert_eq!(
        ok.body,
        p.read_record(TileId::new(l, nx, ny).unwrap())
            .unwrap()
            .unwrap()
    );
    let same_in_good = srv
        .get(&format!("/v1/datasets/synth/tiles/{l}/{}/{}", c.x(), c.y()))
        .expect(200);
    assert_eq!(same_in_good.body, p.read_record(c).unwrap().unwrap());
    srv.get("/healthz").expect(200);
}

/// A stream that carries an Error frame instead of a record is not the dataset's
/// content: no cache may keep it as such. The content hash comes from the index (the
/// checksums the records *should* have), so it is the same before and after the file
/// is repaired; an error-bearing response must therefore not be `immutable`, and its
/// ETag must not revalidate against the repaired file's good response.
#[test]
fn stream_with_a_corrupt_record_is_not_cached_as_the_content() {
    let f = fixtures();
    let c = f.corrupt_tile;
    let m = c.morton().get();
    let hash = open(&f.corrupt).metadata().content_hash.clone();
    assert_eq!(
        hash,
        open(&f.repaired).metadata().content_hash,
        "fixture: repair keeps the content hash"
    );
    let path = format!(
        "/v1/datasets/synth-corrupt/levels/{}/tiles?ranges={}-{}&v={hash}",
        c.level(),
        m - 1,
        m + 1
    );

    let srv = Server::start(&[&f.corrupt], &[]);
    let bad = srv.get(&path);
    let frames = decode_stream(&bad);
    assert!(frames.iter().any(|f| matches!(f, Frame::Error { .. })));
    let cc = bad.header("cache-control").unwrap_or("");
    assert!(
        !cc.contains("immutable"),
        "a response with an Error frame is cached as immutable: Cache-Control {cc:?}"
    );
    let bad_etag = bad.header("etag").map(str::to_string);
    drop(srv);

    // The operator replaces the file with a good copy and restarts.
    let srv = Server::start(&[&f.repaired], &[]);
    let good = srv.get(&path);
    let frames = decode_stream(&good);
    assert!(frames.iter().all(|f| !matches!(f, Frame::Error { .. })));
    if let Some(e) = bad_etag {
        assert_ne!(
            good.header("etag"),
            Some(e.as_str()),
            "the error-bearing and the good body share one strong ETag"
        );
        let r = srv.get_with(&path, &[("if-none-match", &e)]);
        assert_eq!(
            r.status, 200,
            "a cache holding the error-bearing stream is told it is still current (304)"
        );
    }
}
