//! `tessera`: the Tessera client's command line — the clap definitions, and a
//! dispatch of each command to its run mode in `tessera_client::app`.

use anyhow::Context;
use clap::{Parser, Subcommand};
use std::path::PathBuf;
use tessera_client::app::bench_select::{BenchSelect, bench_select};
use tessera_client::app::fly::{self, FlyOptions};
use tessera_client::app::headless::{Draws, RenderSetup};
use tessera_client::app::{load_test, window};
use tessera_client::globe::GlobeMode;
use tessera_client::load::merge::merge_files;
use tessera_client::load::output;
use tessera_client::load::replay::{self, ReplayOptions};
use tessera_client::load::report::ReplayReport;
use tessera_client::load::schedule::{Pacing, RampStages, RateArg};
use tessera_client::load::trace::{Shard, Trace};
use tessera_client::render::gpu::Backend;
use tessera_client::render::normals::NormalSource;
use tessera_client::render::{DebugView, Parallax, RenderOptions};
use tessera_client::select::Policy;
use tessera_client::stream::{OpenArgs, RequestMode, StreamConfig, TileSource};
use tessera_shared::Pyramid;

#[derive(Debug, Parser)]
#[command(
    name = "tessera",
    version,
    about = "Tessera client: fly through DEM pyramids streamed from a Tessera server"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Load-test a server (or a static host serving a pyramid file, --pyramid): N
    /// simulated clients fly the built-in paths (staggered) through the real
    /// selection and streaming code, without rendering.
    ///
    /// Or, with --replay TRACE, send a recorded trace's requests on a schedule (as
    /// recorded, --rate, --ramp, or --rate max) without selection or decoding,
    /// checking every answer, with latency from each request's scheduled start;
    /// `tessera load merge` adds up the reports of --shard K/N processes.
    #[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
    Load {
        #[command(flatten)]
        source: LoadSourceArgs,
        #[arg(long, default_value_t = 16, conflicts_with = "replay")]
        clients: u32,
        /// How long, e.g. 30s, 2m (with --replay: how long --rate N or --rate max
        /// runs; a recorded replay or a --ramp takes as long as it takes).
        #[arg(long, default_value = "30s", value_parser = parse_duration)]
        duration: std::time::Duration,
        /// Request Morton-range batches, or one tile per request.
        #[arg(long, value_enum, default_value_t = Mode::Ranges, conflicts_with = "replay")]
        mode: Mode,
        /// Simulated frames per second per client.
        #[arg(long, default_value_t = 30.0, conflicts_with = "replay")]
        fps: f64,
        #[arg(long, default_value_t = 1.0, conflicts_with = "replay")]
        tau: f64,
        #[arg(long, default_value = "1280x720", conflicts_with = "replay")]
        viewport: String,
        /// Metres between samples, east–west and north–south alike (default: the dataset's
        /// ground spacing, measured by the server for each axis; else 100).
        #[arg(long, conflicts_with = "replay")]
        spacing: Option<f64>,
        /// Also write the clients' requests to TRACE (JSON Lines, FORMAT.md "Request
        /// traces"), with each completed answer's status, tiles, bytes and digest,
        /// for --replay. Needs --server.
        #[arg(long, value_name = "TRACE")]
        record: Option<PathBuf>,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        open: OpenArgs,
        #[command(flatten)]
        replay: ReplayArgs,
        #[command(subcommand)]
        action: Option<LoadAction>,
    },
    /// Fly a path over a dataset served by `tessera-server serve`, or over a pyramid
    /// file read straight from a static host (--pyramid): selection and streaming at
    /// a fixed frame rate, in real time, with per-frame statistics.
    Fly {
        #[command(flatten)]
        source: SourceArgs,
        /// canyon, pass, orbit, descent (from the whole dataset down to 100 m in 6 s),
        /// or a path JSON file (paths.rs documents the format).
        #[arg(long, default_value = "canyon")]
        path: String,
        #[arg(long, default_value_t = 600)]
        frames: u32,
        #[arg(long, default_value_t = 60.0)]
        fps: f64,
        /// Screen-space error threshold in pixels.
        #[arg(long, default_value_t = 1.0)]
        tau: f64,
        #[arg(long, default_value = "1920x1080")]
        viewport: String,
        /// Metres between samples, east–west and north–south alike (default: the dataset's
        /// ground spacing, measured by the server for each axis; else 100).
        #[arg(long)]
        spacing: Option<f64>,
        /// Viewport width (overrides --viewport).
        #[arg(long)]
        width: Option<u32>,
        /// Viewport height (overrides --viewport).
        #[arg(long)]
        height: Option<u32>,
        /// Selection and streaming only: no GPU, no window, no images. Without
        /// this or --out, a window opens (mouse drag looks, WASD/QE move, Shift
        /// faster, +/- τ, 1–5 debug views (5: cells that are not terrain), P parallax, Esc quits).
        #[arg(long, conflicts_with = "out")]
        no_render: bool,
        /// Render headless into DIR: frame_NNNNN.png and stats.jsonl.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// Render the full-resolution reference (every sample a vertex) instead.
        #[arg(long, requires = "out")]
        reference: bool,
        /// Also render the reference and record MSE, PSNR and crack pixels per frame.
        #[arg(long, requires = "out", conflicts_with = "reference")]
        quality: bool,
        /// With --quality or --reference: only every Nth frame.
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
        quality_every: u32,
        /// With --out: write stats but no frame PNGs.
        #[arg(long, requires = "out")]
        no_frames: bool,
        /// With --quality: at each measured frame, wait until the selection has every
        /// tile it asks for (fetched and uploaded) before drawing, with the eye on the
        /// finest ground under it. Quality then measures the policy, not how far
        /// streaming has got, and every run of the flight sees the same cameras.
        #[arg(long, requires = "quality")]
        settle: bool,
        /// With --quality: keep reference images in DIR and reuse them in later runs
        /// of the same flight (same dataset, camera, viewport and view).
        #[arg(long, value_name = "DIR", requires = "quality")]
        reference_cache: Option<PathBuf>,
        /// Measure popping: settle every frame (everything the selection asks for
        /// resident), and compare consecutive frames pixel by pixel, split by
        /// whether the selection changed (mean and p99 change; in the summary's
        /// render.popping). Fly slowly (e.g. a high --fps) for meaningful figures.
        #[arg(long, requires = "out", conflicts_with_all = ["reference", "quality"])]
        popping: bool,
        /// Draw every patch at its own LOD, without geomorphing towards the next
        /// coarser one (LOD changes then pop; for measuring what morphing does).
        #[arg(long)]
        no_morph: bool,
        /// Seconds of flight time a geomorph transition takes: a patch that replaces
        /// another surface (a refinement, a split, a merge) starts as that surface
        /// and morphs to its own LOD in this time, and a refined tile's shading
        /// fades in from its parent's; 0 for none (and with --no-morph).
        #[arg(long, value_name = "S", default_value_t = tessera_client::select::MORPH_SECONDS)]
        morph_seconds: f64,
        /// Also slide each patch towards the next coarser LOD across a band of
        /// distance, as CDLOD does (it draws patches in the band coarser than their
        /// LOD: lower PSNR at the same τ).
        #[arg(long, conflicts_with = "no_morph")]
        morph_by_distance: bool,
        /// The most screen-space error a transition may draw, as a multiple of τ: a
        /// refinement starts as the coarser surface it replaces only as far as that
        /// keeps its error within this, and jumps the rest of the way (fast flight
        /// outruns transitions otherwise). 1: the surface drawn keeps τ; inf: always
        /// start as the old surface.
        #[arg(long, value_name = "X", default_value_t = tessera_client::select::MORPH_ERROR_LIMIT)]
        morph_error_limit: f64,
        /// Do not drape the dataset's imagery (the hypsometric tint instead), even
        /// when the dataset has some.
        #[arg(long)]
        no_imagery: bool,
        /// Draw on the globe: the dataset's longitude/latitude grid on its body's
        /// ellipsoid (ECEF, camera on the local east-north-up frame, horizon
        /// culling). auto: the globe for geographic datasets on a known body, flat
        /// for projected ones (regional: DECISIONS.md); on: the globe or an error;
        /// off: always flat.
        #[arg(long, value_enum, default_value_t = GlobeMode::Auto)]
        globe: GlobeMode,
        /// Debug view.
        #[arg(long, value_enum, default_value_t = DebugView::Shaded)]
        view: DebugView,
        /// Parallax mapping in the fragment shader (González §2.2–2.4).
        #[arg(long, value_enum, default_value_t = Parallax::None)]
        parallax: Parallax,
        /// How detail is chosen: screen-space error from the error tables, or
        /// distance only (the brute-force baseline; τ then bounds a cell's size on
        /// screen).
        #[arg(long, value_enum, default_value_t = Policy::ScreenError)]
        policy: Policy,
        /// Graphics API (WGPU_BACKEND=vulkan|gl also works).
        #[arg(long, value_enum, default_value_t = Backend::Auto)]
        backend: Backend,
        /// Where tiles' normal maps are built: a GPU compute pass over the uploaded
        /// heights (an upload is only texture copies), or the CPU at upload (the
        /// reference, for side-by-side measurement).
        #[arg(long, value_enum, default_value_t = NormalSource::Gpu)]
        normals: NormalSource,
        /// Tiles held on the GPU (texture-array layers).
        #[arg(long, default_value_t = 256)]
        gpu_tiles: u32,
        /// Turn off prefetching (the enlarged, predicted view).
        #[arg(long)]
        no_prefetch: bool,
        /// Ask for the bootstrap every client shares, without the path's starting
        /// point (the focus that makes it carry the first view's finer tiles).
        #[arg(long)]
        no_focus: bool,
        /// Tiles kept decoded in memory.
        #[arg(long, default_value_t = 1024)]
        pool_tiles: usize,
        /// Per-frame streaming budget in milliseconds.
        #[arg(long, default_value_t = 4.0)]
        budget_ms: f64,
        /// Write per-frame statistics here (JSON Lines).
        #[arg(long)]
        stats: Option<PathBuf>,
        #[command(flatten)]
        open: OpenArgs,
    },
    /// Time view-dependent selection on a local pyramid, with every error table
    /// resident: the camera flies a path as `tessera fly` does (the eye at the
    /// path's altitude above the finest ground under it), one selection per frame,
    /// the selector's state carried from frame to frame. The path is run forward
    /// and back until --frames frames are timed; the first frame, which builds every
    /// quadtree from nothing, is not timed. Reports the selector's own clock
    /// (median, mean, p90, max), the median triangle count and the worst deficit.
    BenchSelect {
        /// A `.tess` pyramid file.
        file: PathBuf,
        /// canyon (low and fast), pass (high, across the whole dataset), orbit, or
        /// a path JSON file.
        #[arg(long, default_value = "pass")]
        path: String,
        /// Frames per second along the path (how far the camera moves per frame).
        #[arg(long, default_value_t = 60.0)]
        fps: f64,
        /// Screen-space error threshold in pixels.
        #[arg(long, default_value_t = 1.0)]
        tau: f64,
        /// Frames to time (the path is run forward and back as often as needed).
        #[arg(long, default_value_t = 2000)]
        frames: u32,
        /// Viewport, e.g. 1920x1080.
        #[arg(long, default_value = "1920x1080")]
        viewport: String,
        /// Metres between neighbouring samples, both axes (default: the dataset's ground
        /// spacing, measured by the server for each axis; else 100).
        #[arg(long)]
        spacing: Option<f64>,
        /// Print one JSON object: file, tiles, width, height, tau, path, fps,
        /// frames, median_us, mean_us, p90_us, max_us, median_triangles,
        /// worst_deficit.
        #[arg(long)]
        json: bool,
    },
    /// Pictures of a headless flight: stats.png (plots over time), and with --frames
    /// contact_sheet.png (12 frames) and flight.png (an animated PNG of the frames,
    /// 480 px wide), plus a short summary.
    Report {
        /// The flight's stats.jsonl.
        stats: PathBuf,
        /// The frames directory (frame_NNNNN.png) for the contact sheet and the
        /// animation.
        #[arg(long)]
        frames: Option<PathBuf>,
        /// Where to write stats.png, contact_sheet.png and flight.png.
        #[arg(long, short, default_value = ".")]
        out: PathBuf,
        /// Frames per second the frames were flown at (the animation's pace).
        #[arg(long, default_value_t = 30, value_parser = clap::value_parser!(u32).range(1..=1000))]
        fps: u32,
    },
    /// Print the size, levels and height range of a local pyramid file.
    Inspect {
        /// A `.tess` pyramid file.
        file: PathBuf,
    },
}

