//! `tessera-server serve` end to end: the real binary over real HTTP (API.md).
//!
//! Pyramids are built once per test binary with `tessera-server build`; every test
//! starts its own server on an ephemeral port (killed when the test ends) and checks
//! responses against the pyramid file read independently with the shared reader.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

mod serve_support;

use serve_support::{
    Fixtures, Resp, Server, find, fixtures, metric, parse_head, parse_metrics, present, raw_get,
};
use std::collections::BTreeSet;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::time::{Duration, Instant};
use tessera_shared::wire::{self, Frame};
use tessera_shared::{
    ErrorTable, FileSource, Level, Morton, MortonRange, Pyramid, TileId, codec, testdata,
};

fn open(path: &Path) -> Pyramid<FileSource> {
    Pyramid::open_file(path).unwrap()
}

fn level(l: u8) -> Level {
    Level::new(l).unwrap()
}

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

/// Decodes a tile stream response after checking its head.
fn decode_stream(r: &Resp) -> Vec<Frame> {
    assert_eq!(r.status, 200, "GET {}: {}", r.path, r.text());
    assert_eq!(r.must("content-type"), wire::CONTENT_TYPE, "GET {}", r.path);
    assert_eq!(
        r.must("content-length").parse::<usize>().unwrap(),
        r.body.len(),
        "GET {}: Content-Length",
        r.path
    );
    wire::decode_all(&r.body).unwrap_or_else(|e| panic!("GET {}: {e}", r.path))
}

/// Splits off the trailer, which must be the last frame and the only one.
fn split_trailer(frames: &[Frame]) -> (&[Frame], u64, u64, Vec<MortonRange>) {
    let (last, body) = frames.split_last().expect("at least a trailer");
    let Frame::Trailer {
        tiles,
        errors,
        outside,
    } = last
    else {
        panic!("last frame is not the trailer: {last:?}");
    };
    assert!(
        body.iter().all(|f| !matches!(f, Frame::Trailer { .. })),
        "a trailer before the end"
    );
    (body, *tiles, *errors, outside.clone())
}

/// A JSON number equal to `want` (up to decimal round-tripping).
fn approx(v: &serde_json::Value, want: f64) {
    let got = v.as_f64().unwrap_or_else(|| panic!("{v} is not a number"));
    assert!(
        (got - want).abs() <= 1e-12 * want.abs().max(1.0),
        "{got} != {want}"
    );
}

fn etag_is_strong(etag: &str) {
    assert!(
        etag.len() > 2 && etag.starts_with('"') && etag.ends_with('"') && !etag.contains("W/"),
        "not a strong ETag: {etag:?}"
    );
}

// ---------------------------------------------------------------------------
// Health and metadata

