//! Headless rendering inside a flight (`tessera fly --out DIR`): GPU uploads under
//! the per-frame budget, the frame itself, PNGs, and, with `--quality`, the
//! full-resolution reference and its comparison (MSE, PSNR, crack pixels).

use super::frame_drawer::{FrameDrawer, RenderRecord, RenderSummary};
use super::settle::{SETTLE_TIMEOUT, fetch_tiles};
use crate::camera::Camera;
use crate::flight_report::popping::{Popping, PoppingSummary, SelectionKey};
use crate::render::reference::{finest_tiles_in_view, full_resolution_patches};
use crate::render::slots::OnGpu;
use crate::render::{Parallax, RenderOptions, Renderer, png_out, quality};
use crate::select::{FrameStats, Selection, Selector, Wanted, World};
use crate::stream::Streamer;
use crate::stream::imagery_tiles::ImageryFeed;
use crate::stream::pool::TilePool;
use anyhow::Context;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// How a flight renders.
#[derive(Clone, Debug)]
pub struct RenderSetup {
    pub opts: RenderOptions,
    /// Where frames go (`frame_00000.png`, …).
    pub out_dir: PathBuf,
    /// What each frame draws and measures.
    pub draws: Draws,
    /// With [`Draws::Reference`] or [`Draws::Quality`]: only every Nth frame (the reference draws every
    /// sample in view, which is slow on a CPU rasterizer).
    pub quality_every: u32,
    /// Write every frame as a PNG (the demo and `--out` do; benchmarks may not).
    pub write_frames: bool,
    /// Per-frame budget for GPU uploads.
    pub upload_budget: Duration,
    /// At measured frames, wait until the selection has everything it asks for
    /// (fetched and uploaded) before drawing, with the eye placed on the finest
    /// ground under it: the comparison then measures the policy, not how far
    /// streaming has got, and every run sees the same camera.
    pub settle: bool,
    /// Reuse reference images between flights (one benchmark session): keyed by
    /// the dataset, the exact camera and the view.
    pub reference_cache: Option<PathBuf>,
}

/// What a headless flight draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Draws {
    /// The selection.
    Selection,
    /// The full-resolution reference instead of the selection.
    Reference,
    /// Both; they are compared per frame, and references go to `out_dir/reference/`.
    Quality,
    /// The selection, settled at every frame (everything it asks for resident),
    /// and the popping metric over consecutive frames ([`crate::flight_report::popping`]).
    Popping,
}

#[derive(Debug)]
pub struct Headless {
    pub renderer: Renderer,
    setup: RenderSetup,
    heights: (f64, f64),
    popping: Popping,
    /// With [`Draws::Popping`]: the previous frame's patches, drawn again from
    /// this frame's camera (the same-camera figures).
    previous_patches: Option<Vec<crate::select::Patch>>,
    /// The dataset's imagery, when it has some and frames are drawn
    /// ([`Headless::for_flight`]).
    imagery: Option<ImageryFeed>,
}

impl Headless {
    pub fn new(world: World, heights: (f64, f64), setup: RenderSetup) -> anyhow::Result<Self> {
        std::fs::create_dir_all(&setup.out_dir)
            .with_context(|| format!("{}: cannot create", setup.out_dir.display()))?;
        if setup.draws == Draws::Quality {
            std::fs::create_dir_all(setup.out_dir.join("reference"))?;
        }
        let renderer = Renderer::new(world, heights, setup.opts)?;
        tracing::info!(gpu = %renderer.gpu.describe(), "renderer ready");
        Ok(Self {
            renderer,
            setup,
            heights,
            popping: Popping::default(),
            previous_patches: None,
            imagery: None,
        })
    }

    /// [`Headless::new`] for a flight over `streamer`'s dataset, draping its
    /// imagery when it has some: the drawn tiles' imagery is fetched each frame and
    /// uploaded into their slots (Yang §3). Its pool holds as many tiles as the GPU
    /// (a 256² tile is 256 KiB decoded).
    pub fn for_flight(
        world: World,
        heights: (f64, f64),
        setup: RenderSetup,
        streamer: &Streamer,
    ) -> anyhow::Result<Self> {
        let mut headless = Self::new(world, heights, setup)?;
        headless.imagery = imagery_feed(&mut headless.renderer, streamer)?;
        Ok(headless)
    }

