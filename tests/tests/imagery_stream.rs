//! Issue 17 item 5, the client side as far as it goes: the client's imagery fetch
//! (`tessera_client::stream::imagery`) against a real server (in process, real
//! sockets) serving the real Olinda DEM with its Landsat imagery. Every tile the DEM
//! has comes back decoded, exactly the texels of the file's own record, and nothing
//! for tiles the DEM lacks.

#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed test

use std::net::SocketAddr;
use tessera_client::stream::imagery::{self, ImageryPool};
use tessera_shared::api::DatasetInfo;
use tessera_shared::{FileSource, Pyramid};

#[allow(dead_code)] // each test binary uses some of the shared fixtures
mod streaming_support;
use streaming_support::{olinda_with_imagery, start_server_for};

#[test]
fn the_client_fetches_and_decodes_the_imagery_of_every_tile() {
    let dir = tempfile::tempdir().unwrap();
    let Some(out) = olinda_with_imagery(dir.path()) else {
        return;
    };
    let file =
        Pyramid::open_imagery(FileSource::open(&out.with_extension("tessimg")).unwrap()).unwrap();

    let rt = tokio::runtime::Runtime::new().unwrap();
    let addr = start_server_for(&rt, SocketAddr::from(([127, 0, 0, 1], 0)), &out).0;
    let base = format!("http://{addr}");
    let client = imagery::http_client(std::time::Duration::from_secs(30)).unwrap();
    let doc = rt
        .block_on(async {
            client
                .get(format!("{base}/v1/datasets/olinda"))
                .send()
                .await?
                .bytes()
                .await
        })
        .unwrap();
    let info: DatasetInfo = serde_json::from_slice(&doc).unwrap();
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
