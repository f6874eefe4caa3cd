//! Which Cesium tiles hold data (DECISIONS.md "Cesium terrain", "Availability"): the
//! tiles `layer.json` and the tiles' metadata say exist, so that CesiumJS asks for
//! no other.
//!
//! A tile is available when a valid finest cell of the pyramid (a cell whose four
//! corners are data: `tessera_shared::mask`) reaches into its open rectangle. Absent
//! pyramid tiles (a mosaic's missing piece) and masked cells (no-data, the padding
//! beyond the DEM) make no tile available, so a hole in the data is a hole in the
//! availability at the zooms whose tiles fit in it. It is computed once per dataset:
//! at the deepest zoom from the pyramid's index (a tile stored without the partial
//! flag is valid throughout, one absent has no cell) and the masks of the partial
//! tiles, then each coarser zoom from the one below (a tile is available when one of
//! its four children is).
//!
//! Both root tiles (zoom 0) are always available: CesiumJS assumes so whenever
//! `layer.json` has `metadataAvailability`; a root without data is a sea-level tile.
//!
//! CesiumJS learns the deeper zooms from the tiles themselves: a tile whose zoom is a
//! multiple of [`AVAILABILITY_LEVELS`] carries, in its metadata extension, the
//! available tiles under it for the next `AVAILABILITY_LEVELS` zooms
//! ([`Availability::carried`]).

use super::mapping::Mapping;
use super::{LevelData, Terrain};
use crate::cesium::tiling::CesiumTile;
use tessera_shared::TileId;

/// `metadataAvailability`: the zooms a tile's metadata says the availability of,
/// and the step between the zooms that carry it (Cesium ion's value).
pub const AVAILABILITY_LEVELS: u8 = 10;

/// How a finest pyramid tile holds data, from its index entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stored {
    /// No record: no valid cell.
    Absent,
    /// Every cell valid (no partial flag).
    Full,
    /// Some cells masked: the record's mask says which.
    Partial,
}

/// One row's runs `[x0, x1]` (inclusive) of available tiles: sorted, disjoint and
/// not adjacent.
type Runs = Vec<(u32, u32)>;

/// One zoom: the first row's `y`, then each row's runs.
type Zoom = (u32, Vec<Runs>);

/// The available tiles of every zoom.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Availability {
    /// Per zoom `0..=max_zoom`.
    zooms: Vec<Zoom>,
}

/// A rectangle of tiles `[x0, y0, x1, y1]`, inclusive.
pub type Range = [u32; 4];

impl Terrain {
    /// The dataset's availability: `stored` says how each finest pyramid tile holds
    /// data (from the index); masks of partial tiles are read through `data`.
    pub fn availability<D: LevelData>(
        &self,
        stored: impl Fn(TileId) -> Stored,
        data: &D,
    ) -> Result<Availability, D::Error> {
        let g = &self.geometry;
        let z = self.max_zoom;
        let Some([_, y0, _, y1]) = self.available(z) else {
            return Ok(Availability::roots_only(z));
        };
        // A projected box's edges may bulge a little past the bounds' points.
        let mut rows = Rows::new(y0.saturating_sub(2), (y1 + 2).min((1 << z) - 1));
        let finest = g.finest();
        let t = g.tile_size();
        let (last_col, last_row) = (g.width() - 1, g.height() - 1);
        for tile in g.present_tiles(finest) {
            let (ox, oy) = g.origin(tile);
            let (ox, oy) = (ox as u32, oy as u32);
            let (cx1, cy1) = ((ox + t).min(last_col), (oy + t).min(last_row));
            match stored(tile) {
                Stored::Absent => {}
                Stored::Full => {
                    for r in self.cells_covering(z, [ox, oy, cx1, cy1]) {
                        rows.add(r);
                    }
                }
                Stored::Partial => {
                    data.check()?;
                    let Some(src) = data.tile(tile)? else {
                        continue;
                    };
                    for cy in 0..(cy1 - oy) {
                        let mut cx = 0;
                        while cx < cx1 - ox {
                            if !src.mask.is_valid(cx, cy) {
                                cx += 1;
                                continue;
                            }
                            let start = cx;
                            while cx < cx1 - ox && src.mask.is_valid(cx, cy) {
                                cx += 1;
                            }
                            let cells = [ox + start, oy + cy, ox + cx, oy + cy + 1];
                            for r in self.cells_covering(z, cells) {
                                rows.add(r);
                            }
                        }
                    }
                }
            }
        }
        let mut zooms = vec![rows.finish()];
        for _ in 0..z {
            let (first, finer) = zooms.last().expect("one zoom at least");
            zooms.push(coarser(*first, finer));
        }
        zooms.reverse();
        zooms[0] = (0, vec![vec![(0, 1)]]);
        Ok(Availability { zooms })
    }

