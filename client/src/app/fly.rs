//! `tessera fly --no-render`: selection and streaming along a path at a fixed frame
//! rate, in real time against a real server (or a pyramid file on a static host,
//! `--pyramid`), writing per-frame statistics.

use super::frame_drawer::{FrameDrawer, RenderRecord, RenderSummary};
use super::settle::{SETTLE_TIMEOUT, fetch_tiles};
use crate::paths::{FlyPath, pose_camera};
use crate::select::{FrameStats, SelectParams, Selector, World};
use crate::stream::pool::TilePool;
use crate::stream::{FrameWork, StreamConfig, StreamStats, Streamer, TileSource};
use anyhow::Context;
use std::io::Write;
use std::path::Path;
use std::time::{Duration, Instant};

#[derive(Clone, Debug)]
pub struct FlyOptions {
    /// A dataset on a Tessera server (`--server URL --dataset NAME`), or a pyramid
    /// file read with HTTP Range from any static host (`--pyramid URL`).
    pub source: TileSource,
    pub path: String,
    pub frames: u32,
    pub fps: f64,
    pub tau: f64,
    /// Screen-space error (the default) or distance only.
    pub policy: crate::select::Policy,
    /// Seconds of flight time a geomorph transition takes
    /// ([`SelectParams::morph_seconds`]; `--morph-seconds`).
    pub morph_seconds: f64,
    /// Geomorphing across a band of distance too ([`SelectParams::morph_by_distance`];
    /// `--morph-by-distance`).
    pub morph_by_distance: bool,
    /// [`SelectParams::morph_error_limit`] (`--morph-error-limit`).
    pub morph_error_limit: f64,
    pub width: u32,
    pub height: u32,
    /// Metres between samples on both axes (`--spacing`); default the dataset's
    /// `ground_spacing` (east–west and north–south), else 100.
    pub spacing: Option<f64>,
    pub prefetch: bool,
    pub pool_tiles: usize,
    pub stream: StreamConfig,
    /// Seconds into the path at the first frame (the load generator staggers clients).
    pub t_offset: f64,
    /// Run fetches on this runtime instead of one of the flight's own.
    pub runtime: Option<tokio::runtime::Handle>,
    /// Tiles received so far, shared with a progress display.
    pub progress: Option<std::sync::Arc<std::sync::atomic::AtomicU64>>,
    /// Render headless (`--out`); `None` for selection and streaming only.
    #[cfg(feature = "render")]
    pub render: Option<super::headless::RenderSetup>,
    /// Draw on the globe (`--globe`, DECISIONS.md "The globe").
    pub globe: crate::globe::GlobeMode,
}

/// One line of `--stats` (JSON Lines).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FrameRecord {
    pub frame: u32,
    pub t: f64,
    #[serde(flatten)]
    pub select: FrameStats,
    #[serde(flatten)]
    pub stream: FrameWork,
    pub resident: usize,
    pub wanted: usize,
    pub bytes_fetched: u64,
    pub requests: u64,
    /// The streamer's last failure so far (`null` while there has been none): why
    /// tiles are missing or a coarser level stands in.
    #[serde(default)]
    pub last_error: Option<String>,
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub render: Option<RenderRecord>,
}

/// Totals of a flight.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FlySummary {
    pub frames: u32,
    /// Frames that drew at least one tile. A flight where this is 0 failed
    /// ([`FlySummary::verdict`]; `tessera fly` exits non-zero).
    #[serde(default)]
    pub frames_drawn: u32,
    /// Frames whose deficit was missing (`max_rho: null`): part of the view had
    /// nothing drawn, or the eye was inside a stand-in's error box.
    #[serde(default)]
    pub frames_missing: u32,
    pub within_tau: f64,
    pub within_2tau: f64,
    /// The same for the surface as drawn, geomorph transitions included
    /// ([`crate::select::FrameStats::drawn_deficit`]): a refined patch is drawn
    /// coarser than its LOD while its transition runs.
    #[serde(default)]
    pub drawn_within_tau: f64,
    #[serde(default)]
    pub drawn_within_2tau: f64,
    /// Frames before the first one within τ (start-up: the root and its first
    /// descendants are still on their way).
    pub warmup_frames: u32,
    /// Fractions over the frames after the warm-up.
    pub steady_within_tau: f64,
    pub steady_within_2tau: f64,
    pub p99_stream_us: f64,
    pub max_stream_us: f64,
    pub stream: StreamStats,
    /// Requests and bytes of the open, before the first frame (the bootstrap: one
    /// request; `stream` counts the tile requests of the frames only).
    #[serde(default)]
    pub open_requests: u32,
    #[serde(default)]
    pub open_bytes: u64,
    /// The last request failure, if any (why a flight against a failing server stalled).
    pub last_error: Option<String>,
    /// With rendering: medians per frame.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub render: Option<RenderSummary>,
    /// Latency of every finished request, in milliseconds (not serialized).
    #[serde(skip)]
    pub latencies_ms: Vec<f64>,
}

