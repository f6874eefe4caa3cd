//! Fixtures of the `streaming*` and `imagery_*` tests: the test pyramid (built once
//! per test binary), the Olinda DEM with its Landsat imagery, a real server on a
//! runtime of the test's choosing, the flight options and paths
//! the tests fly, and invariant 5 (no holes once the root has arrived).

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Duration;
use tessera_client::app::fly::{FlyOptions, FrameRecord, fly};
use tessera_client::stream::{OpenArgs, StreamConfig, TileSource};
use tessera_server::builder::{BuildOptions, build};
use tessera_server::serve::config::Settings;

/// The test pyramid: a synthetic 4097² terrain in 128-cell tiles, named `terrain`.
pub fn pyramid() -> &'static Path {
    static P: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &P.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("terrain.tess");
        let opts = BuildOptions {
            tile_size: 128,
            ..BuildOptions::default()
        };
        build("synthetic:4097:11", &out, &opts).unwrap();
        (dir, out)
    })
    .1
}

/// A server on `addr` (port 0 for any) in the background of `rt`; returns its address
/// and a handle that kills it (abruptly: connections drop) when aborted.
pub fn start_server(
    rt: &tokio::runtime::Runtime,
    addr: SocketAddr,
) -> (SocketAddr, tokio::task::JoinHandle<()>) {
    start_server_for(rt, addr, pyramid())
}

/// [`start_server`] serving `dataset` (named after its file stem).
pub fn start_server_for(
    rt: &tokio::runtime::Runtime,
    addr: SocketAddr,
    dataset: &Path,
) -> (SocketAddr, tokio::task::JoinHandle<()>) {
    let settings = Settings {
        listen: addr,
        datasets: vec![dataset.to_path_buf()],
        ..Settings::default()
    };
    let state = tessera_server::serve::state(&settings).unwrap();
    let listener = rt.block_on(tokio::net::TcpListener::bind(addr)).unwrap();
    let bound = listener.local_addr().unwrap();
    let task = rt.spawn(async move {
        let _ =
            tessera_server::serve::serve_until(listener, state, &settings, std::future::pending())
                .await;
    });
    (bound, task)
}

/// A server for the Olinda pyramid `out` ([`olinda_with_imagery`]) on `rt`: its base
/// URL, an HTTP client set up as the imagery feed's, and the dataset's document as
/// that client reads it.
pub fn serve_olinda(
    rt: &tokio::runtime::Runtime,
    out: &Path,
) -> (String, reqwest::Client, tessera_shared::api::DatasetInfo) {
    let addr = start_server_for(rt, SocketAddr::from(([127, 0, 0, 1], 0)), out).0;
    let base = format!("http://{addr}");
    let client =
        tessera_client::stream::imagery_tiles::http_client(Duration::from_secs(30)).unwrap();
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
    (base, client, serde_json::from_slice(&doc).unwrap())
}

/// The Olinda DEM (64-cell tiles, EPSG:31985) built in `dir` with its Landsat
/// imagery (bands 3, 2, 1) beside it: the `.tess` path; `None` when the data is
/// not there (`testdata::imagery_or_skip` says so).
pub fn olinda_with_imagery(dir: &Path) -> Option<PathBuf> {
    let dem = tessera_shared::testdata::imagery_or_skip("olinda_dem_utm25s.tif")?;
    let image = tessera_shared::testdata::imagery_or_skip("L7_ETMs.tif")?;
    let out = dir.join("olinda.tess");
    let opts = BuildOptions {
        tile_size: 64,
        crs: Some("EPSG:31985".into()),
        progress: false,
        ..BuildOptions::default()
    };
    build(dem.to_str().unwrap(), &out, &opts).unwrap();
    let prepared = tessera_server::imagery::Prepared::open(&image, Some("3,2,1")).unwrap();
    tessera_server::imagery::build_beside(&prepared, &out, &opts.interrupt).unwrap();
    Some(out)
}