/// Where the tiles come from: a server and dataset, or a pyramid file's URL.
#[derive(Debug, clap::Args)]
struct SourceArgs {
    /// Server base URL, e.g. http://127.0.0.1:8080.
    #[arg(long, required_unless_present = "pyramid", requires = "dataset")]
    server: Option<String>,
    /// Dataset name on the server.
    #[arg(long, required_unless_present = "pyramid", requires = "server")]
    dataset: Option<String>,
    /// Read a pyramid file straight from a static host, CDN or object store with
    /// HTTP Range requests, no Tessera server: http(s)://host/path/file.tess (or
    /// file:///path/file.tess). The host must answer Range requests with 206.
    #[arg(long, value_name = "URL", conflicts_with_all = ["server", "dataset"])]
    pyramid: Option<String>,
}

impl SourceArgs {
    fn source(self) -> anyhow::Result<TileSource> {
        match (self.pyramid, self.server, self.dataset) {
            (Some(url), None, None) => Ok(TileSource::pyramid(url)),
            (None, Some(server), Some(dataset)) => Ok(TileSource::server(server, dataset)),
            _ => anyhow::bail!("give --server URL --dataset NAME, or --pyramid URL"),
        }
    }
}

/// `tessera load`'s source: as [`SourceArgs`], but none is required by itself, since
/// `--replay` takes its server from the trace (`--server` overrides it) and needs no
/// `--dataset`; `run` checks the combinations.
#[derive(Debug, clap::Args)]
struct LoadSourceArgs {
    /// Server base URL, e.g. http://127.0.0.1:8080 (with --replay: instead of the
    /// server the trace was recorded against).
    #[arg(long)]
    server: Option<String>,
    /// Dataset name on the server (not with --replay: the trace names it).
    #[arg(long, conflicts_with = "replay")]
    dataset: Option<String>,
    /// Read a pyramid file straight from a static host, CDN or object store with
    /// HTTP Range requests, no Tessera server: http(s)://host/path/file.tess (or
    /// file:///path/file.tess). The host must answer Range requests with 206.
    #[arg(long, value_name = "URL", conflicts_with_all = ["server", "dataset", "replay"])]
    pyramid: Option<String>,
}