    /// The tiles of zoom `z` whose open rectangle meets the open box of finest cells
    /// `[c0, r0, c1, r1)` (their corner samples `c0..=c1`, `r0..=r1`).
    fn cells_covering(&self, z: u8, [c0, r0, c1, r1]: [u32; 4]) -> Vec<Range> {
        let corners: Vec<[f64; 2]> = match self.mapping {
            Mapping::Affine { .. } => vec![[c0, r0], [c1, r1]]
                .into_iter()
                .filter_map(|[c, r]| self.mapping.lon_lat(f64::from(c), f64::from(r)))
                .collect(),
            // A projected box is curved in longitude and latitude: its bounding box
            // from points along its edges (a little more than the box, never less
            // but for the curvature between 8 points an edge).
            Mapping::Projected { .. } => (0..=8)
                .flat_map(|k| {
                    let t = f64::from(k) / 8.0;
                    let c = f64::from(c0) + t * f64::from(c1 - c0);
                    let r = f64::from(r0) + t * f64::from(r1 - r0);
                    [
                        [c, f64::from(r0)],
                        [c, f64::from(r1)],
                        [f64::from(c0), r],
                        [f64::from(c1), r],
                    ]
                })
                .filter_map(|[c, r]| self.mapping.lon_lat(c, r))
                .collect(),
        };
        let (mut w, mut s, mut e, mut n) = (
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        );
        for [lon, lat] in corners {
            (w, s, e, n) = (w.min(lon), s.min(lat), e.max(lon), n.max(lat));
        }
        // East of the antimeridian (a geographic grid crossing it): the tiles from −180.
        let mut out: Vec<Range> = CesiumTile::covering(z, [w, s, e, n]).into_iter().collect();
        if e > 180.0 {
            out.extend(CesiumTile::covering(z, [w - 360.0, s, e - 360.0, n]));
        }
        out
    }
}

/// Rows of runs being collected.
struct Rows {
    first: u32,
    runs: Vec<Runs>,
    /// Per row, its length when last merged.
    merged: Vec<usize>,
}

impl Rows {
    fn new(first: u32, last: u32) -> Self {
        let n = (last - first + 1) as usize;
        Self {
            first,
            runs: vec![Vec::new(); n],
            merged: vec![0; n],
        }
    }

    fn add(&mut self, [x0, y0, x1, y1]: Range) {
        for y in y0..=y1 {
            let Some(i) = y.checked_sub(self.first).map(|i| i as usize) else {
                continue;
            };
            let Some(row) = self.runs.get_mut(i) else {
                continue;
            };
            row.push((x0, x1));
            // Merged now and then, so a row holds about as many runs as it has.
            if row.len() >= 64 && row.len() > 2 * self.merged[i] {
                merge(row);
                self.merged[i] = row.len();
            }
        }
    }

    fn finish(mut self) -> Zoom {
        for row in &mut self.runs {
            merge(row);
        }
        (self.first, self.runs)
    }
}

