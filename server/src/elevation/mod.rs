//! Heights on demand: the elevation of points and profiles, each with the error
//! bound of the level that answers it (API.md "Elevation queries", DECISIONS.md
//! "Elevation queries"). One engine serves `GET`/`POST /v1/datasets/{name}/elevation`
//! (serve/routes/elevation.rs) and `tessera-server query` (query.rs).
//!
//! 1. **Where.** Each WGS 84 point goes to the dataset's finest sample coordinates
//!    through the projection library (one PROJ call for the batch), as the
//!    standard-grid tiles do (web/footprint.rs). A point more than half a sample
//!    beyond the DEM is outside.
//! 2. **Which level.** By default the deepest level stored at the point (the finest
//!    data there; in a multi-resolution pyramid, the finest that exists there). With
//!    `accuracy=`, the coarsest level whose bound at the point is within it, trying
//!    levels from the root down; the finest data answers when none is.
//! 3. **The height** is the level's samples interpolated ([`kernel`]), and its bound
//!    is computed from the level's own samples and error table ([`bound`]).
//! 4. **No data.** A point is terrain when its nearest sample at the answering level
//!    is a corner of a valid cell, as the tiles decide it; a void there is tried at
//!    finer levels, then answered `null` with the reason.
//! 5. **Each tile once.** Points are grouped level by level and, within a level, by
//!    tile in row-major order, and the tiles they read are held while later points
//!    may need them (within a memory bound: [`answer`]'s `hold`), so a batch of
//!    100 000 points decodes each tile it needs once, whatever the server's cache of
//!    decoded tiles holds.

pub mod bound;
pub mod kernel;
pub mod locations;
pub mod output;
pub mod profile;
pub mod request;

use crate::geoid::Geoid;
use crate::web::footprint::Footprint;
use crate::web::resample::SourceTile;
use bound::{LevelGrid, LevelView};
use kernel::Interpolation;
use locations::LatLon;
use request::{Datum, Options};
use std::sync::Arc;
use tessera_shared::{Level, Quantization, TileGeometry, TileId, VerticalDatum};

/// What the engine needs to know about a dataset.
#[derive(Debug)]
pub struct Dem<'a> {
    pub footprint: &'a Footprint,
    pub geometry: &'a TileGeometry,
    pub quantization: Quantization,
}

/// Where the engine reads tiles: the server's cache, or the command's.
pub trait Tiles {
    type Error;
    /// Whether the pyramid stores `tile` (from its index: nothing is read).
    fn stored(&self, tile: TileId) -> bool;
    /// The decoded tile, `None` when the pyramid has none.
    fn load(&self, tile: TileId) -> Result<Option<Arc<SourceTile>>, Self::Error>;
    /// An error when the work should stop (its requester is gone).
    fn check(&self) -> Result<(), Self::Error>;
}

/// Why a point has no height.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Missing {
    /// More than half a sample beyond the DEM (or not carried to its CRS).
    Outside,
    /// Over a void of the DEM, or a tile the pyramid does not store.
    NoData,
}

impl Missing {
    pub const fn reason(self) -> &'static str {
        match self {
            Self::Outside => "outside the dataset",
            Self::NoData => "no data: a void in the dataset",
        }
    }
}

/// A point's height and where it comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Height {
    /// Metres, in the answer's datum.
    pub elevation: f64,
    pub level: Level,
    /// Metres: the most `elevation` can differ from the source DEM interpolated the
    /// same way at the point (elevation/bound.rs).
    pub error_bound: f64,
    /// Metres between the level's samples at the dataset's centre.
    pub resolution: f64,
}

/// One point's answer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Answer {
    pub point: LatLon,
    pub height: Result<Height, Missing>,
}

/// How answers are carried to the requested datum.
#[derive(Clone, Debug)]
pub enum Shift {
    None,
    /// Add the geoid's undulation (geoid heights to ellipsoidal).
    AddGeoid(Arc<Geoid>),
    /// Subtract it (ellipsoidal heights to geoid).
    SubtractGeoid(Arc<Geoid>),
}