#[test]
fn healthz_and_dataset_metadata_match_the_files() {
    let f = fixtures();
    let mut files: Vec<&Path> = vec![&f.synth, &f.corrupt];
    files.extend(f.bigtujunga.as_deref());
    let srv = Server::start(&files, &[]);

    let h = srv.get("/healthz").expect(200).json();
    assert_eq!(h["status"], "ok", "{h}");
    assert_eq!(h["datasets"], files.len(), "{h}");

    let list = srv.get("/v1/datasets").expect(200).json();
    let listed = list["datasets"]
        .as_array()
        .unwrap_or_else(|| panic!("{list}"));
    let names: BTreeSet<&str> = listed.iter().map(|d| d["name"].as_str().unwrap()).collect();
    let want: BTreeSet<&str> = files
        .iter()
        .map(|p| p.file_stem().unwrap().to_str().unwrap())
        .collect();
    assert_eq!(names, want, "datasets are named by file stem");

    for path in &files {
        let name = path.file_stem().unwrap().to_str().unwrap();
        let m = open(path).metadata().clone();
        let in_list = listed.iter().find(|d| d["name"] == name).unwrap();
        let one = srv.get(&format!("/v1/datasets/{name}")).expect(200);
        assert!(
            one.must("content-type").starts_with("application/json"),
            "{:?}",
            one.headers
        );
        let one = one.json();
        for d in [in_list, &one] {
            assert_eq!(d["name"], name);
            assert_eq!(d["width"], m.width, "{name}: {d}");
            assert_eq!(d["height"], m.height, "{name}: {d}");
            assert_eq!(d["levels"], m.levels, "{name}: {d}");
            assert_eq!(d["tile_size"], m.tile_size, "{name}: {d}");
            assert_eq!(d["content_hash"], m.content_hash.as_str(), "{name}: {d}");
            approx(&d["min_height"], m.min_height);
            approx(&d["max_height"], m.max_height);
            approx(&d["quantization"]["scale"], m.quantization.scale);
            approx(&d["quantization"]["offset"], m.quantization.offset);
        }
        assert_eq!(in_list, &one, "{name}: list and single description differ");
    }

    let e = srv.get("/v1/datasets/nosuchthing").error(404);
    assert!(e.contains("nosuchthing"), "{e}");
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
// Caching

#[test]
fn etags_304s_and_cache_control() {
    let f = fixtures();
    let hash = open(&f.synth).metadata().content_hash.clone();
    let srv = Server::start(&[&f.synth], &["--cache-max-age", "123"]);
    let tiles = "/v1/datasets/synth/levels/3/tiles?ranges=0-7";

    let a = srv.get(tiles).expect(200);
    let etag = a.must("etag").to_string();
    etag_is_strong(&etag);
    let cc = a.must("cache-control");
    assert!(cc.contains("max-age=123"), "{cc}");
    assert!(
        !cc.contains("immutable"),
        "unpinned URL must not be immutable: {cc}"
    );
    // Same request, same ETag.
    assert_eq!(srv.get(tiles).must("etag"), etag);

    // 304 for If-None-Match, also in a list; 200 for a stale one.
    for inm in [etag.clone(), format!("\"stale\", {etag}")] {
        let nm = srv.get_with(tiles, &[("if-none-match", &inm)]);
        assert_eq!(nm.status, 304, "If-None-Match {inm}");
        assert!(nm.body.is_empty());
        assert_eq!(nm.must("etag"), etag);
        assert!(nm.must("cache-control").contains("max-age=123"));
    }
    assert_eq!(
        srv.get_with(tiles, &[("if-none-match", "\"stale\"")])
            .status,
        200
    );

    // Different ranges, levels or endpoints: different ETags.
    let mut seen = BTreeSet::from([etag.clone()]);
    for other in [
        "/v1/datasets/synth/levels/3/tiles?ranges=0-8",
        "/v1/datasets/synth/levels/3/tiles?ranges=1-7",
        "/v1/datasets/synth/levels/3/tiles?ranges=0-3,5-7",
        "/v1/datasets/synth/levels/4/tiles?ranges=0-7",
        "/v1/datasets/synth/levels/3/errors?ranges=0-7",
    ] {
        let e = srv.get(other).expect(200).must("etag").to_string();
        etag_is_strong(&e);
        assert!(seen.insert(e.clone()), "{other} reuses ETag {e}");
        // And the first response's ETag does not revalidate it.
        assert_eq!(
            srv.get_with(other, &[("if-none-match", &etag)]).status,
            200,
            "{other}"
        );
    }

    // Pinned by ?v=<content_hash>: immutable. A wrong v is not pinned.
    let pinned = srv.get(&format!("{tiles}&v={hash}")).expect(200);
    let cc = pinned.must("cache-control");
    assert!(cc.contains("immutable"), "{cc}");
    let wrong = srv.get(&format!("{tiles}&v=0000000000000000")).expect(200);
    let cc = wrong.must("cache-control");
    assert!(
        !cc.contains("immutable") && cc.contains("max-age=123"),
        "{cc}"
    );
    let single = srv
        .get(&format!("/v1/datasets/synth/tiles/2/1/1?v={hash}"))
        .expect(200);
    assert!(single.must("cache-control").contains("immutable"));
    let single = srv.get("/v1/datasets/synth/tiles/2/1/1").expect(200);
    let cc = single.must("cache-control");
    assert!(!cc.contains("immutable") && cc.contains("max-age="), "{cc}");

    // Metadata: ETag and 304.
    let m = srv.get("/v1/datasets/synth").expect(200);
    let metag = m.must("etag").to_string();
    etag_is_strong(&metag);
    assert!(!seen.contains(&metag));
    assert!(m.must("cache-control").contains("max-age="));
    let nm = srv.get_with("/v1/datasets/synth", &[("if-none-match", &metag)]);
    assert_eq!(nm.status, 304);
    assert!(nm.body.is_empty());
}

// ---------------------------------------------------------------------------
// The raw pyramid file with HTTP Range

/// Parses a `multipart/byteranges` body into `(Content-Range, bytes)` parts.
fn multipart_parts(body: &[u8], boundary: &str) -> Vec<(String, Vec<u8>)> {
    let delim = format!("--{boundary}");
    let mut parts = Vec::new();
    let mut rest = body;
    // Skip the preamble up to the first delimiter.
    let start = find(rest, delim.as_bytes()).expect("first boundary");
    rest = &rest[start + delim.len()..];
    loop {
        if rest.starts_with(b"--") {
            break; // closing delimiter
        }
        let rest_after_crlf = rest.strip_prefix(b"\r\n").expect("CRLF after boundary");
        let head_end = find(rest_after_crlf, b"\r\n\r\n").expect("part head");
        let head = std::str::from_utf8(&rest_after_crlf[..head_end]).unwrap();
        let content_range = head
            .split("\r\n")
            .filter_map(|l| l.split_once(':'))
            .find(|(k, _)| k.trim().eq_ignore_ascii_case("content-range"))
            .map(|(_, v)| v.trim().to_string())
            .expect("Content-Range in part");
        let data = &rest_after_crlf[head_end + 4..];
        let next = find(data, format!("\r\n{delim}").as_bytes()).expect("next boundary");
        parts.push((content_range, data[..next].to_vec()));
        rest = &data[next + 2 + delim.len()..];
    }
    parts
}

#[test]
fn pyramid_file_with_http_range() {
    let f = fixtures();
    let file = std::fs::read(&f.synth).unwrap();
    let size = file.len();
    let srv = Server::start(&[&f.synth], &[]);
    let url = "/v1/datasets/synth/pyramid";

    let full = srv.get(url).expect(200);
    assert_eq!(full.body.len(), size);
    assert!(full.body == file, "full GET differs from the file");
    assert_eq!(full.must("accept-ranges"), "bytes");
    assert_eq!(full.must("content-length").parse::<usize>().unwrap(), size);
    let etag = full.must("etag").to_string();
    etag_is_strong(&etag);

    let range = |spec: &str, extra: &[(&str, &str)]| {
        let mut h = vec![("range", spec)];
        h.extend_from_slice(extra);
        srv.get_with(url, &h)
    };
    let check_206 = |r: &Resp, a: usize, b: usize| {
        assert_eq!(r.status, 206, "{}", r.text());
        assert_eq!(r.must("content-range"), format!("bytes {a}-{b}/{size}"));
        assert_eq!(r.body.len(), b - a + 1);
        assert!(r.body == file[a..=b], "bytes {a}-{b} differ");
        assert_eq!(
            r.must("content-length").parse::<usize>().unwrap(),
            b - a + 1
        );
    };
    check_206(&range("bytes=100-199", &[]), 100, 199);
    check_206(&range("bytes=-50", &[]), size - 50, size - 1);
    check_206(
        &range(&format!("bytes={}-", size - 10), &[]),
        size - 10,
        size - 1,
    );
    // An end past the file is clamped.
    check_206(
        &range(&format!("bytes={}-{}", size - 5, size + 100), &[]),
        size - 5,
        size - 1,
    );

    // Multiple ranges: multipart/byteranges with both parts.
    let multi = range("bytes=0-9,20-29", &[]);
    assert_eq!(multi.status, 206, "{}", multi.text());
    let ct = multi.must("content-type");
    assert!(ct.starts_with("multipart/byteranges"), "{ct}");
    let boundary = ct
        .split(';')
        .find_map(|p| p.trim().strip_prefix("boundary="))
        .unwrap_or_else(|| panic!("no boundary in {ct}"))
        .trim_matches('"')
        .to_string();
    let parts = multipart_parts(&multi.body, &boundary);
    assert_eq!(parts.len(), 2, "{parts:?}");
    assert_eq!(parts[0].0, format!("bytes 0-9/{size}"));
    assert_eq!(parts[0].1, file[0..10]);
    assert_eq!(parts[1].0, format!("bytes 20-29/{size}"));
    assert_eq!(parts[1].1, file[20..30]);

    // Unsatisfiable.
    let r = range(&format!("bytes={size}-"), &[]);
    assert_eq!(r.status, 416, "{}", r.text());
    assert_eq!(r.must("content-range"), format!("bytes */{size}"));

    // Revalidation.
    let nm = srv.get_with(url, &[("if-none-match", &etag)]);
    assert_eq!(nm.status, 304);
    assert!(nm.body.is_empty());

    // If-Range: our ETag → the range; another (or a weak one) → the whole file.
    check_206(&range("bytes=100-199", &[("if-range", &etag)]), 100, 199);
    let stale = range("bytes=100-199", &[("if-range", "\"someone-else\"")]);
    assert_eq!(stale.status, 200);
    assert!(
        stale.body == file,
        "If-Range mismatch must send the whole file"
    );
}

// ---------------------------------------------------------------------------
// PNG tiles and TileJSON

/// Decodes an 8-bit RGB PNG into `(width, height, rgb)`.
fn decode_png(bytes: &[u8]) -> (u32, u32, Vec<u8>) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb, "want RGB");
    assert_eq!(info.bit_depth, png::BitDepth::Eight, "want 8-bit");
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