impl LoadSourceArgs {
    fn source(self) -> anyhow::Result<TileSource> {
        SourceArgs {
            server: self.server,
            dataset: self.dataset,
            pyramid: self.pyramid,
        }
        .source()
    }
}

/// `tessera load --replay`'s settings (issue 18).
#[derive(Debug, clap::Args)]
struct ReplayArgs {
    /// Replay the requests of TRACE (written by --record) instead of flying clients:
    /// only HTTP and the frames' checksums, no selection or decoding. Without --rate
    /// or --ramp, every request once at its recorded time.
    #[arg(long, value_name = "TRACE", conflicts_with = "record")]
    replay: Option<PathBuf>,
    /// With --replay: a constant arrival rate, requests/s (all --shard processes
    /// together, at most 1000000/s for each), for --duration, cycling through the
    /// trace; or `max`: saturation, each of --connections sending its next request
    /// when its last one finished.
    #[arg(long, value_name = "N|max", requires = "replay")]
    rate: Option<RateArg>,
    /// With --replay: ramping arrival rate, stages DURATION:RATE,… (e.g.
    /// 10s:100,20s:400): over each stage the rate moves linearly from the previous
    /// stage's (the first from --rate, else 0) to its own; --duration is not used.
    #[arg(long, value_name = "STAGES", requires = "replay")]
    ramp: Option<RampStages>,
    /// With --replay: HTTP/1.1: at most C requests in flight, on C keep-alive
    /// connections; with --http2: C connections, each carrying up to 100 requests.
    /// When all are busy, a request waits, and the wait counts in its latency. At
    /// most the open-file limit (`ulimit -n`) less 64, and 65536.
    #[arg(long, value_name = "C", default_value_t = 64, requires = "replay",
          value_parser = clap::value_parser!(u32).range(1..))]
    connections: u32,
    /// With --replay: this process is shard K of N (K from 0): it replays the
    /// clients c with c % N == K at 1/N of --rate.
    #[arg(long, value_name = "K/N", default_value = "0/1", requires = "replay")]
    shard: Shard,
    /// With --replay: a request's limit (at most 1h), and how long to wait for the
    /// requests still in flight when the schedule ends (those count as timeout
    /// errors). The run stops then, whatever the rate: requests not yet sent are
    /// not sent, and reported as unsent.
    #[arg(long, default_value = "10s", value_parser = parse_duration, requires = "replay")]
    timeout: std::time::Duration,
    /// With --replay: runtime threads (1: everything on one core).
    #[arg(long, default_value_t = 1, requires = "replay",
          value_parser = clap::value_parser!(u32).range(1..256))]
    threads: u32,
    /// With --replay: write DIR/load.json (the report) and DIR/latency.png.
    #[arg(long, value_name = "DIR", requires = "replay")]
    out: Option<PathBuf>,
}

