//! Imagery pyramids (DECISIONS.md "Imagery pyramids"), the client side as far as it goes:
//! the client's imagery fetch (`tessera_client::stream::imagery_tiles`) against a real server
//! (in process, real sockets) serving the real Olinda DEM with its Landsat imagery. Every
//! tile the DEM has comes back decoded, exactly the texels of the file's own record, and
//! nothing for tiles the DEM lacks.

#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed test

use tessera_client::stream::imagery_tiles::{self as imagery, ImageryPool};
use tessera_shared::{FileSource, Pyramid};

#[allow(dead_code)] // each test binary uses some of the shared fixtures
mod streaming_support;
use streaming_support::{olinda_with_imagery, serve_olinda};

#[test]
fn the_client_fetches_and_decodes_the_imagery_of_every_tile() {
    let dir = tempfile::tempdir().unwrap();
    let Some(out) = olinda_with_imagery(dir.path()) else {
        return;
    };
    let file =
        Pyramid::open_imagery(FileSource::open(&out.with_extension("tessimg")).unwrap()).unwrap();

    let rt = tokio::runtime::Runtime::new().unwrap();
    let (base, client, info) = serve_olinda(&rt, &out);
    let im = info.imagery.expect("the document names the imagery");
    assert_eq!(im.texels, 256);

    // Every slot of every level: the geometry's tiles, as a flight would ask for them.
    let g = *file.geometry();
    let all: Vec<_> = g
        .levels()
        .flat_map(|l| g.present_tiles(l).collect::<Vec<_>>())
        .collect();
    let mut pool = ImageryPool::new(64);
    for (level, ranges) in imagery::ranges_by_level(&pool.missing(&all)) {
        for (tile, texels) in rt
            .block_on(imagery::fetch(&client, &base, &im, level, &ranges))
            .unwrap()
        {
            pool.insert(tile, texels);
        }
    }
    for tile in &all {
        match file.read_record(*tile).unwrap() {
            Some(record) => {
                let want = imagery::decode(&record, 256).unwrap();
                assert_eq!(pool.get(*tile), Some(&want), "{tile}");
            }
            None => assert!(pool.get(*tile).is_none(), "{tile} has no record"),
        }
    }
    assert_eq!(pool.len(), 5);
    assert!(pool.missing(&all).iter().all(|t| file.entry(*t).is_none()));
}

/// Serverless reads (no Tessera server): a pyramid file read from a static host
/// (nginx, HTTP Range) or `file://` brings the `.tessimg` beside it, read with Range
/// requests too, decoded to exactly the file's own records; one built for another
/// DEM beside a pyramid is not used, and a pyramid with none beside it has none.
#[test]
fn a_pyramid_read_serverlessly_brings_the_imagery_beside_it() {
    use tessera_client::stream::{StreamConfig, Streamer, TileSource};
    let dir = tempfile::tempdir().unwrap();
    let Some(out) = olinda_with_imagery(dir.path()) else {
        return;
    };
    let file =
        Pyramid::open_imagery(FileSource::open(&out.with_extension("tessimg")).unwrap()).unwrap();
    let g = *file.geometry();
    let all: Vec<_> = g
        .levels()
        .flat_map(|l| g.present_tiles(l).collect::<Vec<_>>())
        .collect();
    // Another DEM (the moon) with olinda's imagery beside it, and a bare copy.
    std::fs::copy(streaming_support::pyramid(), dir.path().join("moon.tess")).unwrap();
    std::fs::copy(
        out.with_extension("tessimg"),
        dir.path().join("moon.tessimg"),
    )
    .unwrap();
    std::fs::copy(streaming_support::pyramid(), dir.path().join("bare.tess")).unwrap();

    let rt = tokio::runtime::Runtime::new().unwrap();
    let nginx = tessera_e2e::nginx::Nginx::serve(dir.path());
    let mut urls = vec![format!("file://{}", out.display())];
    urls.extend(nginx.as_ref().map(|n| n.url("olinda.tess")));
    let open = |url: &str| {
        Streamer::open(
            &TileSource::pyramid(url.to_string()),
            StreamConfig::default(),
            Some(rt.handle().clone()),
        )
        .unwrap()
        .0
    };
    for url in &urls {
        let streamer = open(url);
        let mut feed = streamer
            .imagery_feed(16)
            .unwrap_or_else(|| panic!("{url}: no imagery beside it"));
        assert_eq!(feed.texels(), 256, "{url}");
        assert!(
            feed.settle(&all, std::time::Duration::from_secs(60)),
            "{url}"
        );
        assert!(feed.last_error.is_none(), "{url}: {:?}", feed.last_error);
        for tile in &all {
            match file.read_record(*tile).unwrap() {
                Some(record) => {
                    let want = imagery::decode(&record, 256).unwrap();
                    assert_eq!(feed.pool().get(*tile), Some(&want), "{url}: {tile}");
                }
                None => assert!(feed.pool().get(*tile).is_none(), "{url}: {tile}"),
            }
        }
        // Every tile at once: one request per level (its records are contiguous).
        assert_eq!(feed.requests as usize, g.levels().count(), "{url}");
    }
    if let Some(nginx) = &nginx {
        // The imagery file was read with Range requests only, each answered 206.
        let reads: Vec<_> = nginx
            .log()
            .into_iter()
            .filter(|l| l.uri == "/olinda.tessimg")
            .collect();
        assert!(reads.len() >= 2, "header and records: {reads:?}");
        assert!(
            reads.iter().all(|l| l.range.is_some() && l.status == 206),
            "{reads:?}"
        );
    }
    let base = format!("file://{}", dir.path().display());
    for name in ["moon", "bare"] {
        let streamer = open(&format!("{base}/{name}.tess"));
        assert!(
            streamer.imagery_feed(16).is_none(),
            "{name}: imagery that is not this DEM's, or none, is not used"
        );
    }
}
