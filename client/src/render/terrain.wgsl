// Terrain with emulated tessellation (docs/ARCHITECTURE.md#rendering; Kang §3–4).
//
// There is no vertex buffer: vertex `vid` of an inner-LOD-n patch is grid point
// (vid % (n+1), vid / (n+1)), and the per-instance data says which tile slot, which
// patch of it, and the four edge LODs. `terrain_vertex` must produce exactly what
// `client/src/tessellate.rs` produces; the `capture` compute entry point runs the
// same function so that tests can compare the two bit for bit.

struct Globals {
    // Projection × view with the eye at the origin (camera-relative rendering).
    view_proj: mat4x4<f32>,
    // The eye's finest-grid cell (x, y), so that vertex positions are computed from
    // small exact integer differences.
    eye_cell: vec4<i32>,
    // (eye x − cell x·sx, eye height, eye z − cell y·sy, unused).
    eye_frac: vec4<f32>,
    // (offset, scale) of the height quantization; (min, max) height for the tint.
    quant: vec4<f32>,
    // Direction towards the sun (unit), w unused.
    sun: vec4<f32>,
    // Haze colour, and the distance through air at the lowest terrain over which
    // it takes 63% of the colour.
    haze: vec4<f32>,
    // (debug view, parallax mode, tile size in cells, unused).
    mode: vec4<u32>,
    // (sx, sy, unused, unused): metres per finest sample east–west (x) and
    // north–south (z); they differ where cells are not square (geographic DEMs).
    spacing: vec4<f32>,
    // The globe (DECISIONS.md "The globe", `client/src/globe/tables.rs`): (1 on, K,
    // unused, unused), and the rotation from ECEF to the eye's (east, up, south) frame,
    // rows.
    globe: vec4<f32>,
    to_local0: vec4<f32>,
    to_local1: vec4<f32>,
    to_local2: vec4<f32>,
    // The air of the aerial perspective: (scale height in metres, unused, unused,
    // unused); its density is 1 at the lowest terrain (quant.z).
    air: vec4<f32>,
};

@group(0) @binding(0) var<uniform> g: Globals;
@group(0) @binding(1) var heights: texture_2d_array<f32>;
@group(0) @binding(2) var normals: texture_2d_array<f32>;
@group(0) @binding(3) var linear_clamp: sampler;
// One texel per tile cell (T × T): 1 where the cell is terrain, 0 for no-data and
// the padding beyond the DEM (FORMAT.md "Validity mask").
@group(0) @binding(4) var masks: texture_2d_array<f32>;
// Eye-relative globe tables (`globe/tables.rs`), per finest row (A, B, cos φ, sin φ)
// and per finest column (cos λ − cos λe, sin λ − sin λe, cos λ, sin λ); one
// unused entry each on flat datasets.
@group(0) @binding(5) var<storage, read> globe_rows: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> globe_cols: array<vec4<f32>>;
// Draped imagery (DECISIONS.md "Imagery pyramids"): a layer per slot, and per slot where
// its tile's imagery is (render/drape.rs): r = 1 + the layer (0: none yet, the
// hypsometric tint), g = levels up to the layer's tile | x offset << 8 | y offset << 20
// there.
@group(0) @binding(7) var imagery: texture_2d_array<f32>;
@group(0) @binding(8) var imagery_source: texture_2d<u32>;

// Per-instance data, packed (see `render/instances.rs`):
//   a = (slot | level << 16, origin x | origin y << 16, size in tile cells, inner LOD)
//   b = (edge LODs north | east << 8 | south << 16 | west << 24,
//        tile origin x, tile origin y (finest samples), finest samples per tile sample)
//   c = (interior morph, morph north | east << 16, morph south | west << 16, 0),
//       factors in 0..=256 (`select/morph.rs`)
//   d = (fade factor 0..=256, levels up | source slot << 8, offset x, offset y):
//       the shading fade from an ancestor tile (`select/fade.rs`), 0: none
struct TerrainVertex {
    // Global finest-grid coordinates, the quantized sample and the morphed height
    // in 1/512 quantization steps: the contract.
    x: u32,
    y: u32,
    q: u32,
    h: u32,
    // Tile sample coordinates (for the height and normal maps).
    u: u32,
    v: u32,
};

fn snap(index: u32, n: u32, e: u32) -> u32 {
    let step = n / max(e, 1u);
    return index / step * step;
}

