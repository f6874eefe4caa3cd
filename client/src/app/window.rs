//! The windowed client (`tessera fly --server URL --dataset NAME`, or `--pyramid
//! URL`): a winit window
//! flown with the mouse and keyboard, the same selection, streaming and renderer as
//! the headless client, statistics in the title bar.
//!
//! Keys: mouse drag looks around; W/S forward/back, A/D sideways, E/Q up/down,
//! Shift ×5 speed; `+`/`-` raise/lower τ; 1–5 shaded/LOD/level/wireframe/mask
//! (non-terrain cells in red instead of discarded); P cycles parallax; Escape quits.

use super::fly::FlyOptions;
use crate::camera::Camera;
use crate::render::gpu::Gpu;
use crate::render::present::Presenter;
use crate::render::slots::OnGpu;
use crate::render::{DebugView, Parallax, RenderOptions, Renderer};
use crate::select::{SelectParams, Selector};
use crate::stream::Streamer;
use crate::stream::pool::TilePool;
use anyhow::Context;
use glam::DVec3;
use std::collections::HashSet;
use std::sync::Arc;
use std::time::Instant;
use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Window, WindowId};

/// Opens the window and flies until it is closed.
pub fn run(opts: &FlyOptions, render: RenderOptions) -> anyhow::Result<()> {
    let event_loop = EventLoop::new().context(
        "cannot open a window (no display?); render headless with --out DIR, or use --no-render",
    )?;
    let mut app = App {
        opts: opts.clone(),
        render,
        display: Some(Box::new(event_loop.owned_display_handle())),
        state: None,
        error: None,
    };
    event_loop
        .run_app(&mut app)
        .context("the window's event loop failed")?;
    app.error.map_or(Ok(()), Err)
}

struct App {
    opts: FlyOptions,
    render: RenderOptions,
    display: Option<Box<dyn wgpu::wgt::WgpuHasDisplayHandle>>,
    state: Option<State>,
    error: Option<anyhow::Error>,
}

struct State {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    renderer: Renderer,
    presenter: Presenter,
    streamer: Streamer,
    imagery: Option<crate::stream::imagery_tiles::ImageryFeed>,
    pool: TilePool,
    selector: Selector,
    camera: Camera,
    keys: HashSet<KeyCode>,
    dragging: bool,
    cursor: Option<(f64, f64)>,
    last: Instant,
    /// When the window opened: the clock of geomorph transitions.
    started: Instant,
    fps: (u32, Instant, f64),
    dataset: String,
}

