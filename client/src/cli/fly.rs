//! `tessera fly`: a flight headless (`--out`), without rendering (`--no-render`), or in a
//! window; the arguments and their checks.

use super::args::{SourceArgs, parse_viewport};
use crate::app::fly::{self, FlyOptions};
use crate::app::headless::{Draws, RenderSetup};
use crate::app::window;
use crate::globe::GlobeMode;
use crate::render::gpu::Backend;
use crate::render::normals::NormalSource;
use crate::render::{DebugView, Parallax, RenderOptions};
use crate::select::Policy;
use crate::stream::{OpenArgs, StreamConfig};
use std::path::PathBuf;

/// `tessera fly`'s arguments (its help text is on the `Command` it is a variant of).
// Command-line switches, each a bool of its own.
#[allow(clippy::struct_excessive_bools)]
#[derive(Debug, clap::Args)]
pub struct FlyArgs {
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
    #[arg(long, value_name = "S", default_value_t = crate::select::MORPH_SECONDS)]
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
    #[arg(long, value_name = "X", default_value_t = crate::select::MORPH_ERROR_LIMIT)]
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
}

/// Runs the command.
pub fn run(args: FlyArgs) -> anyhow::Result<()> {
    let FlyArgs {
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
    } = args;
    let (vw, vh) = parse_viewport(&viewport)?;
    let (width, height) = (w.unwrap_or(vw), h.unwrap_or(vh));
    anyhow::ensure!(
        width > 0 && height > 0,
        "--width and --height must be positive"
    );
    let budget = std::time::Duration::from_secs_f64(budget_ms / 1e3);
    // What to draw with, headless or in the window.
    let render_opts = RenderOptions {
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
    let render = out.as_ref().map(|dir| RenderSetup {
        opts: render_opts,
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
        .then(|| crate::paths::FlyPath::start_focus(&path, 0.0))
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
        return window::run(&opts, render_opts);
    }
    let summary = fly::fly_to_file(&opts, stats.as_deref())?;
    println!("{}", serde_json::to_string_pretty(&summary)?);
    // A flight that drew nothing at all is a failure, whatever it fetched
    // (docs/ARCHITECTURE.md#the-client-never-goes-blind): the summary above says what,
    // this says why.
    summary.verdict()
}
