//! The renderer's device objects and terrain pipeline (one bind group for the
//! globals, the height, normal and cell-mask arrays and a sampler; one index buffer
//! range per inner LOD), drawing a frame into the offscreen targets, and resizing
//! them.

use super::imagery::ImageryTextures;
use super::slots::SlotTable;
use super::{DrawStats, RenderOptions, Renderer, capture, gpu::Gpu, gpu_normals, instances};
use crate::camera::Camera;
use crate::select::{Patch, World};
use anyhow::Context;
use glam::DVec3;
use instances::{Batches, Instance};
use std::time::Instant;
use wgpu::util::DeviceExt;

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
    spacing: [f32; 4],
    globe: [f32; 4],
    to_local: [[f32; 4]; 3],
    air: [f32; 4],
}

/// How many times shorter the air's scale height is than the haze's visibility
/// distance (see `write_globals`).
const AIR_THINNING: f64 = 10.0;

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
        let cells = world.geometry.tile_size();
        let layers = layer_count(opts.slots).min(gpu.limits.max_texture_array_layers);
        anyhow::ensure!(
            samples <= dim,
            "{samples}-sample tiles exceed this GPU's {dim}-texel limit"
        );
        let device = &gpu.device;
        let array = |label, format, side, extra| {
            texture_array(device, label, format, (side, layers), extra)
        };
        let heights = array(
            "heights",
            wgpu::TextureFormat::R16Unorm,
            samples,
            wgpu::TextureUsages::empty(),
        );
        // Written by the normal-map compute pass (gpu_normals.rs).
        let normals = array(
            "normals",
            gpu_normals::NORMAL_FORMAT,
            samples,
            wgpu::TextureUsages::COPY_SRC | wgpu::TextureUsages::STORAGE_BINDING,
        );
        let normal_pass = gpu_normals::NormalPass::chosen(opts.normals, &gpu, &heights, &normals);
        // One texel per cell: 1.0 where the cell is terrain (FORMAT.md "Validity mask").
        let masks = array(
            "cell masks",
            wgpu::TextureFormat::R8Unorm,
            cells,
            wgpu::TextureUsages::empty(),
        );
        let globals = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("globals"),
            size: size_of::<Globals>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        // Rows and columns of the padded finest grid on the globe.
        let entries = match world.globe {
            Some(_) => world.geometry.padded_samples(),
            None => 1,
        };
        let table = |label| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: entries * 16,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let globe_tables = [table("globe rows"), table("globe columns")];
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
        let storage_entry = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: all,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: true },
                has_dynamic_offset: false,
                min_binding_size: None,
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
                texture_entry(4),
                storage_entry(5),
                storage_entry(6),
                // Imagery (imagery.rs): the layers, and one flag per slot.
                texture_entry(7),
                wgpu::BindGroupLayoutEntry {
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Uint,
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    ..texture_entry(8)
                },
            ],
        });
        let imagery = ImageryTextures::new(device, layers, 1);
        let bind_group = bind_group(
            device,
            &layout,
            &BindParts {
                globals: &globals,
                heights: &heights,
                normals: &normals,
                sampler: &sampler,
                masks: &masks,
                globe_tables: &globe_tables,
                imagery: &imagery,
            },
        );
        let capture_layout = capture::bind_group_layout(device);
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
            attributes: &wgpu::vertex_attr_array![
                0 => Uint32x4, 1 => Uint32x4, 2 => Uint32x4, 3 => Uint32x4
            ],
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
            normal_pass,
            masks,
            globals,
            globe_tables,
            sampler,
            imagery,
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

    fn write_globals(&self, camera: &Camera) {
        // Metres per finest sample east–west (x) and north–south (z).
        let s = self.world.spacing;
        let p = camera.position;
        let cell = (p.x / s.x).floor().max(0.0).min(f64::from(i32::MAX));
        let cell_z = (p.z / s.y).floor().max(0.0).min(f64::from(i32::MAX));
        let view = glam::DMat4::look_to_rh(DVec3::ZERO, camera.forward(), DVec3::Y);
        let vp = (camera.projection() * view).as_mat4();
        // A low sun from the north-west brings out relief.
        let sun = DVec3::new(-0.7, 0.42, -0.58).normalize().as_vec3();
        // Haze (terrain.wgsl `haze_amount`): the dataset's far edge, seen across the
        // lowest ground, mostly hidden; the air's scale height a tenth of that
        // distance (Earth: ~8 km against ~50–100 km of visibility), so that views
        // from above are clear and views along the ground hazy.
        let extent = self.world.size_m().max_element();
        let q = self.world.quant;
        let globals = Globals {
            view_proj: vp.to_cols_array_2d(),
            eye_cell: [cell as i32, cell_z as i32, 0, 0],
            eye_frac: [
                (p.x - cell * s.x) as f32,
                p.y as f32,
                (p.z - cell_z * s.y) as f32,
                0.0,
            ],
            quant: [
                q.offset as f32,
                q.scale as f32,
                self.height_range.0 as f32,
                self.height_range.1 as f32,
            ],
            sun: [sun.x, sun.y, sun.z, 0.0],
            haze: [
                super::HAZE_COLOUR[0],
                super::HAZE_COLOUR[1],
                super::HAZE_COLOUR[2],
                extent as f32,
            ],
            mode: [
                self.opts.view as u32,
                self.opts.parallax as u32,
                self.world.geometry.tile_size(),
                0,
            ],
            spacing: [s.x as f32, s.y as f32, 0.0, 0.0],
            globe: [0.0; 4],
            to_local: [[0.0; 4]; 3],
            air: [(extent / AIR_THINNING) as f32, 0.0, 0.0, 0.0],
        };
        let globals = self.globe_globals(globals, camera);
        self.gpu
            .queue
            .write_buffer(&self.globals, 0, bytemuck::bytes_of(&globals));
    }

    /// On the globe, the eye-relative tables for this eye (written to their
    /// buffers) and the globals that go with them; flat datasets unchanged.
    fn globe_globals(&self, mut globals: Globals, camera: &Camera) -> Globals {
        let Some(globe) = self.world.globe else {
            return globals;
        };
        let eye = crate::globe::frame::EyeFrame::of_world(&globe, camera.position);
        let n = self.world.geometry.padded_samples() as u32;
        let t = crate::globe::tables::EyeTables::new(&globe, &eye, n, n);
        let queue = &self.gpu.queue;
        queue.write_buffer(&self.globe_tables[0], 0, bytemuck::cast_slice(&t.rows));
        queue.write_buffer(&self.globe_tables[1], 0, bytemuck::cast_slice(&t.cols));
        globals.globe = [1.0, t.k, 0.0, 0.0];
        globals.eye_frac[1] = t.eye_height;
        for (row, r) in globals.to_local.iter_mut().zip(0..3) {
            let v = t.to_local.row(r);
            *row = [v.x, v.y, v.z, 0.0];
        }
        globals
    }

    /// Draws `patches` seen from `camera` into the offscreen target and waits for
    /// the GPU.
    pub fn draw(&mut self, camera: &Camera, patches: &[Patch]) -> anyhow::Result<DrawStats> {
        let started = Instant::now();
        // Normal maps of tiles uploaded one by one since the last frame.
        self.flush_normals();
        self.write_globals(camera);
        let g = self.world.geometry;
        let batches = Batches::build(&g, patches, self.opts.morph, |t| self.slots.get(t));
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

    /// Resizes the offscreen targets (a window was resized).
    pub fn resize(&mut self, width: u32, height: u32) {
        if width == 0 || height == 0 || (width, height) == (self.opts.width, self.opts.height) {
            return;
        }
        self.opts.width = width;
        self.opts.height = height;
        (self.colour, self.depth) = targets(&self.gpu.device, width, height);
    }
}