/// Sorts runs and joins those that overlap or touch.
fn merge(row: &mut Runs) {
    row.sort_unstable();
    let mut out: Vec<(u32, u32)> = Vec::with_capacity(row.len());
    for &(a, b) in row.iter() {
        match out.last_mut() {
            Some(last) if a <= last.1.saturating_add(1) => last.1 = last.1.max(b),
            _ => out.push((a, b)),
        }
    }
    *row = out;
}

/// The zoom above: a tile is available when one of its children is.
fn coarser(first: u32, finer: &[Runs]) -> Zoom {
    let top = first / 2;
    let n = finer.len().div_ceil(2) + 1;
    let mut rows = vec![Vec::new(); n];
    for (i, row) in finer.iter().enumerate() {
        let y = (first + i as u32) >> 1;
        rows[(y - top) as usize].extend(row.iter().map(|&(a, b)| (a / 2, b / 2)));
    }
    for row in &mut rows {
        merge(row);
    }
    while rows.last().is_some_and(Vec::is_empty) {
        rows.pop();
    }
    (top, rows)
}

impl Availability {
    /// No data anywhere: the two roots only.
    fn roots_only(max_zoom: u8) -> Self {
        let mut zooms = vec![(0, Vec::new()); usize::from(max_zoom) + 1];
        zooms[0] = (0, vec![vec![(0, 1)]]);
        Self { zooms }
    }

    /// The deepest zoom with tiles.
    pub fn max_zoom(&self) -> u8 {
        (self.zooms.len() - 1) as u8
    }

    /// Whether `tile` is available.
    pub fn contains(&self, tile: CesiumTile) -> bool {
        let Some((first, rows)) = self.zooms.get(usize::from(tile.z)) else {
            return false;
        };
        let Some(row) = tile
            .y
            .checked_sub(*first)
            .and_then(|i| rows.get(i as usize))
        else {
            return false;
        };
        let k = row.partition_point(|&(_, b)| b < tile.x);
        row.get(k).is_some_and(|&(a, _)| a <= tile.x)
    }

    /// The available tiles of zoom `z` within `[x0, y0, x1, y1]`, as few rectangles
    /// (rows with the same runs joined), south row first.
    pub fn ranges_within(&self, z: u8, [x0, y0, x1, y1]: Range) -> Vec<Range> {
        let Some((first, rows)) = self.zooms.get(usize::from(z)) else {
            return Vec::new();
        };
        let mut done: Vec<Range> = Vec::new();
        // Rectangles still growing, by their runs.
        let mut open: Vec<Range> = Vec::new();
        for y in y0.max(*first)..=y1 {
            let Some(row) = rows.get((y - first) as usize) else {
                break;
            };
            let runs: Vec<(u32, u32)> = row
                .iter()
                .filter(|&&(a, b)| b >= x0 && a <= x1)
                .map(|&(a, b)| (a.max(x0), b.min(x1)))
                .collect();
            let mut next = Vec::with_capacity(runs.len());
            for (a, b) in runs {
                match open.iter().position(|r| r[0] == a && r[2] == b) {
                    Some(k) => {
                        let mut r = open.swap_remove(k);
                        r[3] = y;
                        next.push(r);
                    }
                    None => next.push([a, y, b, y]),
                }
            }
            done.append(&mut open);
            open = next;
        }
        done.append(&mut open);
        done.sort_unstable_by_key(|r| (r[1], r[0]));
        done
    }

    /// Every available tile of zoom `z`, as rectangles.
    pub fn ranges(&self, z: u8) -> Vec<Range> {
        self.ranges_within(z, [0, 0, u32::MAX - 1, u32::MAX - 1])
    }