    /// Whether frame `frame` needs every finest tile in view (fetched before it).
    pub fn needs_reference(&self, frame: u32) -> bool {
        matches!(self.setup.draws, Draws::Reference | Draws::Quality)
            && frame.is_multiple_of(self.setup.quality_every.max(1))
    }

    /// Whether frame `frame` waits for its selection to converge ([`RenderSetup::settle`]).
    pub fn settles(&self, frame: u32) -> bool {
        (self.setup.settle && self.needs_reference(frame)) || self.setup.draws == Draws::Popping
    }

    /// With [`Draws::Popping`], the figures so far.
    pub fn popping(&self) -> Option<PoppingSummary> {
        (self.setup.draws == Draws::Popping).then(|| self.popping.summary())
    }

    /// What selection may draw: tiles that are decoded and uploaded.
    pub fn tables<'a>(&'a self, pool: &'a TilePool) -> OnGpu<'a> {
        OnGpu {
            pool,
            slots: &self.renderer.slots,
        }
    }

    /// Uploads, draws and writes frame `frame`.
    pub fn frame(
        &mut self,
        frame: u32,
        camera: &Camera,
        sel: &Selection,
        pool: &TilePool,
    ) -> anyhow::Result<RenderRecord> {
        let r = &mut self.renderer;
        r.slots.touch(&sel.tiles);
        let started = Instant::now();
        let uploads = r.upload_wanted(pool, &sel.wanted, self.setup.upload_budget);
        let upload_ms = started.elapsed().as_secs_f64() * 1e3;
        let mut rec = RenderRecord {
            uploads,
            upload_ms,
            ..RenderRecord::default()
        };
        let name = format!("frame_{frame:05}.png");
        let measured = self.needs_reference(frame);
        if self.setup.draws == Draws::Reference && !measured {
            rec.gpu_tiles = self.renderer.slots.len();
            return Ok(rec);
        }
        if self.setup.draws == Draws::Reference {
            let (d, tris) = self.draw_reference(camera, pool)?;
            rec.draw_calls = d;
            rec.reference_triangles = Some(tris);
        } else {
            let d = self.renderer.draw(camera, &sel.patches)?;
            rec.draw_calls = d.draw_calls;
            rec.render_ms = d.render_ms;
        }
        let (w, h) = (self.renderer.width(), self.renderer.height());
        let image = self.renderer.read_rgba()?;
        if self.setup.write_frames {
            write_frame(&self.setup.out_dir.join(&name), &image, w, h)?;
        }
        if self.setup.draws == Draws::Popping {
            // What selection decided, not the inner LODs transitions raise for a
            // while (those change continuously, as the factors do).
            let key = SelectionKey::new(&sel.tiles, &sel.chosen);
            rec.selection_changed = self.popping.add(image.clone(), key)?;
            let previous = self.previous_patches.replace(sel.patches.clone());
            if let (Some(changed), Some(previous)) = (rec.selection_changed, previous) {
                let d = self.renderer.draw(camera, &previous)?;
                anyhow::ensure!(
                    d.skipped == 0,
                    "the previous frame's tiles are no longer on the GPU; raise --gpu-tiles"
                );
                let again = self.renderer.read_rgba()?;
                self.popping.add_same_camera(&image, &again, changed)?;
            }
        }
        if self.setup.draws == Draws::Quality && measured {
            let (reference, tris) = self.reference_image(camera, pool)?;
            if self.setup.write_frames {
                write_frame(
                    &self.setup.out_dir.join("reference").join(&name),
                    &reference,
                    w,
                    h,
                )?;
            }
            let mse = quality::mse(&image, &reference);
            rec.mse = Some(mse);
            rec.psnr = Some(quality::psnr(mse));
            rec.crack_pixels = Some(quality::crack_pixels(&image, &reference, w, h));
            rec.reference_triangles = Some(tris);
        }
        rec.gpu_tiles = self.renderer.slots.len();
        Ok(rec)
    }

