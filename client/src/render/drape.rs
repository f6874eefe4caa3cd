//! Imagery draped over the terrain (DECISIONS.md "Imagery pyramids"; Yang §3: texture LOD
//! follows grid LOD): one `Rgba8Unorm` texture-array layer per GPU slot, the same slot as
//! the tile's heights, and a one-row `Rg32Uint` texture saying, per slot, where its
//! tile's imagery is: its own layer, or — until that arrives — the layer of its
//! nearest ancestor that has its imagery, with the ancestor level's offset of the
//! tile (`r` = 1 + the layer, `g` = levels up | x offset << 8 | y offset << 20); `r` =
//! 0: none, the hypsometric tint (`terrain.wgsl`, `surface_colour`).
//!
//! `Rgba8Unorm`, not `Srgb`: the colour target is `Rgba8Unorm` and the tint is
//! written as stored bytes, so the imagery's bytes pass through unchanged.
//!
//! The textures and what each slot's layer holds are [`ImageryTextures`]; here are
//! the renderer's draping methods: making room, uploading, resolving ancestors.

use super::drape_textures::ImageryTextures;
use super::error::RenderError;
use super::renderer::Renderer;
use crate::stream::imagery_tiles::{ImageryPool, Texels};
use tessera_shared::TileId;

impl Renderer {
    /// Makes room for imagery of `side × side` texels per tile (the dataset's
    /// `imagery.texels`); every slot starts without.
    pub fn enable_imagery(&mut self, side: u32) -> Result<(), RenderError> {
        let dim = self.gpu.limits.max_texture_dimension_2d;
        if !(1..=dim).contains(&side) {
            return Err(RenderError::ImageryTooLarge { side, dim });
        }
        let layers = self.imagery.layers();
        self.imagery = ImageryTextures::new(&self.gpu.device, layers, side);
        self.rebuild_bind_group();
        Ok(())
    }

    /// Texels per tile side of the imagery (`None` without imagery).
    pub fn imagery_side(&self) -> Option<u32> {
        (self.imagery.side > 1).then_some(self.imagery.side)
    }

    /// Whether `tile` is on the GPU with its imagery.
    pub fn has_imagery(&self, tile: TileId) -> bool {
        self.slots
            .get(tile)
            .is_some_and(|s| self.imagery.holds(s) == Some(tile))
    }

    /// Of `tiles`, those on the GPU without their imagery yet.
    pub fn imagery_missing(&self, tiles: &[TileId]) -> Vec<TileId> {
        tiles
            .iter()
            .copied()
            .filter(|&t| self.slots.get(t).is_some() && !self.has_imagery(t))
            .collect()
    }

    /// Writes `tile`'s imagery into its slot's layer. `false` when the tile has no
    /// slot, or the texels are not the size [`Renderer::enable_imagery`] set.
    pub fn upload_imagery(&mut self, tile: TileId, texels: &Texels) -> bool {
        let Some(slot) = self.slots.get(tile) else {
            return false;
        };
        let side = self.imagery.side;
        if texels.side != side || texels.rgba.len() != (side * side * 4) as usize {
            return false;
        }
        if self.has_imagery(tile) {
            return true;
        }
        super::upload::write_layer(
            &self.gpu.queue,
            &self.imagery.texels,
            slot,
            &texels.rgba,
            side,
            4,
        );
        self.imagery.set_holds(&self.gpu.queue, slot, Some(tile));
        true
    }

    /// Uploads the pooled imagery of those of `tiles` (the drawn ones) that are on
    /// the GPU without it. Returns how many layers were written.
    pub fn upload_imagery_from(&mut self, pool: &ImageryPool, tiles: &[TileId]) -> u32 {
        let mut n = 0;
        for t in self.imagery_missing(tiles) {
            if let Some(texels) = pool.get(t)
                && self.upload_imagery(t, texels)
            {
                n += 1;
            }
        }
        self.resolve_imagery(tiles);
        n
    }

    /// Points each of `tiles` (the drawn ones) without its own imagery at its
    /// nearest ancestor's, when one is on the GPU with it (the shader reads the
    /// ancestor's layer at the tile's place in it), else at none (the tint). Run
    /// after uploads and before drawing: an ancestor of a drawn tile keeps its slot
    /// this frame ([`super::slots::SlotTable::touch`]).
    pub fn resolve_imagery(&mut self, tiles: &[TileId]) {
        for &t in tiles {
            let Some(slot) = self.slots.get(t) else {
                continue;
            };
            if self.has_imagery(t) {
                continue;
            }
            let mut source = [0, 0];
            let mut a = t;
            for k in 1..=12u32 {
                let Some(p) = a.parent() else { break };
                a = p;
                if self.has_imagery(a)
                    && let Some(s) = self.slots.get(a)
                {
                    let (px, py) = (t.x() - (a.x() << k), t.y() - (a.y() << k));
                    source = [s + 1, k | px << 8 | py << 20];
                    break;
                }
            }
            self.imagery.set_source(&self.gpu.queue, slot, source);
        }
    }

    /// A slot now holds `tile`'s heights: its imagery layer is stale until
    /// [`Renderer::upload_imagery`].
    pub(super) fn imagery_slot_taken(&mut self, slot: u32, tile: TileId) {
        if self.imagery.holds(slot) != Some(tile) {
            self.imagery.set_holds(&self.gpu.queue, slot, None);
        }
    }
}
