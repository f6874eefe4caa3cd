//! The wgpu renderer (DESIGN §5): emulated tessellation with at most 7 instanced
//! terrain draws per frame.
//!
//! - Heights live in an `R16Unorm` 2-D texture array, one layer ("slot") per
//!   resident tile ([`slots`]), with a normal map beside it ([`normals`]).
//! - One index buffer range per inner LOD `n ∈ {1, 2, …, 64}`; the vertex shader
//!   derives grid coordinates from the vertex index and reads heights with integer
//!   texel loads, snapping edge vertices as the reference tessellator does
//!   (`terrain.wgsl`, [`crate::tessellate`]).
//! - Parallax in the fragment shader (González §2.2–2.4) moves where the normal
//!   and height maps are read.
//!
//! Rendering is offscreen into an RGBA8 target; [`Renderer::read_rgba`] reads it
//! back for PNGs and quality measures, and the windowed client copies it to the
//! window.

pub mod gpu;
pub mod instances;
pub mod normals;
pub mod png_out;
pub mod present;
pub mod quality;
pub mod reference;
pub mod slots;

use crate::camera::Camera;
use crate::select::{Patch, Wanted, World};
use crate::stream::pool::TilePool;
use crate::tessellate::Vertex;
use anyhow::Context;
use glam::DVec3;
use gpu::{Backend, Gpu};
use instances::{Batches, Instance};
use slots::SlotTable;
use std::time::{Duration, Instant};
use tessera_shared::TileId;
use wgpu::util::DeviceExt;

/// What the fragment shader shows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DebugView {
    /// Lambert lighting with a hypsometric tint.
    #[default]
    Shaded,
    /// Colour by inner LOD.
    Lod,
    /// Colour by pyramid level.
    Level,
    /// Shaded, with the triangles drawn over it.
    Wireframe,
}

/// Parallax mapping over the tessellated base surface (González §2.2–2.4).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Parallax {
    #[default]
    None,
    /// Offset limiting (threshold 0.5).
    Offset,
    /// Two iterations of offset parallax.
    Iterative,
    /// Binary search, 3 steps, then a secant step.
    Binary,
}

#[derive(Clone, Copy, Debug)]
pub struct RenderOptions {
    pub width: u32,
    pub height: u32,
    /// Tiles the GPU holds at once (texture-array layers).
    pub slots: u32,
    pub view: DebugView,
    pub parallax: Parallax,
    pub backend: Backend,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            width: 1280,
            height: 720,
            slots: 256,
            view: DebugView::Shaded,
            parallax: Parallax::None,
            backend: Backend::Auto,
        }
    }
}

/// What one frame cost and drew.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct DrawStats {
    pub draw_calls: u32,
    pub instances: u32,
    /// Patches whose tile had no GPU slot (0 when selection used [`slots::OnGpu`]).
    pub skipped: u32,
    /// CPU time to encode and submit, and wait for the GPU, in milliseconds.
    pub render_ms: f64,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct Globals {
    view_proj: [[f32; 4]; 4],
    eye_cell: [i32; 4],
    eye_frac: [f32; 4],
    quant: [f32; 4],
    sun: [f32; 4],
    haze: [f32; 4],
    mode: [u32; 4],
}

const COLOUR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Texture-array layer count for `slots` tiles. On GL, wgpu guesses a texture's
/// view type from its layer count: one layer becomes a plain 2-D texture and a
/// multiple of six a cube map, and viewing either as an array samples zeros
/// (PLATFORM.md). Avoid both.
fn layer_count(slots: u32) -> u32 {
    let mut n = slots.max(2);
    while n.is_multiple_of(6) {
        n += 1;
    }
    n
}

#[derive(Debug)]
pub struct Renderer {
    pub gpu: Gpu,
    pub world: World,
    pub opts: RenderOptions,
    pub slots: SlotTable,
    height_range: (f64, f64),
    heights: wgpu::Texture,
    normals: wgpu::Texture,
    globals: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    layout: wgpu::BindGroupLayout,
    capture_layout: wgpu::BindGroupLayout,
    module: wgpu::ShaderModule,
    pipeline: wgpu::RenderPipeline,
    index: wgpu::Buffer,
    lod_ranges: [std::ops::Range<u32>; 7],
    instances: Option<(wgpu::Buffer, u64)>,
    colour: wgpu::Texture,
    depth: wgpu::Texture,
}