impl FlySummary {
    /// `Err` when the whole flight drew nothing (the client exits non-zero then:
    /// docs/ARCHITECTURE.md#the-client-never-goes-blind), saying what the streamer could
    /// not get.
    pub fn verdict(&self) -> anyhow::Result<()> {
        if self.frames == 0 || self.frames_drawn > 0 {
            return Ok(());
        }
        let s = &self.stream;
        anyhow::bail!(
            "the flight drew nothing in any of its {} frames ({} requests, {} failed, {} corrupt-record reports, {} tiles written off); last error: {}",
            self.frames,
            s.requests,
            s.failures,
            s.corrupt,
            s.written_off,
            self.last_error.as_deref().unwrap_or("none")
        )
    }
}

/// What the client learns from `/v1/datasets/{name}` (or a static file's header).
pub(crate) struct DatasetView {
    pub world: World,
    pub min_height: f64,
    pub max_height: f64,
}

/// Opens the flight's source ([`Streamer::open`]): the streamer, and the dataset's
/// document read into a [`World`], the height range and record layout.
pub(crate) fn open(opts: &FlyOptions) -> anyhow::Result<(Streamer, DatasetView)> {
    let (streamer, info) = Streamer::open(&opts.source, opts.stream.clone(), opts.runtime.clone())
        .with_context(|| format!("cannot open {}", opts.source))?;
    let world = World::from_dataset(&info, opts.spacing)?.with_globe(opts.globe, &info)?;
    let view = DatasetView {
        world,
        min_height: info.min_height,
        max_height: info.max_height,
    };
    Ok((streamer, view))
}

/// [`fly`] with its records written to the file `stats` (JSON Lines), if any,
/// after creating the headless output directory (`RenderSetup::out_dir`).
pub fn fly_to_file(opts: &FlyOptions, stats: Option<&Path>) -> anyhow::Result<FlySummary> {
    #[cfg(feature = "render")]
    if let Some(setup) = &opts.render {
        let dir = &setup.out_dir;
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create", dir.display()))?;
    }
    let mut file = match stats {
        Some(p) => Some(std::io::BufWriter::new(
            std::fs::File::create(p).with_context(|| format!("{}: cannot create", p.display()))?,
        )),
        None => None,
    };
    let summary = fly(opts, file.as_mut().map(|f| f as &mut dyn Write))?;
    if let Some(mut f) = file {
        f.flush()?;
    }
    Ok(summary)
}

/// The flight's renderer: headless rendering when [`FlyOptions::render`] asks
/// for it (with the dataset's imagery to drape), else none.
#[cfg(feature = "render")]
fn drawer(
    opts: &FlyOptions,
    world: World,
    heights: (f64, f64),
    streamer: &Streamer,
) -> anyhow::Result<Option<Box<dyn FrameDrawer>>> {
    let Some(setup) = &opts.render else {
        return Ok(None);
    };
    let headless = super::headless::Headless::for_flight(world, heights, setup.clone(), streamer)?;
    Ok(Some(Box::new(headless)))
}

/// Without the `render` feature a flight selects and streams only.
#[cfg(not(feature = "render"))]
#[allow(clippy::unnecessary_wraps)]
fn drawer(
    _opts: &FlyOptions,
    _world: World,
    _heights: (f64, f64),
    _streamer: &Streamer,
) -> anyhow::Result<Option<Box<dyn FrameDrawer>>> {
    Ok(None)
}

