//! What a tile upload costs with normal maps built on the CPU against the GPU's
//! compute pass (DECISIONS.md "Normal maps on the GPU"): every tile of the moon 4096²
//! built with 256-cell tiles (257² samples), uploaded in batches of 8 on a headless
//! renderer (lavapipe where there is no GPU), the arms alternating `RUNS` times (default
//! 3). Per tile, medians over the batches: the CPU time of `upload` (what the per-frame
//! upload budget pays), the flush that submits the compute pass, and the wait for the
//! device (copies and, on the GPU path, the pass itself).
//!
//! `cargo run --release -p tessera-e2e --example upload_cost`

#![allow(clippy::unwrap_used, clippy::print_stderr)] // a measuring tool

use std::time::Instant;
use tessera_client::render::gpu::Backend;
use tessera_client::render::normals::NormalSource;
use tessera_client::render::{RenderOptions, Renderer};
use tessera_e2e::Moon;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let Some(m) = Moon::build(256) else { return };
    let runs: usize = std::env::var("RUNS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(3);
    let meta = m.pyramid.metadata();
    let pool = m.pool();
    let mut tiles: Vec<_> = m.tables.keys().copied().collect();
    tiles.sort_unstable();
    let n = m.world.geometry.tile_samples();
    for run in 1..=runs {
        for source in [NormalSource::Cpu, NormalSource::Gpu] {
            let opts = RenderOptions {
                width: 64,
                height: 64,
                slots: tiles.len() as u32 + 1,
                backend: Backend::Vulkan,
                normals: source,
                ..RenderOptions::default()
            };
            let mut r = Renderer::new(m.world, (meta.min_height, meta.max_height), opts).unwrap();
            // The first tile and pass initialize the device's textures and buffers.
            r.upload(&pool, tiles[0]);
            r.flush_normals();
            r.gpu.wait().unwrap();
            let (mut upload, mut flush, mut wait) = (Vec::new(), Vec::new(), Vec::new());
            for batch in tiles[1..].chunks(8) {
                let k = batch.len() as f64;
                let t = Instant::now();
                for &tile in batch {
                    r.upload(&pool, tile);
                }
                upload.push(t.elapsed().as_secs_f64() * 1e3 / k);
                let t = Instant::now();
                r.flush_normals();
                flush.push(t.elapsed().as_secs_f64() * 1e3 / k);
                let t = Instant::now();
                r.gpu.wait().unwrap();
                wait.push(t.elapsed().as_secs_f64() * 1e3 / k);
            }
            eprintln!(
                "{{\"run\":{run},\"normals\":\"{}\",\"tiles\":{},\"samples\":{n},\"gpu\":\"{}\",\"upload_ms_per_tile\":{:.3},\"flush_ms_per_tile\":{:.3},\"wait_ms_per_tile\":{:.3}}}",
                if source == NormalSource::Gpu {
                    "gpu"
                } else {
                    "cpu"
                },
                tiles.len() - 1,
                r.gpu.describe(),
                median(upload),
                median(flush),
                median(wait)
            );
        }
    }
}