#[test]
fn png_height_tiles_decode_to_the_tile_heights() {
    let f = fixtures();
    let p = open(&f.synth);
    let q = p.metadata().quantization;
    let t = p.geometry().tile_size();
    let srv = Server::start(&[&f.synth], &[]);
    for (z, x, y) in [(0, 0, 0), (2, 1, 3), (4, 15, 0)] {
        let tile = TileId::new(level(z), x, y).unwrap();
        let rec = p.read_tile(tile).unwrap().unwrap();
        let side = t as usize + 1;
        for enc in ["terrarium", "mapbox"] {
            let r = srv
                .get(&format!(
                    "/v1/datasets/synth/{z}/{x}/{y}.png?encoding={enc}"
                ))
                .expect(200);
            assert!(r.must("content-type").starts_with("image/png"));
            let (w, h, rgb) = decode_png(&r.body);
            assert_eq!((w, h), (t, t), "{enc} PNG of {tile} is {w}×{h}");
            let mut worst = 0f64;
            for j in 0..t as usize {
                for i in 0..t as usize {
                    let px = &rgb[(j * t as usize + i) * 3..][..3];
                    let (r8, g8, b8) = (f64::from(px[0]), f64::from(px[1]), f64::from(px[2]));
                    let got = if enc == "mapbox" {
                        -10000.0 + (r8 * 65536.0 + g8 * 256.0 + b8) * 0.1
                    } else {
                        r8 * 256.0 + g8 + b8 / 256.0 - 32768.0
                    };
                    let want = q.height(rec.heights[j * side + i]);
                    worst = worst.max((got - want).abs());
                }
            }
            let tol = if enc == "mapbox" { 0.05 } else { 1.0 / 256.0 } + 1e-9;
            assert!(
                worst <= tol,
                "{enc} {tile}: off by {worst} m (tolerance {tol})"
            );
        }
    }
    let e = srv
        .get("/v1/datasets/synth/0/0/0.png?encoding=jpeg2000")
        .error(400);
    assert!(e.contains("jpeg2000") || e.contains("encoding"), "{e}");
}

