//! The renderer's textures: arrays of one layer per GPU slot (heights, normals,
//! cell masks, imagery) and the offscreen colour and depth targets.

pub(super) const COLOUR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
pub(super) const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Texture-array layer count for `slots` tiles. On GL, wgpu guesses a texture's
/// view type from its layer count: one layer becomes a plain 2-D texture and a
/// multiple of six a cube map, and viewing either as an array samples zeros
/// (PLATFORM.md). Avoid both.
pub(super) fn layer_count(slots: u32) -> u32 {
    let mut n = slots.max(2);
    while n.is_multiple_of(6) {
        n += 1;
    }
    n
}

/// The offscreen colour target (RGBA8, read back and presented) and its depth buffer.
pub(super) fn targets(
    device: &wgpu::Device,
    width: u32,
    height: u32,
) -> (wgpu::Texture, wgpu::Texture) {
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
