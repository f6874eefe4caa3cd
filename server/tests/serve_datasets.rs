//! `tessera-server serve` end to end, the dataset list and metadata: `/healthz`,
//! `/v1/datasets` and `/v1/datasets/{name}` against the files, and the caching
//! headers (ETags, 304s, `Cache-Control`) of every endpoint (API.md).
//!
//! Pyramids are shared by every test (`serve_support`); every test starts its own
//! server on an ephemeral port (killed when the test ends) and checks responses
//! against the pyramid file read independently with the shared reader.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{Server, etag_is_strong, fixtures, open};
use std::collections::BTreeSet;
use std::path::Path;

/// A JSON number equal to `want` (up to decimal round-tripping).
fn approx(v: &serde_json::Value, want: f64) {
    let got = v.as_f64().unwrap_or_else(|| panic!("{v} is not a number"));
    assert!(
        (got - want).abs() <= 1e-12 * want.abs().max(1.0),
        "{got} != {want}"
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
