//! `serve` with imagery (DECISIONS.md "Imagery pyramids"): `NAME.tessimg` beside
//! `NAME.tess` is served as `/v1/datasets/NAME/imagery/levels/{level}/tiles?ranges=…`,
//! framed as the height stream, its records byte for byte the file's; the dataset
//! document says so; ETags come from the imagery's own content hash; a dataset without
//! imagery (or with a stale one, built for another DEM) answers 404. Real Olinda data.

#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{Server, bin, decode_stream, etag_is_strong, split_trailer};
use std::path::Path;
use tessera_shared::wire::Frame;
use tessera_shared::{FileSource, Pyramid, TileId, testdata};

fn build(out: &Path, crs: &str, extra: &[&str]) -> bool {
    let Some(dem) = testdata::imagery_or_skip("olinda_dem_utm25s.tif") else {
        return false;
    };
    let o = bin()
        .arg("build")
        .arg(dem)
        .args(["--tile-size", "64", "--quiet", "--crs", crs, "-o"])
        .arg(out)
        .args(extra)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    true
}

fn build_with_imagery(out: &Path, crs: &str) -> bool {
    let Some(image) = testdata::imagery_or_skip("L7_ETMs.tif") else {
        return false;
    };
    build(
        out,
        crs,
        &["--imagery", image.to_str().unwrap(), "--bands", "3,2,1"],
    )
}

#[test]
fn imagery_records_over_http_are_the_files() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("olinda.tess");
    if !build_with_imagery(&out, "EPSG:31985") {
        return;
    }
    let img =
        Pyramid::open_imagery(FileSource::open(&out.with_extension("tessimg")).unwrap()).unwrap();
    let meta = img.imagery().unwrap();
    let srv = Server::start(&[&out], &[]);

    let doc = srv.get("/v1/datasets/olinda").expect(200).json();
    let i = &doc["imagery"];
    assert_eq!(i["texels"], 256);
    assert_eq!(i["media_type"], "image/jpeg");
    assert_eq!(i["content_hash"], meta.content_hash.as_str());
    assert_eq!(i["bands"], serde_json::json!([3, 2, 1]));
    assert!((i["texel_size"][0].as_f64().unwrap() - 89.994 / 4.0).abs() < 0.01);
    let template = i["tiles"].as_str().unwrap();

    let g = *img.geometry();
    for level in g.levels() {
        let last = level.tile_slots() - 1;
        let path = template
            .replace("{level}", &level.to_string())
            .replace("{ranges}", &format!("0-{last}"));
        let r = srv.get(&path);
        let frames = decode_stream(&r);
        let (body, tiles, errors, _) = split_trailer(&frames);
        assert_eq!(errors, 0);
        let mut got = Vec::new();
        for f in body {
            let Frame::Tile {
                level: l,
                morton,
                checksum,
                record,
                ..
            } = f
            else {
                panic!("unexpected frame {f:?}");
            };
            assert_eq!(*l, level);
            let tile = TileId::from_morton(level, *morton).unwrap();
            assert_eq!(*checksum, img.entry(tile).unwrap().checksum, "{tile}");
            assert_eq!(
                record,
                &img.read_record(tile).unwrap().unwrap(),
                "{tile}: record differs from the file"
            );
            // And it is the JPEG the metadata describes.
            let jpeg =
                image::load_from_memory_with_format(record, image::ImageFormat::Jpeg).unwrap();
            assert_eq!((jpeg.width(), jpeg.height()), (256, 256));
            got.push(tile);
        }
        let want: Vec<TileId> = g
            .present_tiles(level)
            .filter(|t| img.entry(*t).is_some())
            .collect();
        assert_eq!(got, want, "level {level}");
        assert_eq!(tiles, want.len() as u64);

        // Cached as the height stream is, under the imagery's own content hash.
        let etag = r.must("etag").to_string();
        etag_is_strong(&etag);
        assert!(etag.contains(&meta.content_hash), "{etag}");
        let heights = srv.get(&format!(
            "/v1/datasets/olinda/levels/{level}/tiles?ranges=0-{last}"
        ));
        assert_ne!(heights.must("etag"), etag);
        srv.get_with(&path, &[("if-none-match", &etag)]).expect(304);
    }
    // Bad requests are the height stream's: a level beyond the pyramid is a 404.
    let e = srv
        .get("/v1/datasets/olinda/imagery/levels/9/tiles?ranges=0")
        .error(404);
    assert!(e.contains("level"), "{e}");
}

