//! Normal maps computed on the GPU (`normals.wgsl`), from the heights already in
//! their texture-array slots, so that uploading a tile is only texture copies.
//!
//! Uploads write the tile's heights a second time, into a storage buffer holding
//! every slot's samples where the device's storage buffers can hold them all
//! (the pass reads them there: on CPU rasterizers a texel fetch costs several
//! buffer loads; elsewhere it fetches them from the height texture), and queue
//! the tile; the next flush (the end of
//! [`Renderer::upload_wanted`](super::Renderer::upload_wanted), or the next frame drawn) computes, in one compute
//! pass, the whole normal map of every queued tile and the border ring of each of
//! their resident same-level neighbours. A shared border therefore ends up with
//! the normal computed from both tiles' samples whichever tile arrived first, as
//! the CPU reference ([`super::normals::normal_map`]) computes it when both are
//! decoded. Slots are resolved at the flush, not at upload: a tile evicted in the
//! meantime is skipped, and a slot reused by a later upload is read with its
//! new contents (queue writes land before the pass).

use super::gpu::Gpu;
use super::normals::NormalSource;
use super::slots::SlotTable;
use crate::select::World;
use std::collections::HashSet;
use tessera_shared::TileId;

/// The storage-capable format of the normal texture: WebGPU has no `Rg8Snorm`
/// storage textures. The fragment shader reads `.rg` (x, z); `.b` holds y.
pub(super) const NORMAL_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Snorm;

/// A slot number meaning "no neighbour resident".
const NONE: u32 = u32::MAX;

/// One tile to (re)compute, as `normals.wgsl` reads it.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct Job {
    /// Slot, 1 = border ring only, unused, unused.
    tile: [u32; 4],
    /// North, east, south and west neighbours' slots, or [`NONE`].
    neighbours: [u32; 4],
    /// Metres between samples east–west and north–south, metres per quantum.
    params: [f32; 4],
}

/// Where the pass reads heights (`normals_heights_*.wgsl`).
#[derive(Debug)]
enum Heights {
    /// Every slot's heights, `entries` u16 per slot (two per word), written
    /// at upload beside the texture: buffer loads are cheap on CPU rasterizers.
    Buffer(wgpu::Buffer),
    /// The height texture array itself, where the buffer would exceed the
    /// device's storage-buffer limit.
    Texture(wgpu::TextureView),
}

/// The compute pipelines and the tiles waiting for their normal maps.
#[derive(Debug)]
pub(super) struct NormalPass {
    whole: wgpu::ComputePipeline,
    ring: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    heights: Heights,
    /// `T + 1`: samples per tile side.
    samples: u32,
    /// u16 entries per slot: `samples²` rounded up to even (4-byte writes).
    entries: u64,
    normals: wgpu::TextureView,
    header: wgpu::Buffer,
    /// The job buffer, its capacity in jobs and its bind group (rebuilt when it grows).
    jobs: Option<(wgpu::Buffer, u64, wgpu::BindGroup)>,
    /// Tiles uploaded since the last flush.
    pending: Vec<TileId>,
}