impl Renderer {
    /// A renderer for `world` with heights in `height_range` (metres, for the tint).
    pub fn new(
        world: World,
        height_range: (f64, f64),
        opts: RenderOptions,
    ) -> anyhow::Result<Self> {
        Self::with_gpu(Gpu::new(opts.backend)?, world, height_range, opts)
    }

    /// A renderer on an already opened device.
    pub fn with_gpu(
        gpu: Gpu,
        world: World,
        height_range: (f64, f64),
        opts: RenderOptions,
    ) -> anyhow::Result<Self> {
        anyhow::ensure!(
            opts.width > 0 && opts.height > 0,
            "viewport {}x{} is empty",
            opts.width,
            opts.height
        );
        let dim = gpu.limits.max_texture_dimension_2d;
        anyhow::ensure!(
            opts.width <= dim && opts.height <= dim,
            "viewport {}x{} exceeds this GPU's {dim}-pixel limit",
            opts.width,
            opts.height
        );
        let samples = world.geometry.tile_samples() as u32;
        let layers = layer_count(opts.slots).min(gpu.limits.max_texture_array_layers);
        anyhow::ensure!(
            samples <= dim,
            "{samples}-sample tiles exceed this GPU's {dim}-texel limit"
        );
        let device = &gpu.device;
        let array = |label, format| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d {
                    width: samples,
                    height: samples,
                    depth_or_array_layers: layers,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            })
        };
        let heights = array("heights", wgpu::TextureFormat::R16Unorm);
        let normals = array("normals", wgpu::TextureFormat::Rg8Snorm);
        let globals = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("globals"),
            size: size_of::<Globals>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("linear clamp"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let all = wgpu::ShaderStages::VERTEX_FRAGMENT | wgpu::ShaderStages::COMPUTE;
        let texture_entry = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: all,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: true },
                view_dimension: wgpu::TextureViewDimension::D2Array,
                multisampled: false,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("terrain"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: all,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                texture_entry(1),
                texture_entry(2),
                wgpu::BindGroupLayoutEntry {
                    binding: 3,
                    visibility: all,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let array_view = |t: &wgpu::Texture| {
            t.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2Array),
                ..Default::default()
            })
        };
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("terrain"),
            layout: &layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: globals.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&array_view(&heights)),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&array_view(&normals)),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::Sampler(&sampler),
                },
            ],
        });
        let storage = |binding, read_only| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let capture_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("capture"),
            entries: &[storage(0, true), storage(1, false), storage(2, true)],
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("terrain.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("terrain.wgsl").into()),
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("terrain"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let instance_layout = wgpu::VertexBufferLayout {
            array_stride: size_of::<Instance>() as u64,
            step_mode: wgpu::VertexStepMode::Instance,
            attributes: &wgpu::vertex_attr_array![0 => Uint32x4, 1 => Uint32x4],
        };
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("terrain"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_main"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                buffers: &[Some(instance_layout)],
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleList,
                cull_mode: None,
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Less),
                stencil: wgpu::StencilState::default(),
                bias: wgpu::DepthBiasState::default(),
            }),
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_main"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: COLOUR_FORMAT,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        let (index_data, lod_ranges) = instances::index_buffers();
        let index = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("lod indices"),
            contents: bytemuck::cast_slice(&index_data),
            usage: wgpu::BufferUsages::INDEX,
        });
        let (colour, depth) = targets(device, opts.width, opts.height);
        gpu.check().context("creating the renderer")?;
        Ok(Self {
            slots: SlotTable::new(layers),
            gpu,
            world,
            opts,
            height_range,
            heights,
            normals,
            globals,
            bind_group,
            layout,
            capture_layout,
            module,
            pipeline,
            index,
            lod_ranges,
            instances: None,
            colour,
            depth,
        })
    }

    /// Uploads a decoded tile (heights and a normal map built with its decoded
    /// neighbours) into a slot. `false` when every slot is in use this frame.
    pub fn upload(&mut self, pool: &TilePool, tile: TileId) -> bool {
        let Some(resident) = pool.get(tile) else {
            return false;
        };
        let Some(slot) = self.slots.allocate(tile) else {
            return false;
        };
        let g = self.world.geometry;
        let samples = g.tile_samples();
        let same_level = |dx: i64, dy: i64| {
            let (x, y) = (i64::from(tile.x()) + dx, i64::from(tile.y()) + dy);
            let t = TileId::new(tile.level(), u32::try_from(x).ok()?, u32::try_from(y).ok()?)?;
            pool.get(t).map(|r| r.heights.as_slice())
        };
        let neighbours = [
            same_level(0, -1),
            same_level(1, 0),
            same_level(0, 1),
            same_level(-1, 0),
        ];
        let metres = self.world.spacing * g.spacing(tile.level()) as f64;
        let normal_map = normals::normal_map(
            &resident.heights,
            samples,
            &neighbours,
            metres,
            self.world.quant.scale,
        );
        let write = |texture: &wgpu::Texture, data: &[u8], bytes_per_texel: u32| {
            self.gpu.queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d {
                        x: 0,
                        y: 0,
                        z: slot,
                    },
                    aspect: wgpu::TextureAspect::All,
                },
                data,
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(samples as u32 * bytes_per_texel),
                    rows_per_image: Some(samples as u32),
                },
                wgpu::Extent3d {
                    width: samples as u32,
                    height: samples as u32,
                    depth_or_array_layers: 1,
                },
            );
        };
        write(&self.heights, bytemuck::cast_slice(&resident.heights), 2);
        write(&self.normals, bytemuck::cast_slice(&normal_map), 2);
        true
    }

    /// Uploads the wanted tiles that are decoded but not on the GPU, within
    /// `budget` (at least one, so a slow frame still makes progress): coarse levels
    /// first so ancestors arrive before descendants, then the most wanted.
    /// Returns how many were uploaded.
    pub fn upload_wanted(&mut self, pool: &TilePool, wanted: &[Wanted], budget: Duration) -> u32 {
        let started = Instant::now();
        let mut todo: Vec<&Wanted> = wanted
            .iter()
            .filter(|w| pool.contains(w.tile) && self.slots.get(w.tile).is_none())
            .collect();
        todo.sort_by(|a, b| {
            a.tile
                .level()
                .cmp(&b.tile.level())
                .then(b.rho.total_cmp(&a.rho))
        });
        let mut uploads = 0;
        for w in todo {
            if uploads > 0 && started.elapsed() >= budget {
                break;
            }
            if self.upload(pool, w.tile) {
                uploads += 1;
            }
        }
        uploads
    }

    fn write_globals(&self, camera: &Camera) {
        let s = self.world.spacing;
        let p = camera.position;
        let cell = (p.x / s).floor().max(0.0).min(f64::from(i32::MAX));
        let cell_z = (p.z / s).floor().max(0.0).min(f64::from(i32::MAX));
        let view = glam::DMat4::look_to_rh(DVec3::ZERO, camera.forward(), DVec3::Y);
        let vp = (camera.projection() * view).as_mat4();
        // A low sun from the north-west brings out relief.
        let sun = DVec3::new(-0.7, 0.42, -0.58).normalize().as_vec3();
        let extent = f64::from(
            self.world
                .geometry
                .width()
                .max(self.world.geometry.height()),
        ) * s;
        let q = self.world.quant;
        let globals = Globals {
            view_proj: vp.to_cols_array_2d(),
            eye_cell: [cell as i32, cell_z as i32, 0, 0],
            eye_frac: [
                (p.x - cell * s) as f32,
                p.y as f32,
                (p.z - cell_z * s) as f32,
                s as f32,
            ],
            quant: [
                q.offset as f32,
                q.scale as f32,
                self.height_range.0 as f32,
                self.height_range.1 as f32,
            ],
            sun: [sun.x, sun.y, sun.z, 0.0],
            haze: [0.74, 0.80, 0.88, extent as f32],
            mode: [
                self.opts.view as u32,
                self.opts.parallax as u32,
                self.world.geometry.tile_size(),
                0,
            ],
        };
        self.gpu
            .queue
            .write_buffer(&self.globals, 0, bytemuck::bytes_of(&globals));
    }

    /// Draws `patches` seen from `camera` into the offscreen target and waits for
    /// the GPU.
    pub fn draw(&mut self, camera: &Camera, patches: &[Patch]) -> anyhow::Result<DrawStats> {
        let started = Instant::now();
        self.write_globals(camera);
        let g = self.world.geometry;
        let batches = Batches::build(&g, patches, |p| self.slots.get(p.tile));
        let bytes = bytemuck::cast_slice::<Instance, u8>(&batches.instances);
        let device = &self.gpu.device;
        if !bytes.is_empty() {
            let needed = bytes.len() as u64;
            if self.instances.as_ref().is_none_or(|(_, cap)| *cap < needed) {
                let cap = needed.next_power_of_two().max(4096);
                let buffer = device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("instances"),
                    size: cap,
                    usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                });
                self.instances = Some((buffer, cap));
            }
            if let Some((buffer, _)) = &self.instances {
                self.gpu.queue.write_buffer(buffer, 0, bytes);
            }
        }
        let draws = batches.draws();
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("frame"),
        });
        {
            let colour_view = self
                .colour
                .create_view(&wgpu::TextureViewDescriptor::default());
            let depth_view = self
                .depth
                .create_view(&wgpu::TextureViewDescriptor::default());
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("terrain"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &colour_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color {
                            r: 1.0,
                            g: 0.0,
                            b: 1.0,
                            a: 1.0,
                        }),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(1.0),
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            if let Some((buffer, _)) = &self.instances
                && !draws.is_empty()
            {
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &self.bind_group, &[]);
                pass.set_vertex_buffer(0, buffer.slice(..));
                pass.set_index_buffer(self.index.slice(..), wgpu::IndexFormat::Uint16);
                for &(n, first, count) in &draws {
                    let k = n.trailing_zeros() as usize;
                    pass.draw_indexed(self.lod_ranges[k].clone(), 0, first..first + count);
                }
            }
        }
        self.gpu.queue.submit([encoder.finish()]);
        self.gpu.wait().context("rendering a frame")?;
        Ok(DrawStats {
            draw_calls: draws.len() as u32,
            instances: batches.instances.len() as u32,
            skipped: batches.skipped as u32,
            render_ms: started.elapsed().as_secs_f64() * 1e3,
        })
    }

    /// The last frame as tightly packed RGBA8 rows.
    pub fn read_rgba(&self) -> anyhow::Result<Vec<u8>> {
        let (w, h) = (self.opts.width, self.opts.height);
        let row = w * 4;
        let padded =
            row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let device = &self.gpu.device;
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: u64::from(padded) * u64::from(h),
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("readback"),
        });
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &self.colour,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(padded),
                    rows_per_image: Some(h),
                },
            },
            wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
        );
        self.gpu.queue.submit([encoder.finish()]);
        let data = map_read(&self.gpu, &buffer)?;
        let mut out = Vec::with_capacity((row * h) as usize);
        for y in 0..h as usize {
            out.extend_from_slice(&data[y * padded as usize..][..row as usize]);
        }
        Ok(out)
    }

    /// Runs the vertex shader's own `terrain_vertex` over every vertex of every
    /// patch (a compute pass over the same WGSL function) and returns what it
    /// produced, patch by patch, in the reference tessellator's order.
    pub fn capture_vertices(&self, patches: &[Patch]) -> anyhow::Result<Vec<Vec<Vertex>>> {
        let g = self.world.geometry;
        let mut jobs: Vec<Instance> = Vec::new();
        let mut vids: Vec<u32> = Vec::new();
        for p in patches {
            let slot = self
                .slots
                .get(p.tile)
                .with_context(|| format!("tile {} has no GPU slot", p.tile))?;
            let inst = Instance::new(&g, p, slot);
            for vid in 0..(p.inner + 1) * (p.inner + 1) {
                jobs.push(inst);
                vids.push(vid);
            }
        }
        anyhow::ensure!(!vids.is_empty(), "no vertices to capture");
        let device = &self.gpu.device;
        let init = |label, contents: &[u8], usage| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage,
            })
        };
        let jobs_buf = init(
            "capture jobs",
            bytemuck::cast_slice(&jobs),
            wgpu::BufferUsages::STORAGE,
        );
        let vids_buf = init(
            "capture vids",
            bytemuck::cast_slice(&vids),
            wgpu::BufferUsages::STORAGE,
        );
        let size = vids.len() as u64 * 16;
        let out = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("captured"),
            size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let read = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("captured readback"),
            size,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("capture"),
            layout: &self.capture_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: jobs_buf.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: out.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: vids_buf.as_entire_binding(),
                },
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("capture"),
            bind_group_layouts: &[Some(&self.layout), Some(&self.capture_layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("capture"),
            layout: Some(&layout),
            module: &self.module,
            entry_point: Some("capture"),
            compilation_options: wgpu::PipelineCompilationOptions::default(),
            cache: None,
        });
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("capture"),
        });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("capture"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &self.bind_group, &[]);
            pass.set_bind_group(1, &group, &[]);
            let groups = (vids.len() as u32).div_ceil(64);
            // Spread over two dimensions past the 65535-workgroup limit.
            let (x, y) = (groups.min(65_535), groups.div_ceil(65_535));
            anyhow::ensure!(
                y == 1,
                "too many vertices to capture at once ({})",
                vids.len()
            );
            pass.dispatch_workgroups(x, 1, 1);
        }
        encoder.copy_buffer_to_buffer(&out, 0, &read, 0, size);
        self.gpu.queue.submit([encoder.finish()]);
        let data = map_read(&self.gpu, &read)?;
        let words: &[u32] = bytemuck::cast_slice(&data);
        let mut k = 0;
        let mut result = Vec::with_capacity(patches.len());
        for p in patches {
            let count = ((p.inner + 1) * (p.inner + 1)) as usize;
            result.push(
                (0..count)
                    .map(|i| {
                        let w = &words[(k + i) * 4..];
                        Vertex {
                            x: u64::from(w[0]),
                            y: u64::from(w[1]),
                            q: w[2] as u16,
                        }
                    })
                    .collect(),
            );
            k += count;
        }
        Ok(result)
    }

    pub fn width(&self) -> u32 {
        self.opts.width
    }

    /// The offscreen frame (RGBA8), for presenting to a window.
    pub fn colour(&self) -> &wgpu::Texture {
        &self.colour
    }

    /// Resizes the offscreen targets (a window was resized).
    pub fn resize(&mut self, width: u32, height: u32) {
        if width == 0 || height == 0 || (width, height) == (self.opts.width, self.opts.height) {
            return;
        }
        self.opts.width = width;
        self.opts.height = height;
        (self.colour, self.depth) = targets(&self.gpu.device, width, height);
    }

    pub fn height(&self) -> u32 {
        self.opts.height
    }
}