#[test]
fn no_imagery_or_imagery_of_another_dem_is_not_served() {
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("plain.tess");
    let other = dir.path().join("other.tess");
    // `other` gets the imagery of a DEM of other metadata (its CRS written another
    // way, so another content hash) beside it: the same ground, the wrong DEM.
    let donor = dir.path().join("donor.tess");
    let utm = "+proj=utm +zone=25 +south +ellps=GRS80 +units=m +no_defs";
    if !build(&plain, "EPSG:31985", &[])
        || !build(&other, "EPSG:31985", &[])
        || !build_with_imagery(&donor, utm)
    {
        return;
    }
    std::fs::copy(
        donor.with_extension("tessimg"),
        other.with_extension("tessimg"),
    )
    .unwrap();
    let srv = Server::start(&[&plain, &other], &[]);
    for name in ["plain", "other"] {
        let doc = srv.get(&format!("/v1/datasets/{name}")).expect(200).json();
        assert!(doc.get("imagery").is_none(), "{name}: {doc}");
        let e = srv
            .get(&format!(
                "/v1/datasets/{name}/imagery/levels/0/tiles?ranges=0"
            ))
            .error(404);
        assert!(e.contains("no imagery"), "{name}: {e}");
    }
}

/// A pyramid in object storage serves the imagery object beside it
/// (`s3://…/olinda.tessimg`) exactly as a local one does, and one without (or with
/// a stale one, built for another DEM) serves none. A real S3 server on loopback.
#[test]
fn imagery_beside_a_pyramid_in_object_storage_is_served_like_a_local_ones() {
    use tessera_shared::s3_server::S3Server;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("olinda.tess");
    let plain = dir.path().join("plain.tess");
    // Imagery of the same ground built for a DEM of other metadata (its CRS written
    // another way, so another content hash): stale beside `plain`.
    let donor = dir.path().join("donor.tess");
    let utm = "+proj=utm +zone=25 +south +ellps=GRS80 +units=m +no_defs";
    if !build_with_imagery(&out, "EPSG:31985")
        || !build(&plain, "EPSG:31985", &[])
        || !build_with_imagery(&donor, utm)
    {
        return;
    }
    let Some(s3) = S3Server::start_or_skip() else {
        return;
    };
    s3.create_bucket("tessera");
    let read = |p: &Path| std::fs::read(p).unwrap();
    s3.put("tessera", "olinda.tess", &read(&out));
    s3.put(
        "tessera",
        "olinda.tessimg",
        &read(&out.with_extension("tessimg")),
    );
    // `plain` has no imagery of its own, and gets the donor's beside it.
    s3.put("tessera", "plain.tess", &read(&plain));
    s3.put(
        "tessera",
        "plain.tessimg",
        &read(&donor.with_extension("tessimg")),
    );
    let env = s3.env();
    let env: Vec<(&str, &str)> = env.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
    let remote = Server::start_with(
        &[
            Path::new("s3://tessera/olinda.tess"),
            Path::new("s3://tessera/plain.tess"),
        ],
        &[],
        &env,
    );
    let local = Server::start(&[&out], &[]);

    let doc = remote.get("/v1/datasets/olinda").expect(200).json();
    let want = local.get("/v1/datasets/olinda").expect(200).json();
    assert_eq!(
        doc["imagery"]["content_hash"],
        want["imagery"]["content_hash"]
    );
    let img =
        Pyramid::open_imagery(FileSource::open(&out.with_extension("tessimg")).unwrap()).unwrap();
    for level in img.geometry().levels() {
        let path = format!(
            "/v1/datasets/olinda/imagery/levels/{level}/tiles?ranges=0-{}",
            level.tile_slots() - 1
        );
        let (a, b) = (remote.get(&path).expect(200), local.get(&path).expect(200));
        assert_eq!(a.body, b.body, "{path}: S3 and the local file differ");
        assert_eq!(a.header("etag"), b.header("etag"), "{path}");
        assert!(!split_trailer(&decode_stream(&a)).0.is_empty(), "{path}");
    }
    let doc = remote.get("/v1/datasets/plain").expect(200).json();
    assert!(doc.get("imagery").is_none(), "{doc}");
    remote
        .get("/v1/datasets/plain/imagery/levels/0/tiles?ranges=0")
        .error(404);
}