impl NormalPass {
    /// The pass from the `heights` texture array into the `normals` one
    /// ([`NORMAL_FORMAT`], with storage usage; its size gives the slots and
    /// samples), when `source` asks for it and the device can run it: devices
    /// without compute shaders (GL ES 3.0) fall back to the CPU, with a warning.
    pub(super) fn chosen(
        source: NormalSource,
        gpu: &Gpu,
        heights: &wgpu::Texture,
        normals: &wgpu::Texture,
    ) -> Option<Self> {
        if source != NormalSource::Gpu {
            return None;
        }
        if !gpu
            .downlevel
            .flags
            .contains(wgpu::DownlevelFlags::COMPUTE_SHADERS)
        {
            tracing::warn!(gpu = %gpu.describe(), "no compute shaders: normal maps are built on the CPU");
            return None;
        }
        let samples = normals.width();
        let entries = (u64::from(samples) * u64::from(samples)).next_multiple_of(2);
        let bytes = 2 * entries * u64::from(normals.depth_or_array_layers());
        let limit = gpu
            .limits
            .max_storage_buffer_binding_size
            .min(gpu.limits.max_buffer_size);
        let device = &gpu.device;
        let source = if bytes <= limit {
            Heights::Buffer(device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("heights for normal maps"),
                size: bytes,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }))
        } else {
            tracing::info!(
                bytes,
                limit,
                "normal maps read heights from the texture (every slot's would exceed a storage buffer)"
            );
            Heights::Texture(heights.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2Array),
                ..Default::default()
            }))
        };
        Some(Self::new(device, source, normals, samples, entries))
    }

    fn new(
        device: &wgpu::Device,
        heights: Heights,
        normals: &wgpu::Texture,
        samples: u32,
        entries: u64,
    ) -> Self {
        let buffer = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: true },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("normal maps"),
            entries: &[
                buffer(0),
                buffer(1),
                match heights {
                    Heights::Buffer(_) => buffer(2),
                    Heights::Texture(_) => wgpu::BindGroupLayoutEntry {
                        binding: 2,
                        visibility: wgpu::ShaderStages::COMPUTE,
                        ty: wgpu::BindingType::Texture {
                            sample_type: wgpu::TextureSampleType::Float { filterable: false },
                            view_dimension: wgpu::TextureViewDimension::D2Array,
                            multisampled: false,
                        },
                        count: None,
                    },
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 3,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::StorageTexture {
                        access: wgpu::StorageTextureAccess::WriteOnly,
                        format: NORMAL_FORMAT,
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                    },
                    count: None,
                },
            ],
        });
        let read_heights = match heights {
            Heights::Buffer(_) => include_str!("normals_heights_buffer.wgsl"),
            Heights::Texture(_) => include_str!("normals_heights_texture.wgsl"),
        };
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("normals.wgsl"),
            source: wgpu::ShaderSource::Wgsl(
                format!("{read_heights}\n{}", include_str!("normals.wgsl")).into(),
            ),
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("normal maps"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = |entry| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                cache: None,
            })
        };
        Self {
            whole: pipeline("whole"),
            ring: pipeline("ring"),
            heights,
            samples,
            entries,
            normals: normals.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2Array),
                ..Default::default()
            }),
            header: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("normal jobs header"),
                size: 16,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            layout,
            jobs: None,
            pending: Vec::new(),
        }
    }

    /// Writes `tile`'s heights into `slot` of the pass's buffer, if it reads one,
    /// and queues its normal map.
    pub(super) fn queue(&mut self, queue: &wgpu::Queue, tile: TileId, slot: u32, heights: &[u16]) {
        self.pending.push(tile);
        let Heights::Buffer(buffer) = &self.heights else {
            return;
        };
        debug_assert_eq!(heights.len() as u64, u64::from(self.samples).pow(2));
        let offset = u64::from(slot) * self.entries * 2;
        // Buffer writes come in whole words: an odd count's last sample goes with a pad.
        let whole = heights.len() / 2 * 2;
        queue.write_buffer(buffer, offset, bytemuck::cast_slice(&heights[..whole]));
        if let Some(&last) = heights.get(whole) {
            queue.write_buffer(
                buffer,
                offset + 2 * whole as u64,
                bytemuck::cast_slice(&[last, 0]),
            );
        }
    }
}

/// `tile`'s same-level neighbour `(dx, dy)` tiles away, if inside the level.
fn neighbour(tile: TileId, dx: i64, dy: i64) -> Option<TileId> {
    let (x, y) = (i64::from(tile.x()) + dx, i64::from(tile.y()) + dy);
    TileId::new(tile.level(), u32::try_from(x).ok()?, u32::try_from(y).ok()?)
}

