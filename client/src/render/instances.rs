//! Per-instance data for the terrain draws: one record per patch, grouped by inner
//! LOD so that each LOD is one instanced draw (at most 7 per frame,
//! docs/ARCHITECTURE.md#rendering).

use crate::select::Patch;
use tessera_shared::{TileGeometry, TileId};

/// Inner LODs 1, 2, 4, …, 64: one index buffer and one draw each.
pub const LODS: [u32; 7] = [1, 2, 4, 8, 16, 32, 64];

/// Two `vec4<u32>` as the shader reads them (`terrain.wgsl`):
/// `a = (slot | level << 16, origin x | origin y << 16, size, inner)`,
/// `b = (edges N | E << 8 | S << 16 | W << 24, tile origin x, tile origin y, stride)`,
/// `c = (interior morph, morph N | E << 16, morph S | W << 16, 0)` (factors in
/// `0..=`[`crate::select::morph::FULL`]),
/// `d = (fade factor, levels up | source slot << 8, offset x, offset y)`: the
/// shading fade ([`crate::select::fade`]) from the ancestor in that slot, the
/// tile at that offset among its descendants; factor 0 without one.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Instance {
    pub a: [u32; 4],
    pub b: [u32; 4],
    pub c: [u32; 4],
    pub d: [u32; 4],
}

impl Instance {
    /// The instance of patch `p` in GPU slot `slot`, morphed as `p.morph` says,
    /// and shaded as `p.fade` says when its fade's ancestor has a slot
    /// (`source_slot`; without one, as itself).
    pub fn new(g: &TileGeometry, p: &Patch, slot: u32, source_slot: Option<u32>) -> Self {
        let (gx, gy) = g.origin(p.tile);
        let e = p.edges;
        let m = p.morph.edges.map(u32::from);
        Self {
            a: [
                slot | u32::from(p.tile.level().get()) << 16,
                p.origin[0] | p.origin[1] << 16,
                p.size,
                p.inner,
            ],
            b: [
                e[0] | e[1] << 8 | e[2] << 16 | e[3] << 24,
                gx as u32,
                gy as u32,
                g.spacing(p.tile.level()) as u32,
            ],
            c: [
                u32::from(p.morph.inner),
                m[0] | m[1] << 16,
                m[2] | m[3] << 16,
                0,
            ],
            d: match (p.fade.source(p.tile), source_slot) {
                (Some((_, [ox, oy])), Some(source)) => [
                    u32::from(p.fade.factor),
                    u32::from(p.fade.up) | source << 8,
                    ox,
                    oy,
                ],
                _ => [0; 4],
            },
        }
    }
}

/// Instances sorted by inner LOD, and how many there are of each LOD in [`LODS`].
#[derive(Debug, Default)]
pub struct Batches {
    pub instances: Vec<Instance>,
    pub counts: [u32; 7],
    /// Patches skipped because their tile has no GPU slot.
    pub skipped: usize,
}

impl Batches {
    /// `morph`: draw the patches' morph factors and shading fades, or every
    /// patch unmorphed and as itself. `slot_of` gives a tile's GPU slot.
    pub fn build(
        g: &TileGeometry,
        patches: &[Patch],
        morph: bool,
        slot_of: impl Fn(TileId) -> Option<u32>,
    ) -> Self {
        let mut b = Self::default();
        let mut keyed: Vec<(u32, Instance)> = Vec::with_capacity(patches.len());
        for p in patches {
            match slot_of(p.tile) {
                Some(slot) => {
                    let source = p.fade.source(p.tile).and_then(|(a, _)| slot_of(a));
                    let mut inst = Instance::new(g, p, slot, source);
                    if !morph {
                        inst.c = [0; 4];
                        inst.d = [0; 4];
                    }
                    keyed.push((p.inner.trailing_zeros(), inst));
                }
                None => b.skipped += 1,
            }
        }
        keyed.sort_by_key(|(k, _)| *k);
        for (k, inst) in keyed {
            b.counts[k as usize] += 1;
            b.instances.push(inst);
        }
        b
    }

    /// `(inner LOD, first instance, instance count)` of each non-empty draw.
    pub fn draws(&self) -> Vec<(u32, u32, u32)> {
        let mut first = 0;
        let mut out = Vec::new();
        for (k, &count) in self.counts.iter().enumerate() {
            if count > 0 {
                out.push((LODS[k], first, count));
            }
            first += count;
        }
        out
    }
}

