//! The renderer's device objects and terrain pipeline (one bind group for the
//! globals, the height, normal and cell-mask arrays and a sampler; one index buffer
//! range per inner LOD), created for a world and resized with the window.

use super::bind_group::{BindParts, bind_group};
use super::drape_textures::ImageryTextures;
use super::draw::Globals;
use super::error::RenderError;
use super::instances::{self, Instance};
use super::options::RenderOptions;
use super::renderer::Renderer;
use super::slots::SlotTable;
use super::textures::{COLOUR_FORMAT, DEPTH_FORMAT, layer_count, targets, texture_array};
use super::{capture, gpu::Gpu, gpu_normals};
use crate::select::World;
use wgpu::util::DeviceExt;

impl Renderer {
    /// A renderer for `world` with heights in `height_range` (metres, for the tint).
    pub fn new(
        world: World,
        height_range: (f64, f64),
        opts: RenderOptions,
    ) -> Result<Self, RenderError> {
        Self::with_gpu(Gpu::new(opts.backend)?, world, height_range, opts)
    }

    /// A renderer on an already opened device.
    pub fn with_gpu(
        gpu: Gpu,
        world: World,
        height_range: (f64, f64),
        opts: RenderOptions,
    ) -> Result<Self, RenderError> {
        if !(opts.width > 0 && opts.height > 0) {
            return Err(RenderError::EmptyViewport {
                width: opts.width,
                height: opts.height,
            });
        }
        let dim = gpu.limits.max_texture_dimension_2d;
        if !(opts.width <= dim && opts.height <= dim) {
            return Err(RenderError::ViewportTooLarge {
                width: opts.width,
                height: opts.height,
                dim,
            });
        }
        let samples = world.geometry.tile_samples() as u32;
        let cells = world.geometry.tile_size();
        let layers = layer_count(opts.slots).min(gpu.limits.max_texture_array_layers);
        if samples > dim {
            return Err(RenderError::TilesTooLarge { samples, dim });
        }
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
        gpu.check()
            .map_err(|e| RenderError::Creating(Box::new(e)))?;
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
