// Heights for normals.wgsl fetched from the R16Unorm height texture array (the
// quantized integer back from the normalized value).
@group(0) @binding(2) var heights: texture_2d_array<f32>;

fn height(slot: u32, u: u32, v: u32) -> f32 {
    return round(textureLoad(heights, vec2<u32>(u, v), slot, 0).r * 65535.0);
}
