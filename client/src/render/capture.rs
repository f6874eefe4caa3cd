//! Vertex capture: the vertex shader's own vertices, computed by a compute pass
//! over the same WGSL function and read back, for the tests that compare them with
//! the reference tessellator ([`crate::tessellate`]).

use super::error::RenderError;
use super::renderer::Renderer;
use super::{instances::Instance, readback::map_read};
use crate::select::Patch;
use crate::tessellate::Vertex;
use wgpu::util::DeviceExt;

/// The capture pass's own bind group (group 1): the jobs (instances with the
/// vertex index in `c[3]`) and the output.
pub(super) fn bind_group_layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
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
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("capture"),
        entries: &[storage(0, true), storage(1, false)],
    })
}

impl Renderer {
    /// Runs the vertex shader's own `terrain_vertex` over every vertex of every
    /// patch (a compute pass over the same WGSL function) and returns what it
    /// produced, patch by patch, in the reference tessellator's order.
    pub fn capture_vertices(&self, patches: &[Patch]) -> Result<Vec<Vec<Vertex>>, RenderError> {
        let g = self.world.geometry;
        let mut jobs: Vec<Instance> = Vec::new();
        for p in patches {
            let slot = self
                .slots
                .get(p.tile)
                .ok_or(RenderError::NoSlot { tile: p.tile })?;
            let inst = Instance::new(&g, p, slot, None);
            for vid in 0..(p.inner + 1) * (p.inner + 1) {
                let mut job = inst;
                job.c[3] = vid;
                jobs.push(job);
            }
        }
        if jobs.is_empty() {
            return Err(RenderError::NothingToCapture);
        }
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
        let size = jobs.len() as u64 * 16;
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
            let groups = (jobs.len() as u32).div_ceil(64);
            // Spread over two dimensions past the 65535-workgroup limit.
            let (x, y) = (groups.min(65_535), groups.div_ceil(65_535));
            if y != 1 {
                return Err(RenderError::TooManyVertices {
                    vertices: jobs.len(),
                });
            }
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
                            h: w[3],
                        }
                    })
                    .collect(),
            );
            k += count;
        }
        Ok(result)
    }
}