/// North, east, south, west (the order of [`super::normals::Neighbours`]).
const SIDES: [(i64, i64); 4] = [(0, -1), (1, 0), (0, 1), (-1, 0)];

impl NormalPass {
    /// Computes the normal maps of the tiles queued since the last flush (and the
    /// border rings of their resident neighbours, by their `slots`) in one
    /// submitted compute pass, without waiting for it.
    pub(super) fn flush(&mut self, gpu: &Gpu, slots: &SlotTable, world: &World) {
        let pass = self;
        if pass.pending.is_empty() {
            return;
        }
        let mut seen = HashSet::new();
        let whole: Vec<(TileId, u32)> = std::mem::take(&mut pass.pending)
            .into_iter()
            .filter(|&t| seen.insert(t))
            .filter_map(|t| Some((t, slots.get(t)?)))
            .collect();
        let whole_tiles: HashSet<TileId> = whole.iter().map(|&(t, _)| t).collect();
        let mut ring: Vec<(TileId, u32)> = Vec::new();
        for &(t, _) in &whole {
            for (dx, dy) in SIDES {
                if let Some(n) = neighbour(t, dx, dy)
                    && !whole_tiles.contains(&n)
                    && seen.insert(n)
                    && let Some(slot) = slots.get(n)
                {
                    ring.push((n, slot));
                }
            }
        }
        if whole.is_empty() {
            return;
        }
        let g = world.geometry;
        let scale = world.quant.scale as f32;
        let job = |(tile, slot): (TileId, u32), ring_only: bool| {
            let metres = world.spacing * g.spacing(tile.level()) as f64;
            let neighbours = SIDES.map(|(dx, dy)| {
                neighbour(tile, dx, dy)
                    .and_then(|n| slots.get(n))
                    .unwrap_or(NONE)
            });
            Job {
                tile: [slot, u32::from(ring_only), 0, 0],
                neighbours,
                params: [metres.x as f32, metres.y as f32, scale, 0.0],
            }
        };
        let jobs: Vec<Job> = whole
            .iter()
            .map(|&w| job(w, false))
            .chain(ring.iter().map(|&r| job(r, true)))
            .collect();
        let device = &gpu.device;
        let queue = &gpu.queue;
        let needed = jobs.len() as u64;
        if pass.jobs.as_ref().is_none_or(|(_, cap, _)| *cap < needed) {
            let cap = needed.next_power_of_two().max(16);
            let buffer = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("normal jobs"),
                size: cap * size_of::<Job>() as u64,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("normal maps"),
                layout: &pass.layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: pass.header.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: match &pass.heights {
                            Heights::Buffer(b) => b.as_entire_binding(),
                            Heights::Texture(v) => wgpu::BindingResource::TextureView(v),
                        },
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: wgpu::BindingResource::TextureView(&pass.normals),
                    },
                ],
            });
            pass.jobs = Some((buffer, cap, bind_group));
        }
        let Some((buffer, _, bind_group)) = &pass.jobs else {
            return;
        };
        let (whole_n, total) = (whole.len() as u32, jobs.len() as u32);
        let entries = u32::try_from(pass.entries).unwrap_or(u32::MAX);
        queue.write_buffer(
            &pass.header,
            0,
            bytemuck::cast_slice(&[whole_n, total, pass.samples, entries]),
        );
        queue.write_buffer(buffer, 0, bytemuck::cast_slice(&jobs));
        let n = pass.samples;
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("normal maps"),
        });
        {
            let mut cpass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("normal maps"),
                timestamp_writes: None,
            });
            cpass.set_bind_group(0, bind_group, &[]);
            cpass.set_pipeline(&pass.whole);
            cpass.dispatch_workgroups(n.div_ceil(8), n.div_ceil(8), whole_n);
            if total > whole_n {
                cpass.set_pipeline(&pass.ring);
                cpass.dispatch_workgroups((4 * n).div_ceil(64), 1, total - whole_n);
            }
        }
        queue.submit([encoder.finish()]);
    }
}
