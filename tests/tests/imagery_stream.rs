//! Issue 17 item 5, the client side as far as it goes: the client's imagery fetch
//! (`tessera_client::stream::imagery`) against a real server (in process, real
//! sockets) serving the real Olinda DEM with its Landsat imagery. Every tile the DEM
//! has comes back decoded, exactly the texels of the file's own record, and nothing
//! for tiles the DEM lacks.

#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed test

use std::net::SocketAddr;
use tessera_client::stream::imagery::{self, ImageryPool};
use tessera_server::build::{BuildOptions, build};
use tessera_shared::api::DatasetInfo;
use tessera_shared::{FileSource, Pyramid, testdata};

/// A real server on an ephemeral port of `rt`, serving `dataset`.
fn start_server(rt: &tokio::runtime::Runtime, dataset: &std::path::Path) -> SocketAddr {
    let settings = tessera_server::serve::config::Settings {
        listen: SocketAddr::from(([127, 0, 0, 1], 0)),
        datasets: vec![dataset.to_path_buf()],
        ..tessera_server::serve::config::Settings::default()
    };
    let state = tessera_server::serve::state(&settings).unwrap();
    let listener = rt
        .block_on(tokio::net::TcpListener::bind(settings.listen))
        .unwrap();
    let bound = listener.local_addr().unwrap();
    rt.spawn(async move {
        let _ =
            tessera_server::serve::serve_until(listener, state, &settings, std::future::pending())
                .await;
    });
    bound
}

#[test]
fn the_client_fetches_and_decodes_the_imagery_of_every_tile() {
    let (Some(dem), Some(image)) = (
        testdata::imagery_or_skip("olinda_dem_utm25s.tif"),
        testdata::imagery_or_skip("L7_ETMs.tif"),
    ) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("olinda.tess");
    let opts = BuildOptions {
        tile_size: 64,
        crs: Some("EPSG:31985".into()),
        progress: false,
        ..BuildOptions::default()
    };
    build(dem.to_str().unwrap(), &out, &opts).unwrap();
    let prepared = tessera_server::imagery::Prepared::open(&image, Some("3,2,1")).unwrap();
    tessera_server::imagery::build_beside(&prepared, &out, &opts.interrupt).unwrap();
    let file =
        Pyramid::open_imagery(FileSource::open(&out.with_extension("tessimg")).unwrap()).unwrap();

    let rt = tokio::runtime::Runtime::new().unwrap();
    let addr = start_server(&rt, &out);
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