/// Index data for every LOD's `n × n` grid, concatenated, and each LOD's range;
/// triangles as the reference tessellator splits cells (NW → SE diagonal).
pub fn index_buffers() -> (Vec<u16>, [std::ops::Range<u32>; 7]) {
    let mut data = Vec::new();
    let ranges = LODS.map(|n| {
        let start = data.len() as u32;
        for t in crate::tessellate::triangles(n) {
            data.extend(t.iter().map(|&i| i as u16));
        }
        start..data.len() as u32
    });
    (data, ranges)
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::{Level, TileId};

    #[test]
    fn packs_what_the_shader_unpacks_and_batches_by_lod() {
        let g = TileGeometry::new(2049, 2049, 512).unwrap();
        let tile = TileId::new(Level::new(2).unwrap(), 3, 1).unwrap();
        let p = |inner, origin| Patch {
            tile,
            origin,
            size: 128,
            inner,
            edges: [inner, inner / 2, 1, inner],
            morph: crate::select::morph::Morph::new(inner as u16 * 4, [1, 2, 3, 256]).unwrap(),
            fade: crate::select::fade::Fade::NONE,
        };
        // A patch of a tile with no slot is skipped.
        let elsewhere = TileId::new(Level::new(2).unwrap(), 0, 0).unwrap();
        let patches = [
            p(16, [384, 128]),
            p(1, [0, 0]),
            p(16, [0, 384]),
            Patch {
                tile: elsewhere,
                ..p(64, [128, 0])
            },
        ];
        let slot_of = |t: TileId| (t != elsewhere).then_some(7);
        let b = Batches::build(&g, &patches, true, slot_of);
        let unmorphed = Batches::build(&g, &patches, false, |_| Some(7));
        assert!(unmorphed.instances.iter().all(|i| i.c == [0; 4]));
        assert_eq!(b.skipped, 1);
        assert_eq!(b.draws(), vec![(1, 0, 1), (16, 1, 2)]);
        let i = b.instances[1];
        assert_eq!(i.a[0] & 0xffff, 7);
        assert_eq!(i.a[0] >> 16, 2);
        assert_eq!((i.a[1] & 0xffff, i.a[1] >> 16), (384, 128));
        assert_eq!((i.a[2], i.a[3]), (128, 16));
        assert_eq!(
            [
                i.b[0] & 0xff,
                (i.b[0] >> 8) & 0xff,
                (i.b[0] >> 16) & 0xff,
                i.b[0] >> 24
            ],
            [16, 8, 1, 16]
        );
        assert_eq!((i.b[1], i.b[2], i.b[3]), (3 * 512, 512, 1));
        assert_eq!(i.c[0], 64);
        assert_eq!(
            [i.c[1] & 0xffff, i.c[1] >> 16, i.c[2] & 0xffff, i.c[2] >> 16],
            [1, 2, 3, 256]
        );
        // No fade: d is 0.
        assert_eq!(i.d, [0; 4]);
        // A fade from the grandparent, level 0 (the root), in slot 300: the tile
        // (3, 1) of level 2 is at (3, 1) among its 4 × 4 descendants; without a
        // slot for the root, or unmorphed, no fade.
        let fading = Patch {
            fade: crate::select::fade::Fade::new(2, 200).unwrap(),
            ..p(16, [0, 0])
        };
        let root = TileId::new(Level::ROOT, 0, 0).unwrap();
        let with = |slot: Option<u32>, morph| {
            Batches::build(
                &g,
                &[fading],
                morph,
                |t| if t == root { slot } else { Some(7) },
            )
            .instances[0]
                .d
        };
        assert_eq!(with(Some(300), true), [200, 2 | 300 << 8, 3, 1]);
        assert_eq!(with(None, true), [0; 4]);
        assert_eq!(with(Some(300), false), [0; 4]);
        let (data, ranges) = index_buffers();
        assert_eq!(ranges[6].len(), 6 * 64 * 64);
        assert_eq!(data.len(), ranges[6].end as usize);
        assert_eq!(
            *data[ranges[6].start as usize..ranges[6].end as usize]
                .iter()
                .max()
                .unwrap(),
            65 * 65 - 1
        );
    }
}
