// Normal maps on the GPU, from the heights already in their texture-array slots
// (the Rust side: gpu_normals.rs). The same central differences as the CPU
// reference (normals.rs): on a tile border the sample beyond it comes from the
// same-level neighbour's slot when that neighbour is resident, else the
// difference is one-sided. Both tiles of a shared border read the same samples,
// so they compute the same normal there (shading is continuous across tiles).

// One tile to (re)compute. `tile.x`: its slot; `tile.y`: 1 = only its border
// ring (a neighbour arrived). `neighbours`: the slots of the north, east, south
// and west neighbours, NONE where not resident. `params`: metres between samples
// east–west and north–south, metres per quantization step.
struct Job {
    tile: vec4<u32>,
    neighbours: vec4<u32>,
    params: vec4<f32>,
}

const NONE: u32 = 0xffffffffu;

// `header.x`: how many jobs compute a whole tile (they come first; the border
// jobs follow them); `header.y`: all jobs.
@group(0) @binding(0) var<storage, read> header: vec4<u32>;
@group(0) @binding(1) var<storage, read> jobs: array<Job>;
@group(0) @binding(2) var heights: texture_2d_array<f32>;
@group(0) @binding(3) var normals: texture_storage_2d_array<rgba8snorm, write>;

// The quantized height (an integer, as the CPU sees it) at sample (u, v) of a slot.
fn height(slot: u32, u: i32, v: i32) -> f32 {
    return round(textureLoad(heights, vec2<i32>(u, v), i32(slot), 0).r * 65535.0);
}

// The height one step beyond the tile on `side` (0 north, 1 east, 2 south, 3 west)
// at sample (u, v) of the neighbour, or the tile's own sample `own` with a zero
// step when the neighbour is not resident. Returns (height, step).
fn beyond(job: Job, side: u32, u: i32, v: i32, own: f32) -> vec2<f32> {
    let s = job.neighbours[side];
    if s == NONE {
        return vec2<f32>(own, 0.0);
    }
    return vec2<f32>(height(s, u, v), 1.0);
}

fn normal_at(job: Job, u: i32, v: i32, n: i32) {
    let slot = job.tile.x;
    let here = height(slot, u, v);
    var west = vec2<f32>(0.0, 1.0);
    if u > 0 {
        west.x = height(slot, u - 1, v);
    } else {
        west = beyond(job, 3u, n - 2, v, here);
    }
    var east = vec2<f32>(0.0, 1.0);
    if u + 1 < n {
        east.x = height(slot, u + 1, v);
    } else {
        east = beyond(job, 1u, 1, v, here);
    }
    var north = vec2<f32>(0.0, 1.0);
    if v > 0 {
        north.x = height(slot, u, v - 1);
    } else {
        north = beyond(job, 0u, u, n - 2, here);
    }
    var south = vec2<f32>(0.0, 1.0);
    if v + 1 < n {
        south.x = height(slot, u, v + 1);
    } else {
        south = beyond(job, 2u, u, 1, here);
    }
    let scale = job.params.z;
    let dx = (east.x - west.x) * scale / ((east.y + west.y) * job.params.x);
    let dz = (south.x - north.x) * scale / ((south.y + north.y) * job.params.y);
    // Surface y = f(x, z): normal ∝ (−∂f/∂x, 1, −∂f/∂z); the fragment shader reads .rg.
    let len = sqrt(dx * dx + 1.0 + dz * dz);
    textureStore(normals, vec2<i32>(u, v), i32(slot), vec4<f32>(-dx / len, -dz / len, 1.0 / len, 0.0));
}

// Whole tiles: one invocation per sample, one workgroup layer per job.
@compute @workgroup_size(8, 8, 1)
fn whole(@builtin(global_invocation_id) id: vec3<u32>) {
    let n = i32(textureDimensions(heights).x);
    if i32(id.x) >= n || i32(id.y) >= n || id.z >= header.x {
        return;
    }
    normal_at(jobs[id.z], i32(id.x), i32(id.y), n);
}

// Border rings: invocation i walks the ring's 4n samples (north row, south row,
// west column, east column; corners twice, harmlessly).
@compute @workgroup_size(64, 1, 1)
fn ring(@builtin(global_invocation_id) id: vec3<u32>) {
    let n = i32(textureDimensions(heights).x);
    let index = header.x + id.z;
    if i32(id.x) >= 4 * n || index >= header.y {
        return;
    }
    let side = i32(id.x) / n;
    let k = i32(id.x) % n;
    var uv = vec2<i32>(k, 0);
    if side == 1 {
        uv = vec2<i32>(k, n - 1);
    } else if side == 2 {
        uv = vec2<i32>(0, k);
    } else if side == 3 {
        uv = vec2<i32>(n - 1, k);
    }
    normal_at(jobs[index], uv.x, uv.y, n);
}