impl State {
    fn new(
        event_loop: &ActiveEventLoop,
        opts: &FlyOptions,
        render: RenderOptions,
        display: Box<dyn wgpu::wgt::WgpuHasDisplayHandle>,
    ) -> anyhow::Result<Self> {
        let (
            mut streamer,
            super::fly::DatasetView {
                world,
                min_height: min_h,
                max_height: max_h,
            },
        ) = super::fly::open(opts)?;
        let window = Arc::new(
            event_loop
                .create_window(
                    Window::default_attributes()
                        .with_title(format!("Tessera — {}", opts.source.name()))
                        .with_inner_size(winit::dpi::PhysicalSize::new(
                            render.width,
                            render.height,
                        )),
                )
                .context("cannot create a window")?,
        );
        let instance = wgpu::Instance::new(
            wgpu::InstanceDescriptor::new_without_display_handle_from_env()
                .with_display_handle(display),
        );
        let surface = instance
            .create_surface(window.clone())
            .context("cannot draw into the window")?;
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            compatible_surface: Some(&surface),
            ..Default::default()
        }))
        .context("no GPU adapter can draw into this window")?;
        let gpu = Gpu::from_adapter(&adapter)?;
        let size = window.inner_size();
        let mut config = surface
            .get_default_config(&adapter, size.width.max(1), size.height.max(1))
            .context("the window's surface is not supported by the GPU adapter")?;
        // The renderer's colours are meant as they are (like the PNGs): prefer a
        // surface format that does not gamma-encode them again.
        let plain = config.format.remove_srgb_suffix();
        if surface.get_capabilities(&adapter).formats.contains(&plain) {
            config.format = plain;
        }
        surface.configure(&gpu.device, &config);
        let presenter = Presenter::new(&gpu.device, config.format);
        let mut renderer = Renderer::with_gpu(
            gpu,
            world,
            (min_h, max_h),
            RenderOptions {
                width: config.width,
                height: config.height,
                ..render
            },
        )?;
        // The dataset's imagery, draped on the drawn tiles as it arrives (Yang §3).
        let imagery = super::headless::imagery_feed(&mut renderer, &streamer)?;
        let extent = world.size_m().max_element();
        let camera = Camera {
            position: DVec3::new(0.1 * extent, max_h + extent / 20.0, 0.1 * extent),
            yaw: 135f64.to_radians(),
            pitch: -0.35,
            fovy: 60f64.to_radians(),
            width: config.width,
            height: config.height,
            near: 1.0,
            far: 4.0 * extent + 1e5,
        };
        // What the open fetched (the bootstrap's levels) is drawn from the first frame.
        let mut pool = TilePool::new(opts.pool_tiles);
        streamer.preload(&mut pool);
        Ok(Self {
            window,
            surface,
            config,
            renderer,
            presenter,
            streamer,
            imagery,
            pool,
            selector: Selector::new(
                world,
                SelectParams {
                    tau: opts.tau,
                    morph_seconds: opts.morph_seconds,
                    morph_by_distance: opts.morph_by_distance,
                    morph_error_limit: opts.morph_error_limit,
                    ..SelectParams::default()
                },
            ),
            camera,
            keys: HashSet::new(),
            dragging: false,
            cursor: None,
            last: Instant::now(),
            started: Instant::now(),
            fps: (0, Instant::now(), 0.0),
            dataset: opts.source.name().to_string(),
        })
    }

    fn resize(&mut self, width: u32, height: u32) {
        if width == 0 || height == 0 {
            return;
        }
        self.config.width = width;
        self.config.height = height;
        self.surface
            .configure(&self.renderer.gpu.device, &self.config);
        self.renderer.resize(width, height);
        self.camera.width = width;
        self.camera.height = height;
    }

    fn key(&mut self, code: KeyCode, pressed: bool) {
        if !pressed {
            self.keys.remove(&code);
            return;
        }
        self.keys.insert(code);
        let p = &mut self.selector.params;
        let opts = &mut self.renderer.opts;
        match code {
            KeyCode::Equal | KeyCode::NumpadAdd => p.tau = (p.tau * 1.5).min(64.0),
            KeyCode::Minus | KeyCode::NumpadSubtract => p.tau = (p.tau / 1.5).max(0.25),
            KeyCode::Digit1 => opts.view = DebugView::Shaded,
            KeyCode::Digit2 => opts.view = DebugView::Lod,
            KeyCode::Digit3 => opts.view = DebugView::Level,
            KeyCode::Digit4 => opts.view = DebugView::Wireframe,
            KeyCode::Digit5 => opts.view = DebugView::Mask,
            KeyCode::KeyP => {
                opts.parallax = match opts.parallax {
                    Parallax::None => Parallax::Offset,
                    Parallax::Offset => Parallax::Iterative,
                    Parallax::Iterative => Parallax::Binary,
                    Parallax::Binary => Parallax::None,
                }
            }
            _ => {}
        }
    }

    fn look(&mut self, x: f64, y: f64) {
        if let Some((px, py)) = self.cursor
            && self.dragging
        {
            self.camera.yaw += (x - px) * 0.003;
            self.camera.pitch = (self.camera.pitch - (y - py) * 0.003).clamp(-1.55, 1.55);
        }
        self.cursor = Some((x, y));
    }

    /// Moves the camera, selects, streams, uploads, draws and presents one frame.
    fn frame(&mut self, budget: std::time::Duration) -> anyhow::Result<()> {
        let dt = self.last.elapsed().as_secs_f64().min(0.25);
        self.last = Instant::now();
        let world = self.selector.world;
        let ground = self
            .pool
            .ground_height(&world, self.camera.position.x, self.camera.position.z)
            .unwrap_or(0.0);
        let agl = (self.camera.position.y - ground).max(1.0);
        let boost = if self.keys.contains(&KeyCode::ShiftLeft) {
            5.0
        } else {
            1.0
        };
        let speed = agl.max(50.0) * boost * dt;
        let (s, c) = self.camera.yaw.sin_cos();
        let forward = DVec3::new(s, 0.0, -c);
        let right = DVec3::new(c, 0.0, s);
        let held = |k| f64::from(u8::from(self.keys.contains(&k)));
        let mv = forward * (held(KeyCode::KeyW) - held(KeyCode::KeyS))
            + right * (held(KeyCode::KeyD) - held(KeyCode::KeyA))
            + DVec3::Y * (held(KeyCode::KeyE) - held(KeyCode::KeyQ));
        self.camera.position += mv * speed;
        self.camera.position.y = self.camera.position.y.max(ground + 2.0);

        // Geomorph transitions run on the wall clock.
        let sel = self.selector.select_at(
            &self.camera,
            &OnGpu {
                pool: &self.pool,
                slots: &self.renderer.slots,
            },
            self.started.elapsed().as_secs_f64(),
        );
        self.pool.touch(&sel.tiles);
        self.streamer.frame(&mut self.pool, &sel.wanted, &[]);
        self.renderer.slots.touch(&sel.tiles);
        self.renderer.upload_wanted(&self.pool, &sel.wanted, budget);
        if let Some(feed) = &mut self.imagery {
            feed.frame(&sel.tiles);
            self.renderer.upload_imagery_from(feed.pool(), &sel.tiles);
        }
        let d = self.renderer.draw(&self.camera, &sel.patches)?;
        let frame = match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t)
            | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                self.surface
                    .configure(&self.renderer.gpu.device, &self.config);
                return Ok(());
            }
            _ => return Ok(()),
        };
        let view = frame
            .texture
            .create_view(&wgpu::TextureViewDescriptor::default());
        let gpu = &self.renderer.gpu;
        self.presenter
            .blit(&gpu.device, &gpu.queue, self.renderer.colour(), &view);
        gpu.queue.present(frame);
        gpu.check()?;

        self.fps.0 += 1;
        let since = self.fps.1.elapsed().as_secs_f64();
        if since >= 0.5 {
            self.fps = (0, Instant::now(), f64::from(self.fps.0) / since);
        }
        self.window.set_title(&format!(
            "Tessera — {} — {:.0} fps · {} triangles · {} draws · τ {:.2} · deficit {} · {} tiles ({} on GPU) · {:?}, parallax {:?}",
            self.dataset,
            self.fps.2,
            sel.stats.triangles,
            d.draw_calls,
            self.selector.params.tau,
            // Unbounded while tiles are missing: say so rather than print a number.
            sel.stats.deficit.map_or_else(
                || format!("missing ({} tiles)", sel.stats.missing),
                |d| format!("{:.2}", d.min(999.0))
            ),
            self.pool.len(),
            self.renderer.slots.len(),
            self.renderer.opts.view,
            self.renderer.opts.parallax,
        ));
        Ok(())
    }
}

