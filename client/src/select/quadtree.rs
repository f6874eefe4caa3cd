//! Kang's per-tile quadtree (§4.2) with frame-to-frame memory (§4.4).
//!
//! Node `(k, i, j)` covers `T/2^k` tile cells; drawn with inner LOD `n` it is the
//! within-tile level `m = k + log2(n)`. A node takes the smallest `n ≤ 64` whose
//! `ρ` meets `τ`, and splits when even 64 does not (down to depth `t − 6`, where 64
//! is full resolution). Kang merges bottom-up (Alg. 1) and splits top-down (Alg. 2)
//! from last frame's tree; evaluating top-down with last frame's decisions as the
//! tie-breaker gives the same tree. Hysteresis: a node stays split, and keeps a
//! finer LOD, until the coarser choice is below `τ·(1 − h)`.

use super::metric::{TileRho, node_index};
use super::params::SelectParams;
use super::patch::{Fade, Morph, Patch};
use super::world::World;
use tessera_shared::TileId;

/// Last frame's decision for every node: bit 7 = split, low bits = `log2(n) + 1`
/// (0 = not a leaf).
#[derive(Clone, Debug, Default)]
pub struct TileState {
    nodes: Vec<u8>,
}

const SPLIT: u8 = 0x80;

impl TileState {
    fn get(&self, k: u32, i: u32, j: u32) -> u8 {
        self.nodes.get(node_index(k, i, j)).copied().unwrap_or(0)
    }
}

/// Builds the tile's leaves into `out`; returns the new state and the largest `ρ` drawn.
pub fn build(
    world: &World,
    params: &SelectParams,
    tile: TileId,
    rho: &TileRho,
    prev: Option<&TileState>,
    out: &mut Vec<Patch>,
) -> (TileState, f64) {
    let t = world.geometry.tile_log2();
    let max_depth = world.max_depth();
    let mut state = TileState {
        nodes: vec![0; node_index(max_depth + 1, 0, 0)],
    };
    let empty = TileState::default();
    let prev = prev.unwrap_or(&empty);
    let relaxed = params.tau * (1.0 - params.hysteresis);
    let mut max_rho = 0f64;
    let mut stack = vec![(0u32, 0u32, 0u32)];
    while let Some((k, i, j)) = stack.pop() {
        let before = prev.get(k, i, j);
        // LOD 64 (or the finest this depth allows) decides splitting.
        let top = (t - k).min(6);
        let rho_top = rho.rho(k + top, k, i, j);
        let split =
            k < max_depth && (rho_top > params.tau || (before & SPLIT != 0 && rho_top > relaxed));
        if split {
            state.nodes[node_index(k, i, j)] = SPLIT;
            for (di, dj) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                stack.push((k + 1, 2 * i + di, 2 * j + dj));
            }
            continue;
        }
        let smallest = |limit: f64| {
            (0..=top)
                .find(|&l| rho.rho(k + l, k, i, j) <= limit)
                .unwrap_or(top)
        };
        let strict = smallest(params.tau);
        let loose = smallest(relaxed).max(strict);
        let l = match before & !SPLIT {
            0 => strict,
            b => u32::from(b - 1).clamp(strict, loose),
        };
        state.nodes[node_index(k, i, j)] = l as u8 + 1;
        max_rho = max_rho.max(rho.rho(k + l, k, i, j));
        let size = world.geometry.tile_size() >> k;
        out.push(Patch {
            tile,
            origin: [i * size, j * size],
            size,
            inner: 1 << l,
            edges: [1 << l; 4],
            morph: Morph::NONE,
            fade: Fade::NONE,
        });
    }
    (state, max_rho)
}
