//! Shading fades (DECISIONS.md "Geomorphing over time"): a refined tile's shading comes
//! in over time.
//!
//! Geomorphing ([`super::morph`]) makes a tile refinement continuous in geometry:
//! the children start exactly at the surface their parent drew. Their *shading*
//! still jumps: each child has its own normal map and colour (imagery, or the
//! hypsometric tint of its own heights), one level finer than its parent's, and
//! the finer normals light every pixel of the tile a little differently at once.
//! Measured on the moon descent of `bench/popping.sh`, that was almost all of the
//! same-camera pop of its two tile refinements (0.20 and 0.19 per pixel, against
//! 0.006 and 0.003 with a constant normal), and the two were most of the flight's.
//!
//! So, as a geomorph transition starts from the surface drawn there, a fade starts
//! from the shading drawn there: a tile drawn this frame where one of its ancestors
//! was drawn last frame (a refinement, by one level or more) is shaded as a mix of
//! its own shading and that ancestor's at the same point, wholly the ancestor's at
//! first and its own after [`super::SelectParams::morph_seconds`], linearly in the
//! caller's time (as transitions, so runs are reproducible and a settled frame
//! selecting again at the same time advances nothing). The renderer
//! (`terrain.wgsl`) reads the ancestor's normal map and colour from the
//! ancestor's slot; where the ancestor has none any more, the tile is drawn as
//! itself.
//!
//! What a fade does not cover, said so: a tile whose ancestor was itself fading
//! starts from that ancestor's own shading (the nearest drawn ancestor, wholly),
//! not from the mix drawn there; a merge (a tile drawn where its children were)
//! changes its shading at once, since its shading would have to come from four
//! slots; and neither happens on a descent.

use super::params::SelectParams;
use super::patch::FULL;
use std::collections::HashMap;
use tessera_shared::TileId;

pub use super::patch::Fade;

/// The fades of one frame's tiles: for each drawn tile, the ancestor (levels up)
/// its fade started from and when, if it is fading.
#[derive(Clone, Debug, Default)]
pub struct Fades {
    tiles: HashMap<TileId, Option<(u8, f64)>>,
}

impl Fades {
    /// The fades of the tiles drawn at time `t`, following on from `before` (the
    /// last frame drawn at an earlier time): a tile drawn then keeps its fade (or
    /// its lack of one); a tile drawn where an ancestor was drawn then starts one
    /// from the nearest such ancestor; any other starts none.
    pub fn next(before: &Fades, tiles: &[TileId], t: f64) -> Self {
        let tiles = tiles
            .iter()
            .map(|&tile| {
                if let Some(&kept) = before.tiles.get(&tile) {
                    return (tile, kept);
                }
                let (mut a, mut up) = (tile, 0u8);
                while let Some(p) = a.parent() {
                    (a, up) = (p, up + 1);
                    if before.tiles.contains_key(&a) {
                        return (tile, Some((up, t)));
                    }
                }
                (tile, None)
            })
            .collect();
        Self { tiles }
    }

    /// The tiles of a frame with no fade in flight (the first, or one selected
    /// without a clock).
    pub fn settled(tiles: &[TileId]) -> Self {
        Self {
            tiles: tiles.iter().map(|&t| (t, None)).collect(),
        }
    }

    /// The fade of `tile` at time `t`: the factor falls from [`FULL`] at the
    /// start to 0 after `params.morph_seconds` (none without transitions).
    pub fn at(&self, params: &SelectParams, tile: TileId, t: f64) -> Fade {
        let Some(&Some((up, start))) = self.tiles.get(&tile) else {
            return Fade::NONE;
        };
        if !params.transitions() {
            return Fade::NONE;
        }
        let left = 1.0 - (t - start) / params.morph_seconds;
        let factor = (left * f64::from(FULL)).ceil().clamp(0.0, f64::from(FULL)) as u16;
        Fade::new(up, factor).unwrap_or(Fade::NONE)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::Level;

    fn tile(level: u8, x: u32, y: u32) -> TileId {
        TileId::new(Level::new(level).unwrap(), x, y).unwrap()
    }

    #[test]
    fn a_refinement_fades_in_from_the_ancestor_drawn_over_the_morph_time() {
        let params = SelectParams {
            morph_seconds: 0.25,
            ..SelectParams::default()
        };
        let parent = tile(2, 1, 2);
        let children = parent.children().unwrap();
        let f0 = Fades::settled(&[parent, tile(2, 0, 0)]);
        // At t = 1 the parent is refined; a grandchild of (0, 0) appears, two
        // levels below what was drawn.
        let grandchild = tile(4, 1, 3);
        let mut drawn = children.to_vec();
        drawn.push(grandchild);
        let f1 = Fades::next(&f0, &drawn, 1.0);
        assert_eq!(
            f1.at(&params, children[3], 1.0),
            Fade {
                up: 1,
                factor: FULL
            }
        );
        assert_eq!(
            f1.at(&params, grandchild, 1.0),
            Fade {
                up: 2,
                factor: FULL
            }
        );
        // Where it reads: the parent, at the child's place among its four; the
        // grandparent at (1, 3) of its 4 × 4.
        assert_eq!(
            Fade { up: 1, factor: 9 }.source(children[3]),
            Some((parent, [1, 1]))
        );
        assert_eq!(
            Fade { up: 2, factor: 9 }.source(grandchild),
            Some((tile(2, 0, 0), [1, 3]))
        );
        assert_eq!(Fade::NONE.source(grandchild), None);
        // Kept while drawn, falling linearly with time (rounded up), gone after
        // the morph time; at the same time nothing advances.
        let f2 = Fades::next(&f1, &drawn, 1.1);
        assert_eq!(f2.at(&params, children[0], 1.1).factor, 154);
        assert_eq!(f2.at(&params, children[0], 1.25).factor, 0);
        assert_eq!(f2.at(&params, children[0], 1.25), Fade::NONE);
        // Without transitions, or for a tile that appeared where nothing was
        // drawn (or its parent merged back), no fade.
        let off = SelectParams {
            morph_seconds: 0.0,
            ..params
        };
        assert_eq!(f1.at(&off, children[0], 1.0), Fade::NONE);
        let f3 = Fades::next(&f2, &[parent, tile(2, 3, 3)], 1.2);
        assert_eq!(f3.at(&params, parent, 1.2), Fade::NONE);
        assert_eq!(f3.at(&params, tile(2, 3, 3), 1.2), Fade::NONE);
        assert_eq!(Fade::new(0, 5), None);
        assert_eq!(Fade::new(1, 0), None);
        assert_eq!(Fade::new(1, FULL + 1), None);
    }
}