#[derive(Debug, Subcommand)]
enum LoadAction {
    /// Add up the reports (load.json) of the --shard K/N processes of one replay:
    /// counts and errors add, latency histograms add exactly (percentiles from the
    /// sums), seconds are the longest shard's and rates are totals over them.
    Merge {
        /// Reports (DIR/load.json of --out DIR, or --json's output), or their DIRs.
        #[arg(required = true, value_name = "REPORT")]
        reports: Vec<PathBuf>,
        /// Print the merged report as JSON.
        #[arg(long)]
        json: bool,
        /// Write DIR/load.json and DIR/latency.png.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
    },
}

/// Prints a replay's report (JSON or the summary) and writes it under `out`.
fn emit_replay(r: &ReplayReport, json: bool, out: Option<&std::path::Path>) -> anyhow::Result<()> {
    // Printed first, so that a directory that cannot be written loses no results;
    // written even when stdout has gone away (`| head -1`), which is said after.
    let printed = if json {
        output::print_line(serde_json::to_string_pretty(r)?)
    } else {
        output::print_line(r)
    };
    if let Some(dir) = out {
        r.write_dir(dir)?;
    }
    printed
}

/// `tessera load --replay TRACE …`.
fn load_replay(
    trace: &std::path::Path,
    server: Option<String>,
    args: ReplayArgs,
    duration: std::time::Duration,
    http2: bool,
    json: bool,
) -> anyhow::Result<()> {
    let pacing = match (args.rate, args.ramp) {
        (Some(RateArg::Max), Some(_)) => {
            anyhow::bail!("--ramp needs a starting --rate N, not --rate max")
        }
        (Some(RateArg::Max), None) => Pacing::Saturation { duration },
        (Some(RateArg::PerSecond(rate)), None) => Pacing::Constant { rate, duration },
        (rate, Some(stages)) => Pacing::Ramp {
            start: match rate {
                Some(RateArg::PerSecond(r)) => r.per_second(),
                _ => 0.0,
            },
            stages,
        },
        (None, None) => Pacing::Recorded,
    };
    let opts = ReplayOptions {
        server,
        pacing,
        connections: args.connections,
        http2,
        shard: args.shard,
        timeout: args.timeout,
        threads: args.threads as usize,
        progress: !json,
        ..ReplayOptions::new(Trace::read(trace)?)
    };
    let r = replay::replay(&opts)?;
    emit_replay(&r, json, args.out.as_deref())
}