// Geomorphing (`select/morph.rs`): the height moved `f`/256 of the way from `q`
// to the average of `lo` and `hi`, in integers (exact, as `morph::mix`).
fn mix_height(q: u32, lo: u32, hi: u32, f: u32) -> u32 {
    return 2u * q * (256u - f) + (lo + hi) * f;
}

fn sample_q(a: vec4<u32>, p: vec2<u32>) -> u32 {
    let step = a.z / a.w;
    let u = (a.y & 0xffffu) + p.x * step;
    let v = (a.y >> 16u) + p.y * step;
    let texel = textureLoad(heights, vec2<i32>(i32(u), i32(v)), i32(a.x & 0xffffu), 0).r;
    return u32(round(texel * 65535.0));
}

fn terrain_vertex(a: vec4<u32>, b: vec4<u32>, c: vec4<u32>, vid: u32) -> TerrainVertex {
    let n = a.w;
    let w = n + 1u;
    let i = vid % w;
    let j = vid / w;
    let north = b.x & 0xffu;
    let east = (b.x >> 8u) & 0xffu;
    let south = (b.x >> 16u) & 0xffu;
    let west = b.x >> 24u;
    // Edge snapping (docs/ARCHITECTURE.md#rendering): the along-edge index goes down to a
    // multiple of n/e.
    var ia = i;
    if (j == 0u) {
        ia = snap(i, n, north);
    } else if (j == n) {
        ia = snap(i, n, south);
    }
    var jb = j;
    if (i == 0u) {
        jb = snap(j, n, west);
    } else if (i == n) {
        jb = snap(j, n, east);
    }
    let step = a.z / n;
    let u = (a.y & 0xffffu) + ia * step;
    let v = (a.y >> 16u) + jb * step;
    let slot = a.x & 0xffffu;
    let texel = textureLoad(heights, vec2<i32>(i32(u), i32(v)), i32(slot), 0).r;
    var out: TerrainVertex;
    out.x = b.y + u * b.w;
    out.y = b.z + v * b.w;
    out.q = u32(round(texel * 65535.0));
    out.u = u;
    out.v = v;
    // Morphing (as `tessellate::morph_target`): on a side, odd on the side's own
    // grid by the side's factor; inside, odd on the patch grid by the patch's.
    var lo = vec2<u32>(ia, jb);
    var hi = vec2<u32>(ia, jb);
    var f = 0u;
    if (j == 0u || j == n) {
        let e = select(south, north, j == 0u);
        let per = n / max(e, 1u);
        let fe = select(c.z & 0xffffu, c.y & 0xffffu, j == 0u);
        if (e >= 2u && (ia / per) % 2u == 1u) {
            lo = vec2<u32>(ia - per, jb);
            hi = vec2<u32>(ia + per, jb);
            f = fe;
        }
    } else if (i == 0u || i == n) {
        let e = select(east, west, i == 0u);
        let per = n / max(e, 1u);
        let fe = select(c.y >> 16u, c.z >> 16u, i == 0u);
        if (e >= 2u && (jb / per) % 2u == 1u) {
            lo = vec2<u32>(ia, jb - per);
            hi = vec2<u32>(ia, jb + per);
            f = fe;
        }
    } else if (i % 2u == 1u || j % 2u == 1u) {
        // Towards the n/2 grid, whose cells split north-west → south-east.
        lo = vec2<u32>(i - i % 2u, j - j % 2u);
        hi = vec2<u32>(i + i % 2u, j + j % 2u);
        f = c.x;
    }
    if (f > 0u) {
        out.h = mix_height(out.q, sample_q(a, lo), sample_q(a, hi), f);
    } else {
        out.h = out.q * 512u;
    }
    return out;
}

fn height_m(q: f32) -> f32 {
    return g.quant.x + g.quant.y * q;
}

