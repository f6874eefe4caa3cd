//! A contour tile as a Mapbox Vector Tile (specification 2.1): one layer,
//! [`LAYER`], with one LineString feature per line, carrying its elevation (`ele`, in
//! the levels' [`Unit`]) and whether it is an index contour (`index`). Encoded with the `mvt`
//! crate.
//!
//! Lines are traced on the tile's grid and its border (the tile's buffer: the
//! border's samples are the neighbours' own, so lines continue across tile edges
//! without a seam), simplified by [`TOLERANCE`] and rounded to the tile's integer
//! coordinates.

use super::march::Line;
use super::simplify::douglas_peucker;
use mvt::{GeomEncoder, GeomType, Tile};

/// Tile coordinates across a tile.
pub const EXTENT: u32 = 4096;

/// The layer's name.
pub const LAYER: &str = "contours";

/// Douglas–Peucker tolerance in tile coordinates: half a screen pixel where the tile
/// is drawn 512 pixels wide (as MapLibre draws vector tiles), so at every zoom the
/// same on screen and a ground distance halving per zoom.
pub const TOLERANCE: f64 = 4.0;

/// Which lines a tile holds: every `interval` units of `unit`, and every `index`-th
/// of them (counted from 0; 0 for none) an index contour.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Levels {
    pub interval: f64,
    pub index: u32,
    pub unit: Unit,
}

/// The unit of the levels and of `ele`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Unit {
    Metres,
    /// International feet (0.3048 m), as US topographic maps are drawn.
    Feet,
}

impl Unit {
    /// How the query names it.
    pub const ALLOWED: &str = "m, ft";

    pub fn parse(raw: &str) -> Option<Self> {
        match raw {
            "m" => Some(Self::Metres),
            "ft" => Some(Self::Feet),
            _ => None,
        }
    }

    pub const fn name(self) -> &'static str {
        match self {
            Self::Metres => "m",
            Self::Feet => "ft",
        }
    }

    pub const fn word(self) -> &'static str {
        match self {
            Self::Metres => "metres",
            Self::Feet => "feet",
        }
    }

    /// This unit's measure of one metre.
    pub const fn per_metre(self) -> f64 {
        match self {
            Self::Metres => 1.0,
            Self::Feet => 1.0 / 0.3048,
        }
    }
}

impl Levels {
    /// Level `k`'s elevation in the unit, free of the product's binary noise (3 ×
    /// 0.1 m is 0.3 m).
    pub fn elevation(self, k: i64) -> f64 {
        let e = k as f64 * self.interval;
        (e * 1e6).round() / 1e6
    }

    /// Whether level `k` is an index contour.
    pub fn is_index(self, k: i64) -> bool {
        self.index > 0 && k % i64::from(self.index) == 0
    }
}

/// The tile of `lines`, traced on a grid of `px` samples across the tile (sample
/// centres, as pixel centres) and `border` more on each side.
pub fn encode(lines: &[Line], levels: Levels, px: u32, border: u32) -> Result<Vec<u8>, mvt::Error> {
    let scale = f64::from(EXTENT) / f64::from(px);
    let offset = 0.5 - f64::from(border);
    let mut tile = Tile::new(EXTENT);
    let mut layer = tile.create_layer(LAYER);
    for line in lines {
        let at: Vec<[f64; 2]> = line
            .points
            .iter()
            .map(|p| [(p[0] + offset) * scale, (p[1] + offset) * scale])
            .collect();
        let mut kept: Vec<[i32; 2]> = Vec::with_capacity(at.len());
        for p in douglas_peucker(&at, TOLERANCE) {
            let q = [p[0].round() as i32, p[1].round() as i32];
            if kept.last() != Some(&q) {
                kept.push(q);
            }
        }
        // A line shorter than a tile unit draws nothing.
        if kept.len() < 2 {
            continue;
        }
        let mut geom = GeomEncoder::<i32>::new(GeomType::Linestring);
        for [x, y] in kept {
            geom.add_point(x, y)?;
        }
        let mut feature = layer.into_feature(geom.encode()?);
        let ele = levels.elevation(line.level);
        if ele.fract() == 0.0 && ele.abs() < 1e15 {
            feature.add_tag_sint("ele", ele as i64);
        } else {
            feature.add_tag_double("ele", ele);
        }
        feature.add_tag_bool("index", levels.is_index(line.level));
        layer = feature.into_layer();
    }
    // An empty layer still names the layer: a tile without lines is a valid tile.
    tile.add_layer(layer)?;
    tile.to_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_name_their_elevations_and_index_lines() {
        let l = Levels {
            interval: 0.1,
            index: 5,
            unit: Unit::Metres,
        };
        assert_eq!(l.elevation(3), 0.3);
        assert_eq!(l.elevation(-12), -1.2);
        assert!(l.is_index(10) && l.is_index(-5) && l.is_index(0) && !l.is_index(7));
        let none = Levels {
            interval: 10.0,
            index: 0,
            unit: Unit::Feet,
        };
        assert!(!none.is_index(0));
    }

    #[test]
    fn lines_land_on_tile_coordinates_and_specks_are_dropped() {
        let levels = Levels {
            interval: 10.0,
            index: 5,
            unit: Unit::Metres,
        };
        // A 512-sample tile with a 2-sample border: sample 2 is the tile's first
        // pixel centre (4 units in), 8 units per sample.
        let lines = [
            Line {
                level: 5,
                points: vec![[2.0, 2.0], [10.0, 2.0], [10.0, 514.0]],
            },
            Line {
                level: 7,
                points: vec![[100.0, 100.0], [100.01, 100.0]],
            },
        ];
        let bytes = encode(&lines, levels, 512, 2).unwrap();
        let reader = mvt_reader::Reader::new(bytes).unwrap();
        assert_eq!(reader.get_layer_names().unwrap(), vec![LAYER.to_string()]);
        let features = reader.get_features(0).unwrap();
        // The speck (0.08 units long) is dropped.
        assert_eq!(features.len(), 1);
        let geo_types::Geometry::LineString(l) = &features[0].geometry else {
            panic!("a line string: {:?}", features[0].geometry)
        };
        let xy: Vec<[f32; 2]> = l.coords().map(|c| [c.x, c.y]).collect();
        assert_eq!(xy, vec![[4.0, 4.0], [68.0, 4.0], [68.0, 4100.0]]);
        let p = features[0].properties.as_ref().unwrap();
        assert_eq!(p["ele"], mvt_reader::feature::Value::SInt(50));
        assert_eq!(p["index"], mvt_reader::feature::Value::Bool(true));

        let empty = mvt_reader::Reader::new(encode(&[], levels, 512, 2).unwrap()).unwrap();
        assert_eq!(empty.get_layer_names().unwrap(), vec![LAYER.to_string()]);
        assert!(empty.get_features(0).unwrap().is_empty());
    }
}