/// `tessera load merge REPORT…`.
fn load_merge(
    reports: &[PathBuf],
    json: bool,
    out: Option<&std::path::Path>,
) -> anyhow::Result<()> {
    // Each file once: the same shard twice would count its requests twice.
    let merged = merge_files(reports).with_context(|| {
        format!(
            "cannot merge {}",
            reports
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        )
    })?;
    emit_replay(&merged, json, out)
}

/// Mesa's Vulkan device-select layer looks for a display to pick the GPU that
/// drives it, and without one prints "error: XDG_RUNTIME_DIR is invalid or not set"
/// at every device enumeration. Headless there is nothing to pick; `NODEVICE_SELECT`
/// turns the layer off (what `./run` exports too, for the server's and tests' sake),
/// unless the user set it either way.
fn quiet_headless_vulkan() {
    let headless =
        std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none();
    if headless && std::env::var_os("NODEVICE_SELECT").is_none() {
        // SAFETY: called first in `main`, before any thread exists, so nothing can
        // read or write the environment at the same time.
        #[allow(unsafe_code)]
        unsafe {
            std::env::set_var("NODEVICE_SELECT", "1");
        }
    }
}

fn main() -> std::process::ExitCode {
    quiet_headless_vulkan();
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        // The reader of our output went away (`| head -1`): not an error to report.
        Err(e) if output::is_stdout_closed(&e) => {
            std::process::ExitCode::from(output::STDOUT_CLOSED_EXIT)
        }
        Err(e) => {
            output::progress(format_args!("error: {e:#}\n"));
            std::process::ExitCode::FAILURE
        }
    }
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum Mode {
    Ranges,
    Single,
}

