//! Drawing a frame: the globals the shaders read (camera, sun, haze, the globe's
//! frame), the terrain draws, one per inner LOD present, into the offscreen
//! targets, and the frame read back.

use super::error::RenderError;
use super::instances::{Batches, Instance};
use super::options::{DrawStats, HAZE_COLOUR};
use super::readback::read_layer;
use super::renderer::Renderer;
use crate::camera::Camera;
use crate::select::Patch;
use glam::DVec3;
use std::time::Instant;

#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct Globals {
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

impl Renderer {
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
                HAZE_COLOUR[0],
                HAZE_COLOUR[1],
                HAZE_COLOUR[2],
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
    pub fn draw(&mut self, camera: &Camera, patches: &[Patch]) -> Result<DrawStats, RenderError> {
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
        self.gpu
            .wait()
            .map_err(|e| RenderError::Frame(Box::new(e)))?;
        Ok(DrawStats {
            draw_calls: draws.len() as u32,
            instances: batches.instances.len() as u32,
            skipped: batches.skipped as u32,
            render_ms: started.elapsed().as_secs_f64() * 1e3,
        })
    }
}

impl Renderer {
    /// The last frame as tightly packed RGBA8 rows.
    pub fn read_rgba(&self) -> Result<Vec<u8>, RenderError> {
        let (w, h) = (self.opts.width, self.opts.height);
        read_layer(&self.gpu, &self.colour, 0, (w, h), 4)
    }
}