/// The `encoding` a TileJSON document declares, after checking that its tile URL
/// template asks for the same one.
fn tilejson_encoding(j: &serde_json::Value) -> String {
    let enc = j["encoding"]
        .as_str()
        .unwrap_or_else(|| panic!("no encoding: {j}"));
    assert!(enc == "terrarium" || enc == "mapbox", "{j}");
    let url = j["tiles"][0]
        .as_str()
        .unwrap_or_else(|| panic!("no tiles: {j}"));
    assert!(url.contains(&format!("encoding={enc}")), "{url} vs {enc}");
    enc.to_string()
}

#[test]
fn tilejson_describes_the_png_tiles() {
    let f = fixtures();
    let p = open(&f.synth);
    let mut files: Vec<&Path> = vec![&f.synth];
    files.extend(f.n44.as_deref());
    files.extend(f.bigtujunga.as_deref());
    let srv = Server::start(&files, &[]);
    for query in ["", "?encoding=terrarium", "?encoding=mapbox"] {
        let j = srv
            .get(&format!("/v1/datasets/synth/tilejson.json{query}"))
            .expect(200)
            .json();
        assert_eq!(j["tilejson"], "3.0.0", "{j}");
        tilejson_encoding(&j);
        // The document describes the encoding asked for (Terrarium by default).
        let want = if query.contains("mapbox") {
            "mapbox"
        } else {
            "terrarium"
        };
        assert_eq!(j["encoding"], want, "{j}");
        assert_eq!(j["tileSize"], p.geometry().tile_size(), "{j}");
        assert_eq!(j["minzoom"], 0, "{j}");
        assert_eq!(j["maxzoom"], p.geometry().finest().get(), "{j}");
        let url = j["tiles"][0].as_str().unwrap();
        assert!(url.contains("/v1/datasets/synth/{z}/{x}/{y}.png"), "{url}");
        assert!(
            j.get("bounds").is_none(),
            "a dataset without georeferencing has no bounds: {j}"
        );
        // The template (server-relative without --public-url) resolves to a PNG
        // tile on this server.
        assert!(url.starts_with("/v1/"), "{url}");
        let path = url
            .replace("{z}", "2")
            .replace("{x}", "1")
            .replace("{y}", "3");
        let png = srv.get(&path).expect(200);
        assert_eq!(decode_png(&png.body).0, p.geometry().tile_size());
    }

    if let Some(path) = f.n44.as_deref() {
        let np = open(path);
        let facts = testdata::facts("N44W072.hgt");
        let j = srv
            .get("/v1/datasets/N44W072/tilejson.json")
            .expect(200)
            .json();
        tilejson_encoding(&j);
        assert_eq!(j["tileSize"], 64, "{j}");
        assert_eq!(j["maxzoom"], np.geometry().finest().get(), "{j}");
        let bounds: Vec<f64> = j["bounds"]
            .as_array()
            .unwrap_or_else(|| panic!("EPSG:4326 dataset needs bounds: {j}"))
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let want = facts.extent.unwrap();
        assert_eq!(bounds.len(), 4);
        for (g, w) in bounds.iter().zip(want) {
            assert!((g - w).abs() < 1e-6, "bounds {bounds:?}, want {want:?}");
        }
    }
    // Projected (UTM) coordinates are not longitudes and latitudes: no bounds.
    if f.bigtujunga.is_some() {
        let j = srv
            .get("/v1/datasets/bigtujunga/tilejson.json")
            .expect(200)
            .json();
        assert!(j.get("bounds").is_none(), "UTM dataset with bounds: {j}");
    }
    assert_eq!(srv.get("/v1/datasets/nope/tilejson.json").status, 404);
}