/// Flies the path, writing one [`FrameRecord`] per frame to `stats`.
pub fn fly(opts: &FlyOptions, mut stats: Option<&mut dyn Write>) -> anyhow::Result<FlySummary> {
    let (
        mut streamer,
        DatasetView {
            world,
            min_height,
            max_height,
        },
    ) = open(opts)?;
    let size = world.size_m();
    let path = FlyPath::load(&opts.path, size.max_element())?;
    let params = SelectParams {
        tau: opts.tau,
        policy: opts.policy,
        morph_seconds: opts.morph_seconds,
        morph_by_distance: opts.morph_by_distance,
        morph_error_limit: opts.morph_error_limit,
        ..SelectParams::default()
    };
    let mut selector = Selector::new(world, params);
    let mut ahead = Selector::new(world, params);
    let mut pool = TilePool::new(opts.pool_tiles);
    // What the open fetched (the bootstrap's coarsest levels, a static file's root)
    // is resident before the first frame, so frame 0 draws.
    streamer.preload(&mut pool);
    let mut drawer = drawer(opts, world, (min_height, max_height), &streamer)?;
    let mut rendered: Vec<(FrameStats, RenderRecord)> = Vec::new();
    let mut start = Instant::now();
    let (mut within1, mut within2) = (0u32, 0u32);
    let (mut drawn1, mut drawn2) = (0u32, 0u32);
    let (mut frames_drawn, mut frames_missing) = (0u32, 0u32);
    let mut warmup: Option<u32> = None;
    let (mut steady1, mut steady2) = (0u32, 0u32);
    let mut stream_us = Vec::new();
    let camera_at = |pool: &TilePool, t: f64, fov_scale: f64| {
        let pose = path.pose(t, size);
        let ground = pool
            .ground_height(&world, pose.ground.x, pose.ground.y)
            .unwrap_or(max_height);
        pose_camera(
            &pose,
            ground,
            size.max_element(),
            fov_scale,
            (opts.width, opts.height),
        )
    };
    if let Some(d) = &mut drawer {
        // Selection draws only what is on the GPU, and a frame uploads after it
        // selects; so what the open preloaded goes up now, with the bootstrap's
        // decoding, before the flight clock starts. Without this, frame 0 would
        // select from an empty GPU and draw nothing.
        let camera = camera_at(&pool, opts.t_offset, 1.0);
        d.upload_preloaded(&mut selector, &camera, &pool, opts.t_offset);
        start = Instant::now();
    }
    for frame in 0..opts.frames {
        let t = opts.t_offset + f64::from(frame) / opts.fps;
        let settle = drawer.as_ref().is_some_and(|d| d.settles(frame));
        if settle {
            // The eye's height from the finest tile under it: the same camera in
            // every run, whatever streaming has delivered so far.
            let ground = path.pose(t, size).ground;
            let under = world.finest_tile_at(ground.x, ground.y);
            fetch_tiles(&[under], &mut pool, &mut streamer, SETTLE_TIMEOUT)?;
        }
        let camera = camera_at(&pool, t, 1.0);
        // Flight time, not the wall clock: geomorph transitions are the same in
        // every run, and a settled frame's selections (all at `t`) do not advance
        // them ([`Selector::select_at`]).
        let mut sel = match &drawer {
            Some(d) => d.select(&mut selector, &camera, &pool, t),
            None => selector.select_at(&camera, &pool, t),
        };
        if settle && let Some(d) = &mut drawer {
            let started = Instant::now();
            while !sel.wanted.is_empty() {
                // A written-off tile never arrives: say so now, not after the timeout.
                if let Some(w) = sel.wanted.iter().find(|w| streamer.written_off(w.tile)) {
                    anyhow::bail!(
                        "frame {frame}: {} was written off as corrupt; a settled frame cannot be drawn (last error: {})",
                        w.tile,
                        streamer.last_error.as_deref().unwrap_or("none")
                    );
                }
                anyhow::ensure!(
                    started.elapsed() < SETTLE_TIMEOUT,
                    "frame {frame}: the selection still wants {} tiles after {SETTLE_TIMEOUT:?}{}",
                    sel.wanted.len(),
                    streamer.last_error.as_ref().map_or_else(
                        || " (raise --gpu-tiles or --pool-tiles)".to_string(),
                        |e| format!(" (last error: {e})")
                    )
                );
                streamer.frame(&mut pool, &sel.wanted, &[]);
                if d.upload_all(&pool, &sel.wanted) == 0 {
                    std::thread::sleep(Duration::from_millis(2));
                }
                sel = d.select(&mut selector, &camera, &pool, t);
            }
        }
        pool.touch(&sel.tiles);
        // Prefetch: the view one second ahead, through a wider lens (Kang §6.1).
        let prefetch = if opts.prefetch {
            ahead.select(&camera_at(&pool, t + 1.0, 1.5), &pool).wanted
        } else {
            Vec::new()
        };
        let before = streamer.stats.tiles;
        let work = streamer.frame(&mut pool, &sel.wanted, &prefetch);
        if let Some(p) = &opts.progress {
            p.fetch_add(
                streamer.stats.tiles - before,
                std::sync::atomic::Ordering::Relaxed,
            );
        }
        stream_us.push(work.stream_us);
        let render = match &mut drawer {
            Some(d) => {
                let rec = d.draw(frame, &camera, &sel, &mut pool, &mut streamer, settle)?;
                rendered.push((sel.stats, rec));
                Some(rec)
            }
            None => None,
        };
        // A frame that draws nothing (before the root arrives) is never within τ,
        // nor is one whose deficit is missing.
        frames_drawn += u32::from(!sel.tiles.is_empty());
        frames_missing += u32::from(sel.stats.max_rho.is_none());
        let (ok1, ok2) = (sel.stats.within(1.0), sel.stats.within(2.0));
        within1 += u32::from(ok1);
        within2 += u32::from(ok2);
        drawn1 += u32::from(sel.stats.drawn_within(1.0));
        drawn2 += u32::from(sel.stats.drawn_within(2.0));
        if warmup.is_none() && ok1 {
            warmup = Some(frame);
        }
        if warmup.is_some() {
            steady1 += u32::from(ok1);
            steady2 += u32::from(ok2);
        }
        if let Some(out) = stats.as_deref_mut() {
            let rec = FrameRecord {
                frame,
                t,
                select: sel.stats,
                stream: work,
                resident: pool.len(),
                wanted: sel.wanted.len(),
                bytes_fetched: streamer.stats.bytes,
                requests: streamer.stats.requests,
                last_error: streamer.last_error.clone(),
                render,
            };
            serde_json::to_writer(&mut *out, &rec)?;
            out.write_all(b"\n")?;
        }
        // Fixed simulated frame rate, in real time (the network is real).
        let next = start + Duration::from_secs_f64(f64::from(frame + 1) / opts.fps);
        if let Some(wait) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
    }
    stream_us.sort_by(f64::total_cmp);
    let n = f64::from(opts.frames.max(1));
    let warmup_frames = warmup.unwrap_or(opts.frames);
    let steady = f64::from((opts.frames - warmup_frames).max(1));
    Ok(FlySummary {
        frames: opts.frames,
        frames_drawn,
        frames_missing,
        within_tau: f64::from(within1) / n,
        within_2tau: f64::from(within2) / n,
        drawn_within_tau: f64::from(drawn1) / n,
        drawn_within_2tau: f64::from(drawn2) / n,
        warmup_frames,
        steady_within_tau: f64::from(steady1) / steady,
        steady_within_2tau: f64::from(steady2) / steady,
        p99_stream_us: stream_us
            .get(((stream_us.len() as f64 - 1.0) * 0.99) as usize)
            .copied()
            .unwrap_or(0.0),
        max_stream_us: stream_us.last().copied().unwrap_or(0.0),
        stream: streamer.stats,
        open_requests: streamer.open_cost().0,
        open_bytes: streamer.open_cost().1,
        last_error: streamer.last_error.take(),
        render: drawer.as_ref().map(|d| d.summary(&rendered)),
        latencies_ms: std::mem::take(&mut streamer.latencies_ms),
    })
}