/// The terrain bind group's resources (group 0 of `terrain.wgsl`).
struct BindParts<'a> {
    globals: &'a wgpu::Buffer,
    heights: &'a wgpu::Texture,
    normals: &'a wgpu::Texture,
    sampler: &'a wgpu::Sampler,
    masks: &'a wgpu::Texture,
    globe_tables: &'a [wgpu::Buffer; 2],
    imagery: &'a ImageryTextures,
}

fn bind_group(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    p: &BindParts<'_>,
) -> wgpu::BindGroup {
    fn view(binding: u32, view: &wgpu::TextureView) -> wgpu::BindGroupEntry<'_> {
        wgpu::BindGroupEntry {
            binding,
            resource: wgpu::BindingResource::TextureView(view),
        }
    }
    let array_view = |t: &wgpu::Texture| {
        t.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        })
    };
    let flags = p.imagery.flags.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2),
        ..Default::default()
    });
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("terrain"),
        layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: p.globals.as_entire_binding(),
            },
            view(1, &array_view(p.heights)),
            view(2, &array_view(p.normals)),
            wgpu::BindGroupEntry {
                binding: 3,
                resource: wgpu::BindingResource::Sampler(p.sampler),
            },
            view(4, &array_view(p.masks)),
            wgpu::BindGroupEntry {
                binding: 5,
                resource: p.globe_tables[0].as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 6,
                resource: p.globe_tables[1].as_entire_binding(),
            },
            view(7, &array_view(&p.imagery.texels)),
            view(8, &flags),
        ],
    })
}

impl Renderer {
    /// Builds the terrain bind group again (after a texture was replaced).
    pub(super) fn rebuild_bind_group(&mut self) {
        self.bind_group = bind_group(
            &self.gpu.device,
            &self.layout,
            &BindParts {
                globals: &self.globals,
                heights: &self.heights,
                normals: &self.normals,
                sampler: &self.sampler,
                masks: &self.masks,
                globe_tables: &self.globe_tables,
                imagery: &self.imagery,
            },
        );
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

/// A square 2D texture array, `side` texels a side and `layers` deep (one layer per
/// GPU slot), sampled by the shaders and filled by copies, plus `extra` usages.
pub(super) fn texture_array(
    device: &wgpu::Device,
    label: &str,
    format: wgpu::TextureFormat,
    (side, layers): (u32, u32),
    extra: wgpu::TextureUsages,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: side,
            height: side,
            depth_or_array_layers: layers,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST | extra,
        view_formats: &[],
    })
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