/// Parses `30s`, `2m`, `1500ms` or plain seconds (clap's value parser).
fn parse_duration(s: &str) -> Result<std::time::Duration, String> {
    tessera_client::load::schedule::parse_duration(s)
        .ok_or_else(|| format!("{s:?} is not a positive duration like 30s, 2m or 1500ms"))
}

fn parse_viewport(v: &str) -> anyhow::Result<(u32, u32)> {
    v.split_once('x')
        .and_then(|(a, b)| Some((a.parse::<u32>().ok()?, b.parse::<u32>().ok()?)))
        .filter(|(w, h)| *w > 0 && *h > 0)
        .with_context(|| format!("viewport {v:?} is not WIDTHxHEIGHT"))
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Load {
            source,
            clients,
            duration,
            mode,
            fps,
            tau,
            viewport,
            spacing,
            record,
            json,
            open,
            replay,
            action,
        } => {
            if let Some(LoadAction::Merge { reports, json, out }) = action {
                return load_merge(&reports, json, out.as_deref());
            }
            if let Some(trace) = replay.replay.clone() {
                return load_replay(&trace, source.server, replay, duration, open.http2, json);
            }
            let (width, height) = parse_viewport(&viewport)?;
            let opts = load_test::LoadOptions {
                source: source.source()?,
                clients,
                duration,
                mode: match mode {
                    Mode::Ranges => RequestMode::Ranges,
                    Mode::Single => RequestMode::Single,
                },
                fps,
                tau,
                width,
                height,
                spacing,
                progress: !json,
                open,
                record,
            };
            let r = load_test::load(&opts)?;
            if json {
                output::print_line(serde_json::to_string_pretty(&r)?)
            } else {
                output::print_line(&r)
            }
        }
        Command::Fly {
            source,
            path,
            frames,
            fps,
            tau,
            viewport,
            spacing,
            width: w,
            height: h,
            no_render,
            out,
            reference,
            quality,
            quality_every,
            no_frames,
            settle,
            reference_cache,
            popping,
            no_morph,
            morph_seconds,
            morph_by_distance,
            morph_error_limit,
            no_imagery,
            globe,
            view,
            parallax,
            policy,
            backend,
            normals,
            gpu_tiles,
            no_prefetch,
            no_focus,
            pool_tiles,
            budget_ms,
            stats,
            open,
        } => {
            let (vw, vh) = parse_viewport(&viewport)?;
            let (width, height) = (w.unwrap_or(vw), h.unwrap_or(vh));
            anyhow::ensure!(
                width > 0 && height > 0,
                "--width and --height must be positive"
            );
            let budget = std::time::Duration::from_secs_f64(budget_ms / 1e3);
            let render = out.as_ref().map(|dir| RenderSetup {
                opts: RenderOptions {
                    width,
                    height,
                    slots: gpu_tiles,
                    view,
                    parallax,
                    backend,
                    normals,
                    morph: !no_morph,
                    imagery: !no_imagery,
                },
                out_dir: dir.clone(),
                draws: if reference {
                    Draws::Reference
                } else if quality {
                    Draws::Quality
                } else if popping {
                    Draws::Popping
                } else {
                    Draws::Selection
                },
                quality_every,
                write_frames: !no_frames,
                upload_budget: budget,
                settle,
                reference_cache,
            });
            // Headless runs write their statistics beside the frames by default.
            let stats = stats.or_else(|| out.as_ref().map(|d| d.join("stats.jsonl")));
            anyhow::ensure!(
                fps > 0.0 && tau > 0.0 && budget_ms > 0.0,
                "--fps, --tau and --budget-ms must be positive"
            );
            // The bootstrap's focus: where the path starts.
            let focus = (!no_focus)
                .then(|| tessera_client::paths::FlyPath::start_focus(&path, 0.0))
                .flatten();
            anyhow::ensure!(
                morph_seconds >= 0.0 && morph_seconds.is_finite(),
                "--morph-seconds must be 0 or more"
            );
            anyhow::ensure!(
                morph_error_limit >= 1.0,
                "--morph-error-limit must be 1 or more (a multiple of τ), got {morph_error_limit}"
            );
            let opts = FlyOptions {
                source: source.source()?,
                path,
                frames,
                fps,
                tau,
                policy,
                // --no-morph turns transitions off too: every patch at its own LOD
                // (the baseline), no inner LOD raised while one runs.
                morph_seconds: if no_morph { 0.0 } else { morph_seconds },
                morph_by_distance,
                morph_error_limit,
                width,
                height,
                spacing,
                prefetch: !no_prefetch,
                pool_tiles,
                stream: StreamConfig {
                    budget,
                    focus,
                    ..open.config()
                },
                t_offset: 0.0,
                runtime: None,
                progress: None,
                render,
                globe,
            };
            if !no_render && out.is_none() {
                // Neither headless nor --no-render: the windowed client.
                let render = RenderOptions {
                    width,
                    height,
                    slots: gpu_tiles,
                    view,
                    parallax,
                    backend,
                    normals,
                    morph: !no_morph,
                    imagery: !no_imagery,
                };
                return window::run(&opts, render);
            }
            let summary = fly::fly_to_file(&opts, stats.as_deref())?;
            println!("{}", serde_json::to_string_pretty(&summary)?);
            // A flight that drew nothing at all is a failure, whatever it fetched
            // (DESIGN §8): the summary above says what, this says why.
            summary.verdict()
        }
        Command::BenchSelect {
            file,
            path,
            fps,
            tau,
            frames,
            viewport,
            spacing,
            json,
        } => {
            let (width, height) = parse_viewport(&viewport)?;
            let r = bench_select(&BenchSelect {
                file: &file,
                path: &path,
                fps,
                tau,
                frames,
                width,
                height,
                spacing,
            })?;
            if json {
                println!("{}", serde_json::to_string(&r)?);
            } else {
                println!("{r}");
            }
            Ok(())
        }
        Command::Report {
            stats,
            frames,
            out,
            fps,
        } => {
            use tessera_client::report::animation;
            let summary =
                tessera_client::report::flight::write_report(&stats, frames.as_deref(), &out)?;
            // A reader gone away (`| head -1`) stops the printing, not the report's files.
            let mut printed = output::print_line(&summary);
            if let Some(dir) = &frames {
                let file = out.join("flight.png");
                let opts = animation::AnimationOptions {
                    fps,
                    ..animation::AnimationOptions::default()
                };
                let a = animation::write_animation(&animation::frame_files(dir)?, &file, opts)?;
                if printed.is_ok() {
                    printed = output::print_line(format_args!(
                        "{}: {} frames of {}×{} (every {}), {:.1} MB",
                        file.display(),
                        a.frames,
                        a.width,
                        a.height,
                        a.step,
                        a.bytes as f64 / 1e6
                    ));
                }
            }
            printed
        }
        Command::Inspect { file } => {
            let p = Pyramid::open_file(&file).with_context(|| file.display().to_string())?;
            let m = p.metadata();
            println!(
                "{}: {}×{} samples, {} levels of {}-cell tiles, heights {:.2}..{:.2} m",
                file.display(),
                m.width,
                m.height,
                m.levels,
                m.tile_size,
                m.min_height,
                m.max_height
            );
            Ok(())
        }
    }
}