impl App {
    fn fail(&mut self, event_loop: &ActiveEventLoop, e: anyhow::Error) {
        self.error = Some(e);
        event_loop.exit();
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.state.is_some() {
            return;
        }
        let Some(display) = self.display.take() else {
            return;
        };
        match State::new(event_loop, &self.opts, self.render, display) {
            Ok(s) => self.state = Some(s),
            Err(e) => self.fail(event_loop, e),
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        let Some(state) = self.state.as_mut() else {
            return;
        };
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) => state.resize(size.width, size.height),
            WindowEvent::KeyboardInput { event, .. } => {
                if let PhysicalKey::Code(code) = event.physical_key {
                    if code == KeyCode::Escape {
                        event_loop.exit();
                    }
                    state.key(code, event.state == ElementState::Pressed);
                }
            }
            WindowEvent::MouseInput {
                button: MouseButton::Left,
                state: pressed,
                ..
            } => state.dragging = pressed == ElementState::Pressed,
            WindowEvent::CursorMoved { position, .. } => state.look(position.x, position.y),
            WindowEvent::RedrawRequested => {
                let budget = self.opts.stream.budget;
                if let Err(e) = state.frame(budget) {
                    self.fail(event_loop, e);
                }
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, _: &ActiveEventLoop) {
        if let Some(s) = &self.state {
            s.window.request_redraw();
        }
    }
}