/// The shift from the dataset's datum to `want`, and the name of the datum answers
/// are in; an error (for `datum=`) where it cannot be done.
pub fn shift(
    have: VerticalDatum,
    want: Datum,
    geoid: Option<&Arc<Geoid>>,
    earth: bool,
) -> Result<(Shift, &'static str), String> {
    let target = match want {
        Datum::Native => return Ok((Shift::None, have.name())),
        Datum::Egm96 => VerticalDatum::Egm96,
        Datum::Ellipsoid => VerticalDatum::Ellipsoid,
    };
    let name = want.name();
    if have == target {
        return Ok((Shift::None, target.name()));
    }
    match have {
        VerticalDatum::Unknown => {
            return Err(format!(
                "datum={name}: the dataset's vertical datum is unknown, so its heights cannot be converted (ask for datum=native)"
            ));
        }
        VerticalDatum::Egm2008 => {
            return Err(format!(
                "datum={name}: the dataset's heights are above the EGM2008 geoid, which this server cannot convert"
            ));
        }
        _ => {}
    }
    if !earth {
        return Err(format!(
            "datum={name}: the dataset is not on the Earth, which the EGM96 geoid is of"
        ));
    }
    let geoid = geoid.cloned().ok_or_else(|| {
        format!("datum={name}: this server has no EGM96 geoid grid (tessera-server serve --geoid)")
    })?;
    Ok((
        if target == VerticalDatum::Ellipsoid {
            Shift::AddGeoid(geoid)
        } else {
            Shift::SubtractGeoid(geoid)
        },
        target.name(),
    ))
}

/// The decoded tiles of one level that points read, by `(row, column)`, at most
/// `cap` of them. Points come in row-major order of their tiles, and a point reads
/// at most its tile's neighbours (every kernel reaches less than a tile), so
/// dropping the tiles of the earliest rows first keeps every tile until no point
/// needs it: while the tiles of three consecutive rows fit in `cap`, each is
/// decoded once.
struct Window {
    tiles: std::collections::BTreeMap<(u32, u32), Option<Arc<SourceTile>>>,
    cap: usize,
}

impl Window {
    fn ensure<T: Tiles>(&mut self, tiles: &T, id: TileId) -> Result<(), T::Error> {
        let key = (id.y(), id.x());
        if self.tiles.contains_key(&key) {
            return Ok(());
        }
        let tile = if tiles.stored(id) {
            tiles.load(id)?
        } else {
            None
        };
        if self.tiles.len() >= self.cap {
            self.tiles.pop_first();
        }
        self.tiles.insert(key, tile);
        Ok(())
    }

    fn get(&self, x: u32, y: u32) -> Option<&SourceTile> {
        self.tiles.get(&(y, x)).and_then(|s| s.as_deref())
    }
}

/// A point still looking for its level.
#[derive(Clone, Copy)]
struct Pending {
    index: usize,
    /// Finest sample coordinates, clamped to the DEM.
    at: [f64; 2],
    /// The level to try next, and the deepest stored at the point.
    next: u8,
    deepest: u8,
    /// Sort key within a level: its tile's row, then column.
    key: u64,
}

/// The tile of `level` holding finest position `at` (its cell's tile).
fn tile_at(geometry: &TileGeometry, level: Level, at: [f64; 2]) -> TileId {
    let k = geometry.finest().get() - level.get();
    let span = f64::from(geometry.tile_size()) * f64::from(1u32 << k);
    let n = level.tiles_per_side();
    let of = |v: f64| ((v / span) as u32).min(n - 1);
    TileId::new(level, of(at[0]), of(at[1])).expect("clamped to the level")
}