    /// Uploads what `wanted` asks for, without a time budget (settling a measured
    /// frame). Returns the tiles uploaded.
    pub fn upload_all(&mut self, pool: &TilePool, wanted: &[Wanted]) -> u32 {
        self.renderer.upload_wanted(pool, wanted, Duration::MAX)
    }

    /// Whether the reference of `camera` is in the cache (its tiles need not be fetched).
    pub fn has_cached_reference(&self, camera: &Camera) -> bool {
        self.setup.draws == Draws::Quality
            && self.setup.reference_cache.as_ref().is_some_and(|dir| {
                let base = dir.join(self.reference_key(camera));
                base.with_extension("png").is_file() && base.with_extension("json").is_file()
            })
    }

    /// The reference image of this camera and its triangles: from the cache when it
    /// holds them, else drawn (and then cached).
    fn reference_image(
        &mut self,
        camera: &Camera,
        pool: &TilePool,
    ) -> anyhow::Result<(Vec<u8>, u64)> {
        let cached = self
            .setup
            .reference_cache
            .as_ref()
            .map(|dir| dir.join(self.reference_key(camera)));
        if let Some(base) = &cached {
            let (png, meta) = (base.with_extension("png"), base.with_extension("json"));
            if png.is_file() && meta.is_file() {
                let (rgba, w, h) = png_out::read_png(&png)?;
                let tris: u64 = serde_json::from_slice::<serde_json::Value>(&std::fs::read(&meta)?)
                    .ok()
                    .and_then(|v| v["triangles"].as_u64())
                    .with_context(|| format!("{}: no \"triangles\"", meta.display()))?;
                if (w, h) == (self.renderer.width(), self.renderer.height()) {
                    return Ok((rgba, tris));
                }
            }
        }
        let (_, tris) = self.draw_reference(camera, pool)?;
        let rgba = self.renderer.read_rgba()?;
        if let Some(base) = &cached {
            if let Some(dir) = base.parent() {
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("{}: cannot create", dir.display()))?;
            }
            let (w, h) = (self.renderer.width(), self.renderer.height());
            // The sidecar last: it marks the PNG as complete.
            png_out::write_png(&base.with_extension("png"), &rgba, w, h)?;
            std::fs::write(
                base.with_extension("json"),
                serde_json::json!({ "triangles": tris }).to_string(),
            )?;
        }
        Ok((rgba, tris))
    }

    /// The cache key of a reference image: everything that decides its pixels.
    fn reference_key(&self, camera: &Camera) -> String {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        let w = &self.renderer.world;
        let g = &w.geometry;
        (g.width(), g.height(), g.tile_size()).hash(&mut h);
        for v in [
            w.spacing.x,
            w.spacing.y,
            w.quant.scale,
            w.quant.offset,
            self.heights.0,
            self.heights.1,
            camera.position.x,
            camera.position.y,
            camera.position.z,
            camera.yaw,
            camera.pitch,
            camera.fovy,
            camera.near,
            camera.far,
        ] {
            v.to_bits().hash(&mut h);
        }
        (camera.width, camera.height).hash(&mut h);
        (self.renderer.opts.view as u32).hash(&mut h);
        format!("reference-{:016x}", h.finish())
    }

    /// Fetches (waiting for them) and uploads every finest tile in view, then draws
    /// them at full resolution without parallax (the ground truth every parallax mode
    /// is compared with). Returns draw calls and triangles.
    fn draw_reference(&mut self, camera: &Camera, pool: &TilePool) -> anyhow::Result<(u32, u64)> {
        let world = self.renderer.world;
        let frustum = world.frustum(camera);
        let mut tiles = finest_tiles_in_view(&world, &frustum, self.heights);
        // Absent tiles (wholly no-data) have nothing to draw.
        tiles.retain(|t| !pool.is_absent(*t));
        // The flight fetched these before the frame ([`fetch_reference_tiles`]).
        let missing = tiles.iter().filter(|t| !pool.contains(**t)).count();
        anyhow::ensure!(
            missing == 0,
            "{missing} finest tiles in view are not resident for the reference; raise --pool-tiles"
        );
        self.renderer.slots.touch(&tiles);
        for &t in &tiles {
            anyhow::ensure!(
                self.renderer.upload(pool, t),
                "no GPU slot left for the reference's tiles; raise --gpu-tiles"
            );
        }
        self.renderer.slots.touch(&tiles);
        let patches = full_resolution_patches(&world, &tiles, pool, &frustum);
        let tris = patches.iter().map(crate::select::Patch::triangles).sum();
        let parallax = std::mem::replace(&mut self.renderer.opts.parallax, Parallax::None);
        let d = self.renderer.draw(camera, &patches);
        self.renderer.opts.parallax = parallax;
        let d = d?;
        Ok((d.draw_calls, tris))
    }
}