// Camera-relative position of a finest-grid point: the same integers give the same
// floats on both sides of a shared edge, so there are no cracks.
fn relative(x: u32, y: u32, h: f32) -> vec3<f32> {
    if (g.globe.x > 0.5) {
        // On the globe: ECEF minus the eye's from the eye-relative tables (every
        // term about the distance from the eye, so f32 is exact near it), turned
        // into the eye's local frame.
        let r = globe_rows[y];
        let c = globe_cols[x];
        let dh = h - g.eye_frac.y;
        let k = g.globe.y;
        let e = vec3<f32>(
            r.x * c.z + k * c.x + dh * r.z * c.z,
            r.x * c.w + k * c.y + dh * r.z * c.w,
            r.y + dh * r.w,
        );
        return vec3<f32>(dot(g.to_local0.xyz, e), dot(g.to_local1.xyz, e), dot(g.to_local2.xyz, e));
    }
    let dx = f32(i32(x) - g.eye_cell.x) * g.spacing.x - g.eye_frac.x;
    let dz = f32(i32(y) - g.eye_cell.y) * g.spacing.y - g.eye_frac.z;
    return vec3<f32>(dx, h - g.eye_frac.y, dz);
}

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    // Tile sample coordinates of this point (continuous).
    @location(0) uv: vec2<f32>,
    // Height of the drawn (base) mesh here, metres.
    @location(1) base_h: f32,
    @location(2) rel: vec3<f32>,
    // Grid coordinates before snapping, for the wireframe view.
    @location(3) grid: vec2<f32>,
    // (slot, level, inner LOD, tile cells per triangle edge).
    @location(4) @interpolate(flat) info: vec4<u32>,
    // Finest samples per tile sample (1 on the finest level).
    @location(5) @interpolate(flat) stride: u32,
    // The shading fade, as the instance's `d`.
    @location(6) @interpolate(flat) fade: vec4<u32>,
};

@vertex
fn vs_main(
    @builtin(vertex_index) vid: u32,
    @location(0) a: vec4<u32>,
    @location(1) b: vec4<u32>,
    @location(2) c: vec4<u32>,
    @location(3) d: vec4<u32>,
) -> VsOut {
    let t = terrain_vertex(a, b, c, vid);
    let h = height_m(f32(t.h) / 512.0);
    let rel = relative(t.x, t.y, h);
    var out: VsOut;
    out.clip = g.view_proj * vec4<f32>(rel, 1.0);
    out.uv = vec2<f32>(f32(t.u), f32(t.v));
    out.base_h = h;
    out.rel = rel;
    let w = a.w + 1u;
    out.grid = vec2<f32>(f32(vid % w), f32(vid / w));
    out.info = vec4<u32>(a.x & 0xffffu, a.x >> 16u, a.w, a.z / a.w);
    out.stride = b.w;
    out.fade = d;
    return out;
}

// Bilinear height (metres) at continuous tile sample coordinates.
fn fine_height(uv: vec2<f32>, slot: u32) -> f32 {
    let size = f32(g.mode.z + 1u);
    let t = textureSampleLevel(heights, linear_clamp, (uv + 0.5) / size, i32(slot), 0.0).r;
    return height_m(t * 65535.0);
}

fn normal_at(uv: vec2<f32>, slot: u32) -> vec3<f32> {
    let size = f32(g.mode.z + 1u);
    let nxz = textureSampleLevel(normals, linear_clamp, (uv + 0.5) / size, i32(slot), 0.0).rg;
    let ny = sqrt(max(1.0 - dot(nxz, nxz), 0.0));
    return normalize(vec3<f32>(nxz.x, ny, nxz.y));
}

// Parallax over the tessellated base surface (González §2.2–2.4). `d` is the unit
// view direction (eye → point), `m` metres per tile sample (east–west, north–south),
// `tsize` the triangle size in tile samples. Returns where to read the height and
// normal maps.
fn parallax(uv0: vec2<f32>, base_h: f32, d: vec3<f32>, m: vec2<f32>, tsize: f32, slot: u32) -> vec2<f32> {
    let mode = g.mode.y;
    // View direction in (tile samples, metres) coordinates.
    let duv = d.xz / m;
    if (mode == 1u) {
        // Offset limiting, threshold 0.5 (González Fig. 7, flat base normal).
        let h = fine_height(uv0, slot);
        return uv0 - (h - base_h) * duv / max(-d.y, 0.5);
    }
    if (mode == 2u) {
        // Iterative, Welsh's approximation, 2 iterations (González Fig. 9).
        var uv = uv0;
        for (var k = 0; k < 2; k++) {
            let h = fine_height(uv, slot);
            uv = uv - (h - base_h) * duv;
        }
        return uv;
    }
    if (mode == 3u) {
        // Binary search between points one triangle before and after the base
        // surface along the ray, 3 steps, then a secant step (González Fig. 10).
        let len = max(length(duv), 1e-6);
        let dir = vec3<f32>(duv, d.y) / len * tsize;
        var p1 = vec3<f32>(uv0, base_h) - dir; // towards the eye: above the surface
        var p2 = vec3<f32>(uv0, base_h) + dir; // beyond: below the surface
        var d1 = fine_height(p1.xy, slot) - p1.z;
        var d2 = fine_height(p2.xy, slot) - p2.z;
        if (d1 > 0.0 || d2 < 0.0) {
            // The segment does not bracket the surface: keep the base point.
            return uv0;
        }
        for (var k = 0; k < 3; k++) {
            let pm = (p1 + p2) * 0.5;
            let dm = fine_height(pm.xy, slot) - pm.z;
            if (dm < 0.0) {
                p1 = pm;
                d1 = dm;
            } else {
                p2 = pm;
                d2 = dm;
            }
        }
        let denom = d2 - d1;
        if (denom <= 0.0) {
            return p2.xy;
        }
        return (p2 + (p1 - p2) * (d2 / denom)).xy;
    }
    return uv0;
}