/// Every point's answer, in order, holding at most `hold` decoded tiles at once
/// (at least 9: a point's tile and its neighbours).
pub fn answer<T: Tiles>(
    dem: &Dem,
    tiles: &T,
    points: &[LatLon],
    options: &Options,
    shift: &Shift,
    hold: usize,
) -> Result<Vec<Answer>, T::Error> {
    let geometry = dem.geometry;
    let finest = geometry.finest();
    let (w, h) = (f64::from(geometry.width()), f64::from(geometry.height()));
    let positions = {
        let lon_lat: Vec<[f64; 2]> = points.iter().map(|p| [p.lon(), p.lat()]).collect();
        dem.footprint.lon_lat_to_samples(&lon_lat)
    };
    let mut out: Vec<Answer> = points
        .iter()
        .map(|&point| Answer {
            point,
            height: Err(Missing::Outside),
        })
        .collect();
    let mut pending = Vec::with_capacity(points.len());
    for (index, p) in positions.into_iter().enumerate() {
        let Some([c, r]) = p else { continue };
        if !((-0.5..=w - 0.5).contains(&c) && (-0.5..=h - 0.5).contains(&r)) {
            continue;
        }
        let at = [c.clamp(0.0, w - 1.0), r.clamp(0.0, h - 1.0)];
        let deepest = (0..=finest.get())
            .rev()
            .find(|&l| tiles.stored(tile_at(geometry, Level::new(l).expect("a level"), at)));
        let Some(deepest) = deepest else {
            out[index].height = Err(Missing::NoData);
            continue;
        };
        let next = if options.accuracy.is_some() {
            0
        } else {
            deepest
        };
        pending.push(Pending {
            index,
            at,
            next,
            deepest,
            key: 0,
        });
    }
    for l in 0..=finest.get() {
        let level = Level::new(l).expect("a level");
        // Moved out, not copied: the batch's points are in one of the two vectors.
        let mut here: Vec<Pending> = pending.extract_if(.., |p| p.next == l).collect();
        for p in &mut here {
            let tile = tile_at(geometry, level, p.at);
            p.key = (u64::from(tile.y()) << 32) | u64::from(tile.x());
        }
        here.sort_unstable_by_key(|p| p.key);
        let k = finest.get() - l;
        let grid = LevelGrid {
            k: u32::from(k),
            t: geometry.tile_size(),
            n: level.tiles_per_side(),
        };
        let resolution = dem.footprint.spacing_m() * f64::from(1u32 << k);
        let mut window = Window {
            tiles: std::collections::BTreeMap::new(),
            cap: hold.max(9),
        };
        let mut last_key = None;
        for mut p in here {
            if last_key != Some(p.key) {
                tiles.check()?;
                last_key = Some(p.key);
            }
            // Load what the point reads, then read it.
            let [x0, y0, x1, y1] = grid.tiles_reached(options.interpolation, p.at);
            for ty in y0..=y1 {
                for tx in x0..=x1 {
                    let id = TileId::new(level, tx, ty).expect("within the level");
                    window.ensure(tiles, id)?;
                }
            }
            let get = |x: u32, y: u32| window.get(x, y);
            let view = LevelView::new(grid, &get);
            let [nc, nr] = grid.nearest(p.at);
            let evaluated = view
                .is_terrain(nc, nr)
                .then(|| view.evaluate(options.interpolation, p.at, &dem.quantization))
                .flatten();
            let finer = l < p.deepest;
            match evaluated {
                Some(e) if !finer || options.accuracy.is_none_or(|a| e.bound <= a) => {
                    out[p.index].height = Ok(Height {
                        elevation: e.value,
                        level,
                        error_bound: e.bound,
                        resolution,
                    });
                }
                None if !finer => out[p.index].height = Err(Missing::NoData),
                _ => {
                    p.next = l + 1;
                    pending.push(p);
                }
            }
        }
    }
    let (geoid, sign) = match shift {
        Shift::None => return Ok(out),
        Shift::AddGeoid(g) => (g, 1.0),
        Shift::SubtractGeoid(g) => (g, -1.0),
    };
    for a in &mut out {
        if let Ok(h) = &mut a.height {
            h.elevation += sign * geoid.undulation(a.point.lon(), a.point.lat());
        }
    }
    Ok(out)
}

/// The interpolation methods' names, for messages and help.
pub fn methods() -> String {
    Interpolation::ALL.map(Interpolation::name).join(", ")
}