fn targets(device: &wgpu::Device, width: u32, height: u32) -> (wgpu::Texture, wgpu::Texture) {
    let make = |label, format, usage| {
        device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        })
    };
    (
        make(
            "colour",
            COLOUR_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::COPY_SRC
                | wgpu::TextureUsages::TEXTURE_BINDING,
        ),
        make(
            "depth",
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        ),
    )
}

/// Maps a buffer for reading after the submitted work, and copies it out.
fn map_read(gpu: &Gpu, buffer: &wgpu::Buffer) -> anyhow::Result<Vec<u8>> {
    let (tx, rx) = std::sync::mpsc::channel();
    buffer.map_async(wgpu::MapMode::Read, .., move |r| {
        let _ = tx.send(r);
    });
    gpu.wait()?;
    rx.recv()
        .context("GPU readback was dropped")?
        .map_err(|e| anyhow::anyhow!("GPU readback failed: {e}"))?;
    let data = buffer
        .get_mapped_range(..)
        .map_err(|e| anyhow::anyhow!("GPU readback failed: {e}"))?
        .to_vec();
    buffer.unmap();
    Ok(data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layer_counts_avoid_what_gl_misreads() {
        assert_eq!(layer_count(1), 2);
        assert_eq!(layer_count(6), 7);
        assert_eq!(layer_count(12), 13);
        assert_eq!(layer_count(256), 256);
    }
}