// ---------------------------------------------------------------------------
// Metrics

#[test]
fn metrics_count_requests_tiles_and_corruption() {
    let f = fixtures();
    let srv = Server::start(&[&f.synth, &f.corrupt], &[]);
    let before = parse_metrics(&srv.get("/metrics").expect(200).text());
    let tiles_before = metric(&before, "tessera_tiles_served_total");

    let frames = decode_stream(&srv.get("/v1/datasets/synth/levels/3/tiles?ranges=0-9,20-24"));
    assert_eq!(frames.len(), 16);
    srv.get("/v1/datasets/synth/tiles/2/0/0").expect(200);
    srv.get("/v1/datasets/synth/tiles/9/0/0").error(404);
    let c = f.corrupt_tile;
    srv.get(&format!(
        "/v1/datasets/synth-corrupt/tiles/{}/{}/{}",
        c.level(),
        c.x(),
        c.y()
    ))
    .error(500);

    let r = srv.get("/metrics").expect(200);
    assert!(r.must("content-type").starts_with("text/plain"));
    let after = parse_metrics(&r.text());
    assert_eq!(
        metric(&after, "tessera_tiles_served_total") - tiles_before,
        16.0,
        "15 tiles in the stream and 1 single tile"
    );
    assert_eq!(metric(&after, "tessera_corrupt_records_total"), 1.0);
    assert_eq!(metric(&after, "tessera_corrupt_record_reads_total"), 1.0);
    let requests: Vec<_> = after
        .iter()
        .filter(|s| s.name == "tessera_http_requests_total")
        .collect();
    let count = |route: &str, status: &str| -> f64 {
        requests
            .iter()
            .filter(|s| {
                s.labels.get("route").map(String::as_str) == Some(route)
                    && s.labels.get("status").map(String::as_str) == Some(status)
            })
            .map(|s| s.value)
            .sum()
    };
    assert_eq!(
        count("/v1/datasets/{name}/levels/{level}/tiles", "200"),
        1.0,
        "{requests:?}"
    );
    assert_eq!(
        count("/v1/datasets/{name}/tiles/{level}/{x}/{y}", "200"),
        1.0
    );
    assert_eq!(
        count("/v1/datasets/{name}/tiles/{level}/{x}/{y}", "404"),
        1.0
    );
    assert_eq!(
        count("/v1/datasets/{name}/tiles/{level}/{x}/{y}", "500"),
        1.0
    );
    // Labels are route templates, never raw paths (bounded cardinality).
    assert!(
        requests
            .iter()
            .all(|s| !s.labels["route"].contains("synth")),
        "{requests:?}"
    );
}