    /// The ranges `tile` carries in its metadata (`available`: entry `k` for zoom
    /// `z + 1 + k`, the tiles under it), for a tile whose zoom is a multiple of
    /// [`AVAILABILITY_LEVELS`] and has zooms below; `None` for any other.
    pub fn carried(&self, tile: CesiumTile) -> Option<Vec<Vec<Range>>> {
        if !tile.z.is_multiple_of(AVAILABILITY_LEVELS) || tile.z >= self.max_zoom() {
            return None;
        }
        let last = (tile.z + AVAILABILITY_LEVELS).min(self.max_zoom());
        Some(
            (tile.z + 1..=last)
                .map(|z| {
                    let k = z - tile.z;
                    let box_ = [
                        tile.x << k,
                        tile.y << k,
                        ((tile.x + 1) << k) - 1,
                        ((tile.y + 1) << k) - 1,
                    ];
                    self.ranges_within(z, box_)
                })
                .collect(),
        )
    }
}

/// Ranges as `layer.json` and the metadata extension write them.
pub fn ranges_json(ranges: &[Range]) -> serde_json::Value {
    ranges
        .iter()
        .map(|&[x0, y0, x1, y1]| serde_json::json!({"startX": x0, "startY": y0, "endX": x1, "endY": y1}))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn availability(zooms: Vec<Zoom>) -> Availability {
        Availability { zooms }
    }

    #[test]
    fn runs_merge_and_coarsen() {
        let mut row = vec![(5, 6), (0, 1), (2, 3), (9, 9), (8, 8)];
        merge(&mut row);
        assert_eq!(row, [(0, 3), (5, 6), (8, 9)]);
        // Rows 3..=5 at the finer zoom: rows 1..=2 above.
        let (first, rows) = coarser(3, &[vec![(0, 0)], vec![(4, 5)], vec![(9, 9)]]);
        assert_eq!(first, 1);
        assert_eq!(rows, [vec![(0, 0)], vec![(2, 2), (4, 4)]]);
    }

    #[test]
    fn a_hole_is_a_hole_in_the_ranges() {
        // Zoom 2: rows 1..=3, columns 2..=6, with a hole at (4, 2).
        let a = availability(vec![
            (0, vec![vec![(0, 1)]]),
            (0, vec![]),
            (1, vec![vec![(2, 6)], vec![(2, 3), (5, 6)], vec![(2, 6)]]),
        ]);
        assert!(a.contains(CesiumTile::new(2, 3, 2).unwrap()));
        assert!(!a.contains(CesiumTile::new(2, 4, 2).unwrap()));
        assert!(a.contains(CesiumTile::new(2, 4, 1).unwrap()));
        assert!(!a.contains(CesiumTile::new(2, 7, 1).unwrap()));
        assert!(!a.contains(CesiumTile::new(2, 2, 0).unwrap()));
        assert!(!a.contains(CesiumTile::new(3, 2, 2).unwrap()));
        assert_eq!(
            a.ranges(2),
            [[2, 1, 6, 1], [2, 2, 3, 2], [5, 2, 6, 2], [2, 3, 6, 3]]
        );
        assert_eq!(a.ranges_within(2, [0, 2, 3, 3]), [[2, 2, 3, 3]]);
        let json = ranges_json(&a.ranges_within(2, [0, 2, 3, 3]));
        assert_eq!(
            json,
            serde_json::json!([{"startX": 2, "startY": 2, "endX": 3, "endY": 3}])
        );
        // Zoom 0 carries zooms 1 and 2; zoom 1 carries nothing.
        let west = a.carried(CesiumTile::new(0, 0, 0).unwrap()).unwrap();
        assert_eq!(west, [vec![], vec![[2, 1, 3, 3]]]);
        let east = a.carried(CesiumTile::new(0, 1, 0).unwrap()).unwrap();
        assert_eq!(
            east,
            [vec![], vec![[4, 1, 6, 1], [5, 2, 6, 2], [4, 3, 6, 3]]]
        );
        assert!(a.carried(CesiumTile::new(1, 2, 0).unwrap()).is_none());
    }
}
