//! Readback: copying textures (the offscreen frame, a slot's layer) and buffers
//! the GPU wrote back to the CPU.

use super::error::RenderError;
use super::gpu::Gpu;

/// Layer `layer` of a `w × h` texture of `texel` bytes per texel, as tightly
/// packed rows (the copy itself pads rows to wgpu's alignment).
pub(super) fn read_layer(
    gpu: &Gpu,
    texture: &wgpu::Texture,
    layer: u32,
    (w, h): (u32, u32),
    texel: u32,
) -> Result<Vec<u8>, RenderError> {
    let row = w * texel;
    let padded =
        row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size: u64::from(padded) * u64::from(h),
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut encoder = gpu
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("readback"),
        });
    encoder.copy_texture_to_buffer(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d {
                x: 0,
                y: 0,
                z: layer,
            },
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
    gpu.queue.submit([encoder.finish()]);
    let data = map_read(gpu, &buffer)?;
    let mut out = Vec::with_capacity((row * h) as usize);
    for y in 0..h as usize {
        out.extend_from_slice(&data[y * padded as usize..][..row as usize]);
    }
    Ok(out)
}

/// Maps a buffer for reading after the submitted work, and copies it out.
pub(super) fn map_read(gpu: &Gpu, buffer: &wgpu::Buffer) -> Result<Vec<u8>, RenderError> {
    let (tx, rx) = std::sync::mpsc::channel();
    buffer.map_async(wgpu::MapMode::Read, .., move |r| {
        let _ = tx.send(r);
    });
    gpu.wait()?;
    rx.recv()
        .map_err(RenderError::ReadbackDropped)?
        .map_err(|e| RenderError::Readback {
            error: e.to_string(),
        })?;
    let data = buffer
        .get_mapped_range(..)
        .map_err(|e| RenderError::Readback {
            error: e.to_string(),
        })?
        .to_vec();
    buffer.unmap();
    Ok(data)
}