// ---------------------------------------------------------------------------
// Bad input

#[test]
fn bad_requests_get_json_reasons() {
    let f = fixtures();
    let srv = Server::start(
        &[&f.synth],
        &[
            "--max-ranges",
            "4",
            "--max-tiles",
            "16",
            "--max-query-bytes",
            "256",
        ],
    );
    // A wrong method gets a JSON reason and the Allow header, like every other error.
    let r = srv.send(reqwest::Method::POST, "/healthz", &[]);
    assert!(r.error(405).contains("read-only"));
    assert_eq!(r.header("allow"), Some("GET,HEAD"));
    let tiles = "/v1/datasets/synth/levels";
    // (path, status, words the message must contain, case-insensitively)
    let cases: Vec<(String, u16, Vec<&str>)> = vec![
        ("/v1/datasets/atlantis".into(), 404, vec!["atlantis"]),
        (
            "/v1/datasets/atlantis/levels/0/tiles?ranges=0".into(),
            404,
            vec!["atlantis"],
        ),
        (format!("{tiles}/5/tiles?ranges=0"), 404, vec!["level", "5"]),
        (format!("{tiles}/99/tiles?ranges=0"), 404, vec!["level"]),
        (format!("{tiles}/abc/tiles?ranges=0"), 404, vec!["level"]),
        (
            format!("{tiles}/4/tiles?ranges=abc"),
            400,
            vec!["malformed", "abc"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=1-2-3"),
            400,
            vec!["malformed"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=0-3,"),
            400,
            vec!["malformed"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=5-2"),
            400,
            vec!["reversed", "5-2"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=0-5,3-9"),
            400,
            vec!["overlap"],
        ),
        (
            format!("{tiles}/1/tiles?ranges=0-4"),
            400,
            vec!["outside", "0-4"],
        ),
        (format!("{tiles}/4/tiles?ranges=256"), 400, vec!["outside"]),
        (format!("{tiles}/4/tiles"), 400, vec!["missing", "ranges"]),
        (format!("{tiles}/4/tiles?ranges="), 400, vec!["ranges"]),
        (
            format!("{tiles}/4/errors?ranges=0-5,3-9"),
            400,
            vec!["overlap"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=0,2,4,6,8"),
            400,
            vec!["5 ranges", "at most 4"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=0-16"),
            400,
            vec!["17 tiles", "at most 16"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=0-7,10-18"),
            400,
            vec!["at most 16"],
        ),
        (
            format!("{tiles}/4/tiles?ranges=0&pad={}", "x".repeat(300)),
            414,
            vec!["256"],
        ),
        ("/v2/everything".into(), 404, vec!["endpoint"]),
        ("/v1/datasets/synth/levels/4".into(), 404, vec!["endpoint"]),
    ];
    for (path, status, words) in &cases {
        let msg = srv.get(path).error(*status).to_lowercase();
        for w in words {
            assert!(
                msg.contains(&w.to_lowercase()),
                "GET {path}: message {msg:?} does not mention {w:?}"
            );
        }
    }
    // Within the limits is fine.
    decode_stream(&srv.get(&format!("{tiles}/4/tiles?ranges=0,2,4,6-18")));

    // Path traversal: never a 200, never a file's contents, always a JSON reason.
    for path in [
        "/v1/datasets/..%2F..%2Fetc/levels/0/tiles?ranges=0",
        "/v1/datasets/..%2F..%2F..%2F..%2Fetc%2Fpasswd",
        "/v1/datasets/%2e%2e/pyramid",
        "/v1/datasets/.hidden",
        "/v1/datasets/.hidden/tiles/0/0/0",
        "/v1/datasets/synth%2F..%2Fsynth/tiles/0/0/0",
    ] {
        let r = srv.get(path);
        assert!(
            r.status == 400 || r.status == 404,
            "GET {path}: {} {}",
            r.status,
            r.text()
        );
        r.json_error();
        assert!(!r.text().contains("root:"), "GET {path} leaked a file");
    }
    // Raw targets a client library would normalise away.
    for target in [
        "/v1/datasets/../../../../etc/passwd",
        "/v1/datasets/synth/../../../etc/passwd",
        "/v1/datasets/%2e%2e/%2e%2e/%2e%2e/etc/passwd",
    ] {
        let r = raw_get(srv.addr, target);
        assert!(
            (400..500).contains(&r.status),
            "GET {target}: {} {}",
            r.status,
            String::from_utf8_lossy(&r.body)
        );
        assert!(!String::from_utf8_lossy(&r.body).contains("root:"));
        assert!(
            r.headers
                .get("content-type")
                .is_some_and(|c| c.starts_with("application/json")),
            "GET {target}: {:?}",
            r.headers
        );
    }
    // The server is still healthy after all that.
    srv.get("/healthz").expect(200);
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

// ---------------------------------------------------------------------------
// Graceful shutdown

/// Whether a fresh connection gets an HTTP response (`false`: refused, reset,
/// closed or silent).
fn served(addr: std::net::SocketAddr) -> bool {
    let Ok(mut s) = TcpStream::connect_timeout(&addr, Duration::from_secs(2)) else {
        return false;
    };
    s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
    if write!(
        s,
        "GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
    )
    .is_err()
    {
        return false;
    }
    let mut buf = [0u8; 12];
    matches!(s.read(&mut buf), Ok(n) if n > 0)
}

#[test]
fn sigterm_finishes_in_flight_responses_then_exits() {
    let f = fixtures();
    let mut srv = Server::start(&[&f.synth4k], &[]);
    let p = open(&f.synth4k);
    let finest = p.geometry().finest();
    let slots = finest.tile_slots();

    let mut s = TcpStream::connect(srv.addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    write!(
        s,
        "GET /v1/datasets/synth4k/levels/{finest}/tiles?ranges=0-{} HTTP/1.1\r\nHost: x\r\n\r\n",
        slots - 1
    )
    .unwrap();
    // Read the head and a few body bytes only: the rest (~20 MB) is still in flight.
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    let head_end = loop {
        let n = s.read(&mut buf).unwrap();
        assert!(n > 0, "connection closed before the head");
        got.extend_from_slice(&buf[..n]);
        if let Some(e) = find(&got, b"\r\n\r\n")
            && got.len() > e + 4
        {
            break e;
        }
    };
    let (status, headers) = parse_head(std::str::from_utf8(&got[..head_end]).unwrap());
    assert_eq!(status, 200);
    let len: usize = headers["content-length"].parse().unwrap();
    let mut body = got[head_end + 4..].to_vec();
    assert!(
        len > 8 << 20,
        "fixture: body of {len} bytes is too small to be in flight"
    );

    srv.terminate();

    // New connections are refused or left unanswered once the signal is handled
    // (one accepted before that may still be served: retry within a deadline).
    let deadline = Instant::now() + Duration::from_secs(15);
    while served(srv.addr) {
        assert!(
            Instant::now() < deadline,
            "new connections still served long after SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(50));
    }

    // The server waits for the unfinished response (~20 MB, far more than socket
    // buffers hold while we do not read) rather than exiting under it.
    assert!(
        srv.try_wait().is_none(),
        "server exited with a response still in flight"
    );

    // The in-flight response completes.
    while body.len() < len {
        let n = s.read(&mut buf).unwrap();
        assert!(n > 0, "response cut off at {} of {len} bytes", body.len());
        body.extend_from_slice(&buf[..n]);
    }
    assert_eq!(body.len(), len);
    let frames = wire::decode_all(&body).unwrap();
    let (tiles_frames, tiles, errors, _) = split_trailer(&frames);
    assert_eq!(tiles, slots);
    assert_eq!(errors, 0);
    assert_eq!(tiles_frames.len() as u64, slots);

    let status = srv.wait_exit(Duration::from_secs(20));
    assert!(status.success(), "server exited with {status}");
}

// ---------------------------------------------------------------------------
// Configuration

#[test]
fn config_file_env_and_flags() {
    let f: &Fixtures = fixtures();
    let toml_path = f.dir.join("serve-config.toml");
    std::fs::write(
        &toml_path,
        format!(
            "datasets = [{:?}]\nmax_ranges = 2\nmax_tiles = 4\n",
            f.synth.to_str().unwrap()
        ),
    )
    .unwrap();
    let cfg = toml_path.to_str().unwrap();
    let lvl = "/v1/datasets/synth/levels/4/tiles";

    // TOML alone: datasets and limits from the file.
    let srv = Server::start(&[], &["--config", cfg]);
    let list = srv.get("/v1/datasets").expect(200).json();
    assert_eq!(list["datasets"][0]["name"], "synth", "{list}");
    assert_eq!(list["datasets"].as_array().unwrap().len(), 1);
    let e = srv.get(&format!("{lvl}?ranges=0,2,4")).error(400);
    assert!(e.contains("at most 2"), "{e}");
    decode_stream(&srv.get(&format!("{lvl}?ranges=0,2")));
    let e = srv.get(&format!("{lvl}?ranges=0-4")).error(400);
    assert!(e.contains("at most 4"), "{e}");
    drop(srv);

    // The environment beats the file.
    let srv = Server::start_with(&[], &["--config", cfg], &[("TESSERA_MAX_TILES", "8")]);
    decode_stream(&srv.get(&format!("{lvl}?ranges=0-7")));
    let e = srv.get(&format!("{lvl}?ranges=0-8")).error(400);
    assert!(e.contains("at most 8"), "{e}");
    drop(srv);

    // TESSERA_* alone, and a flag beating it.
    let srv = Server::start_with(&[&f.synth], &[], &[("TESSERA_MAX_TILES", "8")]);
    let e = srv.get(&format!("{lvl}?ranges=0-8")).error(400);
    assert!(e.contains("at most 8"), "{e}");
    drop(srv);
    let srv = Server::start_with(
        &[&f.synth],
        &["--max-tiles", "32"],
        &[("TESSERA_MAX_TILES", "8")],
    );
    decode_stream(&srv.get(&format!("{lvl}?ranges=0-31")));
    let e = srv.get(&format!("{lvl}?ranges=0-32")).error(400);
    assert!(e.contains("at most 32"), "{e}");
    drop(srv);

    // A flag's dataset list replaces the file's.
    let srv = Server::start(&[&f.corrupt], &["--config", cfg]);
    let list = srv.get("/v1/datasets").expect(200).json();
    assert_eq!(list["datasets"].as_array().unwrap().len(), 1, "{list}");
    assert_eq!(list["datasets"][0]["name"], "synth-corrupt", "{list}");
}
