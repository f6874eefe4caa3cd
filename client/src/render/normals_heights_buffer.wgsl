// Heights for normals.wgsl from a storage buffer of every slot's samples, two u16
// per word, `header.w` entries per slot.
@group(0) @binding(2) var<storage, read> heights: array<u32>;

fn height(slot: u32, u: u32, v: u32) -> f32 {
    let i = slot * header.w + v * header.z + u;
    return f32((heights[i >> 1u] >> ((i & 1u) * 16u)) & 0xffffu);
}
