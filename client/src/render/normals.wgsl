// Normal maps on the GPU, from the heights of the resident tiles (the Rust side:
// gpu_normals.rs). The same central differences as the CPU reference
// (normals.rs): on a tile border the sample beyond it comes from the same-level
// neighbour's slot when that neighbour is resident, else the difference is
// one-sided. Both tiles of a shared border read the same samples, so they
// compute the same normal there (shading is continuous across tiles).
//
// Heights are read from a storage buffer holding every slot's samples (two u16
// per word) where the device's storage buffers can hold them all: texel fetches
// cost several times a buffer load on CPU rasterizers (lavapipe), and this pass
// is load-bound. Elsewhere (e.g. 256 slots of 513² samples: 135 MB against
// lavapipe's 128 MiB) they are fetched from the height texture.

// One tile to (re)compute. `tile.x`: its slot. `neighbours`: the slots of the
// north, east, south and west neighbours, NONE where not resident. `params`:
// metres between samples east–west and north–south, metres per quantization step.
struct Job {
    tile: vec4<u32>,
    neighbours: vec4<u32>,
    params: vec4<f32>,
}

const NONE: u32 = 0xffffffffu;

// `header.x`: how many jobs compute a whole tile (they come first; the border
// jobs follow them); `header.y`: all jobs; `header.z`: samples per tile side;
// `header.w`: u16 entries per slot in the heights buffer (unused with the texture).
@group(0) @binding(0) var<storage, read> header: vec4<u32>;
@group(0) @binding(1) var<storage, read> jobs: array<Job>;
// Binding 2, `heights`, and `fn height(slot, u, v) -> f32` (the quantized height at
// sample (u, v) of a slot) come from normals_heights_buffer.wgsl or
// normals_heights_texture.wgsl, prepended by gpu_normals.rs.
@group(0) @binding(3) var normals: texture_storage_2d_array<rgba8snorm, write>;


// The height one step towards a side and that step (1, or 0 when there is no
// sample there: the difference is then one-sided). `inside`: the step stays in
// the tile, at (u, v); else it is read from the neighbour `beyond` at (bu, bv).
fn towards(slot: u32, inside: bool, u: u32, v: u32, beyond: u32, bu: u32, bv: u32, here: f32) -> vec2<f32> {
    let there = inside || beyond != NONE;
    // Branch-free (the lanes of a SIMD rasterizer stay together); an absent
    // neighbour reads the tile's own slot and is discarded.
    let s = select(select(slot, beyond, there), slot, inside);
    let h = height(s, select(bu, u, inside), select(bv, v, inside));
    return select(vec2<f32>(here, 0.0), vec2<f32>(h, 1.0), there);
}

fn normal_at(job: Job, u: u32, v: u32) {
    let n = header.z;
    let slot = job.tile.x;
    let nb = job.neighbours;
    let here = height(slot, u, v);
    let west = towards(slot, u > 0u, u - 1u, v, nb.w, n - 2u, v, here);
    let east = towards(slot, u + 1u < n, u + 1u, v, nb.y, 1u, v, here);
    let north = towards(slot, v > 0u, u, v - 1u, nb.x, u, n - 2u, here);
    let south = towards(slot, v + 1u < n, u, v + 1u, nb.z, u, 1u, here);
    let scale = job.params.z;
    let dx = (east.x - west.x) * scale / ((east.y + west.y) * job.params.x);
    let dz = (south.x - north.x) * scale / ((south.y + north.y) * job.params.y);
    // Surface y = f(x, z): normal ∝ (−∂f/∂x, 1, −∂f/∂z); the fragment shader reads .rg.
    let len = sqrt(dx * dx + 1.0 + dz * dz);
    textureStore(normals, vec2<u32>(u, v), slot, vec4<f32>(-dx / len, -dz / len, 1.0 / len, 0.0));
}

// Whole tiles: one invocation per sample, one workgroup layer per job.
@compute @workgroup_size(8, 8, 1)
fn whole(@builtin(global_invocation_id) id: vec3<u32>) {
    let n = header.z;
    if id.x >= n || id.y >= n || id.z >= header.x {
        return;
    }
    normal_at(jobs[id.z], id.x, id.y);
}

// Border rings: invocation i walks the ring's 4n samples (north row, south row,
// west column, east column; corners twice, harmlessly).
@compute @workgroup_size(64, 1, 1)
fn ring(@builtin(global_invocation_id) id: vec3<u32>) {
    let n = header.z;
    let index = header.x + id.z;
    if id.x >= 4u * n || index >= header.y {
        return;
    }
    let side = id.x / n;
    let k = id.x % n;
    var uv = vec2<u32>(k, 0u);
    if side == 1u {
        uv = vec2<u32>(k, n - 1u);
    } else if side == 2u {
        uv = vec2<u32>(0u, k);
    } else if side == 3u {
        uv = vec2<u32>(n - 1u, k);
    }
    normal_at(jobs[index], uv.x, uv.y);
}