impl FrameDrawer for Headless {
    fn upload_preloaded(
        &mut self,
        selector: &mut Selector,
        camera: &Camera,
        pool: &TilePool,
        t: f64,
    ) {
        while self.upload_all(
            pool,
            &selector.select_at(camera, &self.tables(pool), t).wanted,
        ) > 0
        {}
    }

    fn settles(&self, frame: u32) -> bool {
        Headless::settles(self, frame)
    }

    fn select(
        &self,
        selector: &mut Selector,
        camera: &Camera,
        pool: &TilePool,
        t: f64,
    ) -> Selection {
        selector.select_at(camera, &self.tables(pool), t)
    }

    fn upload_all(&mut self, pool: &TilePool, wanted: &[Wanted]) -> u32 {
        Headless::upload_all(self, pool, wanted)
    }

    fn draw(
        &mut self,
        frame: u32,
        camera: &Camera,
        sel: &Selection,
        pool: &mut TilePool,
        streamer: &mut Streamer,
        settle: bool,
    ) -> anyhow::Result<RenderRecord> {
        if self.needs_reference(frame) && !self.has_cached_reference(camera) {
            fetch_reference_tiles(
                &self.renderer.world,
                self.heights,
                camera,
                pool,
                streamer,
                SETTLE_TIMEOUT,
            )?;
        }
        if let Some(feed) = &mut self.imagery {
            if settle {
                feed.settle(&sel.tiles, SETTLE_TIMEOUT);
            }
            feed.frame(&sel.tiles);
            self.renderer.upload_imagery_from(feed.pool(), &sel.tiles);
        }
        let mut rec = self.frame(frame, camera, sel, pool)?;
        rec.converged = sel.wanted.is_empty();
        Ok(rec)
    }

    fn summary(&self, rendered: &[(FrameStats, RenderRecord)]) -> RenderSummary {
        RenderSummary {
            popping: self.popping(),
            ..RenderSummary::from_records(self.renderer.gpu.describe(), rendered)
        }
    }
}

/// The dataset's imagery feed, when it has imagery and the renderer is to drape it
/// (not `--no-imagery`), with `renderer` made ready to: one layer per GPU slot, so
/// the feed's pool holds as many tiles.
pub fn imagery_feed(
    renderer: &mut Renderer,
    streamer: &Streamer,
) -> anyhow::Result<Option<ImageryFeed>> {
    if !renderer.opts.imagery {
        return Ok(None);
    }
    let Some(feed) = streamer.imagery_feed(renderer.opts.slots as usize) else {
        return Ok(None);
    };
    renderer.enable_imagery(feed.texels())?;
    Ok(Some(feed))
}

/// Writes a frame for people to look at: the sky painted in.
fn write_frame(path: &std::path::Path, rgba: &[u8], w: u32, h: u32) -> anyhow::Result<()> {
    let mut shown = rgba.to_vec();
    quality::paint_sky(&mut shown, w, h);
    png_out::write_png(path, &shown, w, h)
}

/// Fetches every finest tile in `camera`'s view into the pool, waiting up to
/// `timeout` (the reference needs them all; this is a measurement, not a flight).
pub fn fetch_reference_tiles(
    world: &World,
    heights: (f64, f64),
    camera: &Camera,
    pool: &mut TilePool,
    streamer: &mut Streamer,
    timeout: Duration,
) -> anyhow::Result<()> {
    let tiles = finest_tiles_in_view(world, &world.frustum(camera), heights);
    fetch_tiles(&tiles, pool, streamer, timeout)
}