// Hypsometric tint: lowlands green, then tan, brown and grey rock, white peaks.
fn tint(h: f32) -> vec3<f32> {
    let t = clamp((h - g.quant.z) / max(g.quant.w - g.quant.z, 1.0), 0.0, 1.0);
    let c0 = vec3<f32>(0.30, 0.50, 0.28);
    let c1 = vec3<f32>(0.62, 0.60, 0.40);
    let c2 = vec3<f32>(0.55, 0.42, 0.30);
    let c3 = vec3<f32>(0.60, 0.58, 0.56);
    let c4 = vec3<f32>(0.95, 0.95, 0.97);
    if (t < 0.25) {
        return mix(c0, c1, t / 0.25);
    }
    if (t < 0.5) {
        return mix(c1, c2, (t - 0.25) / 0.25);
    }
    if (t < 0.8) {
        return mix(c2, c3, (t - 0.5) / 0.3);
    }
    return mix(c3, c4, (t - 0.8) / 0.2);
}

// Distinct colours for inner LODs 1…64 and pyramid levels.
fn palette(k: u32) -> vec3<f32> {
    let colours = array<vec3<f32>, 8>(
        vec3<f32>(0.20, 0.30, 0.90), vec3<f32>(0.10, 0.70, 0.90), vec3<f32>(0.10, 0.75, 0.35),
        vec3<f32>(0.65, 0.85, 0.15), vec3<f32>(0.95, 0.80, 0.10), vec3<f32>(0.95, 0.50, 0.10),
        vec3<f32>(0.90, 0.15, 0.15), vec3<f32>(0.55, 0.25, 0.70),
    );
    return colours[k % 8u];
}

// Whether the tile cell under tile sample coordinates `uv` is terrain.
fn is_terrain(uv: vec2<f32>, slot: u32) -> bool {
    let last = i32(g.mode.z) - 1;
    let cell = clamp(vec2<i32>(floor(uv)), vec2<i32>(0), vec2<i32>(last));
    return textureLoad(masks, cell, i32(slot), 0).r > 0.5;
}

// The unlit colour at tile sample coordinates `uv`: the tile's imagery (or its
// nearest ancestor's, at the tile's place in it) where there is one, else the
// hypsometric tint. Imagery texel (u, v) is centred at tile sample
// ((u + ½)·T/side, …) (FORMAT.md "Imagery pyramids"), so texture coordinate uv / T
// reads the imagery at sample uv; k levels up, the tile at offset p of the
// ancestor's 2^k × 2^k descendants reads (uv / T + p) / 2^k.
fn surface_colour(uv: vec2<f32>, slot: u32) -> vec3<f32> {
    let src = textureLoad(imagery_source, vec2<i32>(i32(slot), 0), 0).rg;
    if (src.x > 0u) {
        let k = src.y & 0xffu;
        let p = vec2<f32>(f32((src.y >> 8u) & 0xfffu), f32(src.y >> 20u));
        let t = (uv / f32(g.mode.z) + p) / f32(1u << k);
        return textureSampleLevel(imagery, linear_clamp, t, i32(src.x - 1u), 0.0).rgb;
    }
    return tint(fine_height(uv, slot));
}

// The light at tile sample coordinates `uv` of the tile in `slot`: ambient and
// Lambert from its normal map.
fn lit(uv: vec2<f32>, slot: u32) -> f32 {
    let n = normal_at(uv, slot);
    return 0.25 + 0.75 * max(dot(n, g.sun.xyz), 0.0);
}