/// A path JSON file: a short, slow glide that ends still, so the view can settle.
pub fn glide(dir: &Path) -> String {
    let p = dir.join("glide.json");
    std::fs::write(
        &p,
        r#"{"waypoints": [[0.3, 0.3], [0.45, 0.4]], "speed_mps": 2000, "altitude_agl_m": 400, "pitch_deg": -20}"#,
    )
    .unwrap();
    p.to_string_lossy().into_owned()
}

pub fn options(server: SocketAddr, path: String, frames: u32) -> FlyOptions {
    FlyOptions {
        source: TileSource::server(format!("http://{server}"), "terrain"),
        path,
        frames,
        fps: 60.0,
        tau: 2.0,
        policy: tessera_client::select::Policy::ScreenError,
        morph_seconds: tessera_client::select::MORPH_SECONDS,
        morph_by_distance: false,
        morph_error_limit: tessera_client::select::MORPH_ERROR_LIMIT,
        width: 960,
        height: 540,
        spacing: Some(30.0),
        prefetch: true,
        pool_tiles: 512,
        stream: StreamConfig {
            retry_base: Duration::from_millis(50),
            retry_max: Duration::from_millis(400),
            request_timeout: Duration::from_secs(5),
            ..StreamConfig::default()
        },
        t_offset: 0.0,
        runtime: None,
        progress: None,
        render: None,
        globe: tessera_client::globe::GlobeMode::Off,
    }
}

pub fn run_flight(opts: &FlyOptions) -> (Vec<FrameRecord>, tessera_client::app::fly::FlySummary) {
    let mut buf = Vec::new();
    let summary = fly(opts, Some(&mut buf)).unwrap();
    let frames = String::from_utf8(buf)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<FrameRecord>(l).unwrap())
        .collect();
    (frames, summary)
}

/// Invariant 5: once the root is resident, every frame draws something for the view
/// (an ancestor at least), never a hole.
pub fn assert_no_holes(frames: &[FrameRecord]) -> usize {
    let first = frames
        .iter()
        .position(|f| f.select.tiles > 0)
        .expect("the root never arrived");
    for f in &frames[first..] {
        assert!(
            f.select.tiles > 0 && f.select.patches > 0,
            "frame {} draws nothing",
            f.frame
        );
    }
    first
}

/// After an outage: no holes, the outage noticed, and the last frame back within τ
/// with nothing left to fetch.
pub fn assert_recovered(frames: &[FrameRecord], summary: &tessera_client::app::fly::FlySummary) {
    assert_no_holes(frames);
    assert!(summary.stream.failures > 0, "the outage was not noticed");
    let last = frames.last().unwrap();
    assert!(
        last.select.deficit.is_some_and(|d| d <= 1.0),
        "no recovery after the restart: deficit {:?}",
        last.select.deficit
    );
    assert_eq!(last.wanted, 0);
}

/// `tessera load` from `source` with the small settings the streaming tests share
/// (640×360 at 30 fps, τ = 2 px, 30 m spacing, no progress line).
pub fn small_load(
    source: TileSource,
    clients: u32,
    duration: Duration,
    mode: tessera_client::stream::RequestMode,
) -> tessera_client::app::load_test::LoadReport {
    small_load_opened(source, clients, duration, mode, OpenArgs::default())
}

/// [`small_load`] with the clients opening their source as `open` says.
pub fn small_load_opened(
    source: TileSource,
    clients: u32,
    duration: Duration,
    mode: tessera_client::stream::RequestMode,
    open: OpenArgs,
) -> tessera_client::app::load_test::LoadReport {
    tessera_client::app::load_test::load(&tessera_client::app::load_test::LoadOptions {
        source,
        clients,
        duration,
        mode,
        fps: 30.0,
        tau: 2.0,
        width: 640,
        height: 360,
        spacing: Some(30.0),
        progress: false,
        open,
        record: None,
    })
    .unwrap()
}