// Aerial perspective: how much haze lies between the eye and a point `dist` metres
// away at height `h`. The air's density falls off as exp(−(y − base)/H) with height
// y, so the haze follows the air mass the ray crosses, not its length alone: seen
// from high above, the whole dataset stays clear; from a valley floor, the far walls
// fade. Along the ray from the point (height h) to the eye (height h + x·H) the
// mass is dist · ρ(h) · (1 − e^−x)/x, exactly.
fn haze_amount(dist: f32, h: f32) -> f32 {
    let scale = g.air.x;
    let x = clamp((g.eye_frac.y - h) / scale, -30.0, 60.0);
    var mean = 1.0 - 0.5 * x;
    if (abs(x) > 1e-3) {
        mean = (1.0 - exp(-x)) / x;
    }
    let mass = dist * exp(min((g.quant.z - h) / scale, 30.0)) * mean;
    return 1.0 - exp(-mass / g.haze.w);
}

@fragment
fn fs_main(in: VsOut) -> @location(0) vec4<f32> {
    // Derivatives first, in uniform control flow.
    let fw = max(fwidth(in.grid), vec2<f32>(1e-4));
    let slot = in.info.x;
    let view = g.mode.x;
    // Cells that are not terrain (no-data, padding beyond the DEM) are not drawn:
    // the cell is the one under the drawn (base) mesh, before parallax moves the
    // texture lookups.
    let terrain = is_terrain(in.uv, slot);
    if (!terrain && view != 4u) {
        discard;
    }
    let d = normalize(in.rel);
    // Metres per tile sample: finest spacing × finest samples per tile sample.
    let m = g.spacing.xy * f32(in.stride);
    let uv = parallax(in.uv, in.base_h, d, m, f32(in.info.w), slot);
    let light = lit(uv, slot);
    var colour = surface_colour(uv, slot) * light;
    if (in.fade.x > 0u) {
        // A refinement fading in (`select/fade.rs`): the same point in the
        // ancestor `up` levels up, whose 2^up × 2^up descendants this tile is one
        // of, at the offset given; its shading mixed in by the factor.
        let up = in.fade.y & 0xffu;
        let source = in.fade.y >> 8u;
        let uv_a = (uv + vec2<f32>(f32(in.fade.z), f32(in.fade.w)) * f32(g.mode.z)) / f32(1u << up);
        let was = surface_colour(uv_a, source) * lit(uv_a, source);
        colour = mix(colour, was, f32(in.fade.x) / 256.0);
    }
    if (view == 1u) {
        colour = palette(firstTrailingBit(in.info.z)) * light;
    } else if (view == 2u) {
        colour = palette(in.info.y) * light;
    } else if (view == 3u) {
        // Wireframe over the shaded terrain: distance to the nearest grid line or
        // cell diagonal, in pixels.
        let f = fract(in.grid);
        let edge = min(min(f / fw, (1.0 - f) / fw), vec2<f32>(abs(f.x - f.y) / max(fw.x, fw.y)));
        let line = 1.0 - clamp(min(edge.x, edge.y), 0.0, 1.0);
        colour = mix(colour, vec3<f32>(0.05, 0.05, 0.05), line);
    } else if (view == 4u && !terrain) {
        // The mask view: what the other views discard, in red.
        colour = vec3<f32>(0.9, 0.1, 0.1) * (0.5 + 0.5 * light);
    }
    if (view != 1u && view != 2u) {
        colour = mix(colour, g.haze.rgb, haze_amount(length(in.rel), in.base_h));
    }
    // Keep terrain distinguishable from the sky colour in every view.
    colour = clamp(colour, vec3<f32>(0.02), vec3<f32>(0.98));
    return vec4<f32>(colour, 1.0);
}

// The vertex-capture pass: one invocation per (instance, vertex); the vertex
// index rides in `c.w`, which instances leave 0 (two storage buffers, not three:
// lavapipe's GL allows four per stage, group 0 included).
struct CaptureJob {
    a: vec4<u32>,
    b: vec4<u32>,
    c: vec4<u32>,
    // The instance's shading fade: not read here, but part of its layout.
    d: vec4<u32>,
};
@group(1) @binding(0) var<storage, read> jobs: array<CaptureJob>;
// (x, y, q, h) per job.
@group(1) @binding(1) var<storage, read_write> captured: array<vec4<u32>>;

@compute @workgroup_size(64)
fn capture(@builtin(global_invocation_id) id: vec3<u32>) {
    let k = id.x;
    if (k >= arrayLength(&jobs)) {
        return;
    }
    let t = terrain_vertex(jobs[k].a, jobs[k].b, jobs[k].c, jobs[k].c.w);
    captured[k] = vec4<u32>(t.x, t.y, t.q, t.h);
}
