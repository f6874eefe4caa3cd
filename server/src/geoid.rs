//! Geoid undulations for Cesium terrain (DECISIONS.md "Heights for Cesium"): Cesium wants
//! heights above the WGS84 ellipsoid, SRTM gives them above the EGM96 geoid, so each
//! vertex gets the undulation N added (h = H + N, the convention PROJ's `vgridshift`
//! applies from orthometric to ellipsoidal heights).
//!
//! N comes from a grid in NOAA VDatum's GTX format, as PROJ reads it: Debian's
//! `proj-data` ships EGM96 at 15′ as `/usr/share/proj/egm96_15.gtx` (721 × 1440 nodes,
//! 4 MB). The format: a 40-byte big-endian header (south latitude, west longitude,
//! latitude step, longitude step, all f64 degrees; rows, columns, both i32), then
//! rows × columns big-endian f32 metres, row 0 at the south, each row west to east;
//! −88.8888 marks a node without data. [`Geoid::undulation`] interpolates bilinearly as
//! PROJ does for GTX grids (DECISIONS.md "Heights for Cesium: the EGM96 geoid").

use std::ffi::OsString;
use std::fmt;
use std::io::Read;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail, ensure};

/// Where [`find`] looks when no path is given: Debian's `proj-data`, then a PROJ
/// installed from source under /usr/local.
pub const DEFAULT_PATHS: &[&str] = &[
    "/usr/share/proj/egm96_15.gtx",
    "/usr/local/share/proj/egm96_15.gtx",
];

/// The environment variable [`find`] reads when no explicit path is given.
pub const ENV_VAR: &str = "TESSERA_GEOID";

/// The GTX header: four f64 and two i32.
const HEADER_LEN: usize = 40;

/// GTX's official no-data value.
const NODATA: f32 = -88.8888;

/// Tolerance for "the grid reaches the pole" and "the grid goes all the way round":
/// header steps are decimal fractions of a degree, so products of them are inexact.
const EDGE_EPS_DEG: f64 = 1e-9;

/// A geoid model on a regular latitude–longitude grid, read from a GTX file.
#[derive(Clone)]
pub struct Geoid {
    name: String,
    /// Latitude of row 0 (the southernmost), degrees.
    lat0: f64,
    /// Longitude of column 0 (the westernmost), degrees.
    lon0: f64,
    dlat: f64,
    dlon: f64,
    /// 1/dlat and 1/dlon: PROJ scales by the inverse steps, and so do we.
    inv_dlat: f64,
    inv_dlon: f64,
    rows: usize,
    cols: usize,
    /// Row-major from the south, west to east: `values[row * cols + col]`, metres.
    values: Vec<f32>,
    /// The columns cover all 360° (as PROJ decides it: `cols · dlon ≥ 360°`), so the
    /// last column interpolates with the first across the antimeridian.
    global: bool,
    /// Any node is no data: only then does interpolation pay for the checks.
    has_nodata: bool,
}

impl fmt::Debug for Geoid {
    // By hand: the derived one would print a million values.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Geoid")
            .field("name", &self.name)
            .field("lat0", &self.lat0)
            .field("lon0", &self.lon0)
            .field("dlat", &self.dlat)
            .field("dlon", &self.dlon)
            .field("rows", &self.rows)
            .field("cols", &self.cols)
            .field("global", &self.global)
            .field("has_nodata", &self.has_nodata)
            .finish_non_exhaustive()
    }
}

/// The header's facts, checked against each other and the file's length.
#[derive(Clone, Copy, Debug)]
struct Header {
    lat0: f64,
    lon0: f64,
    dlat: f64,
    dlon: f64,
    rows: usize,
    cols: usize,
}

impl Header {
    /// Checks the header (`bytes`, at least its first 40 bytes) of a GTX file that is
    /// `file_len` bytes long, so that no later index can fall outside the data.
    fn parse(name: &str, bytes: &[u8], file_len: u64) -> Result<Self> {
        let Some(h) = bytes.get(..HEADER_LEN) else {
            bail!(
                "{name}: {file_len} bytes is too short for a GTX geoid grid \
                 (its header alone is {HEADER_LEN} bytes)"
            );
        };
        let f64_at = |i: usize| {
            let mut b = [0u8; 8];
            b.copy_from_slice(&h[i..i + 8]);
            f64::from_be_bytes(b)
        };
        let i32_at = |i: usize| {
            let mut b = [0u8; 4];
            b.copy_from_slice(&h[i..i + 4]);
            i32::from_be_bytes(b)
        };
        let (lat0, lon0, dlat, dlon) = (f64_at(0), f64_at(8), f64_at(16), f64_at(24));
        let (rows, cols) = (i32_at(32), i32_at(36));
        for (what, v) in [
            ("south latitude", lat0),
            ("west longitude", lon0),
            ("latitude spacing", dlat),
            ("longitude spacing", dlon),
        ] {
            ensure!(
                v.is_finite(),
                "{name}: the GTX header's {what} is not a finite number ({v}); \
                 not a GTX grid, or a damaged one"
            );
        }
        ensure!(
            dlat > 0.0 && dlon > 0.0,
            "{name}: the GTX header's spacing must be positive, but it is \
             {dlat}° in latitude and {dlon}° in longitude"
        );
        ensure!(
            rows > 0 && cols > 0,
            "{name}: the GTX header gives {rows} rows × {cols} columns; both must be positive"
        );
        let (rows, cols) = (rows as usize, cols as usize);
        let expected = (rows as u64)
            .checked_mul(cols as u64)
            .and_then(|n| n.checked_mul(4))
            .and_then(|n| n.checked_add(HEADER_LEN as u64));
        ensure!(
            expected == Some(file_len),
            "{name}: the GTX header gives {rows} rows × {cols} columns, which is {} bytes \
             with the header, but the file is {file_len} bytes (truncated, or not a GTX grid)",
            expected.map_or_else(|| "more than 2^64".to_owned(), |n| n.to_string())
        );
        let north = lat0 + (rows - 1) as f64 * dlat;
        ensure!(
            lat0 >= -90.0 && north <= 90.0 + EDGE_EPS_DEG,
            "{name}: the GTX header's rows run from {lat0}° to {north}° latitude, \
             outside −90°…90°"
        );
        // PROJ accepts origins in −360°…360° (some grids count longitude 0…360°).
        ensure!(
            (-360.0..=360.0).contains(&lon0),
            "{name}: the GTX header's west longitude {lon0}° is outside −360°…360°"
        );
        // One duplicated column (first repeated at +360°) is the most a world grid has.
        let span = cols as f64 * dlon;
        ensure!(
            span <= 360.0 + dlon + EDGE_EPS_DEG,
            "{name}: the GTX header's {cols} columns of {dlon}° span {span}°, more than 360°"
        );
        Ok(Self {
            lat0,
            lon0,
            dlat,
            dlon,
            rows,
            cols,
        })
    }
}

/// Whether a node's value is no data. PROJ's test: besides the official value, some
/// grids mark voids with huge numbers; non-finite values are ours, so that a damaged
/// value cannot reach a vertex.
fn is_nodata(v: f32) -> bool {
    v == NODATA || !v.is_finite() || v.abs() > 1000.0
}

impl Geoid {
    /// Reads a GTX grid. Errors name the file and say what is wrong with it.
    pub fn open(path: &Path) -> Result<Self> {
        let name = path.display().to_string();
        let mut file = std::fs::File::open(path)
            .with_context(|| format!("cannot open the geoid grid {name}"))?;
        let file_len = file
            .metadata()
            .with_context(|| format!("cannot read the size of the geoid grid {name}"))?
            .len();
        // The header first, so that a wrong file is refused before it is read whole.
        let mut header = [0u8; HEADER_LEN];
        let got = if file_len >= HEADER_LEN as u64 {
            file.read_exact(&mut header)
                .with_context(|| format!("cannot read the geoid grid {name}"))?;
            &header[..]
        } else {
            &[]
        };
        let h = Header::parse(&name, got, file_len)?;
        let mut data = vec![0u8; h.rows * h.cols * 4];
        file.read_exact(&mut data)
            .with_context(|| format!("cannot read the geoid grid {name}"))?;
        Ok(Self::from_parts(name, h, &data))
    }

    /// Reads a GTX grid from memory; `name` is what errors call it.
    pub fn from_bytes(name: &str, bytes: &[u8]) -> Result<Self> {
        let h = Header::parse(name, bytes, bytes.len() as u64)?;
        Ok(Self::from_parts(name.to_owned(), h, &bytes[HEADER_LEN..]))
    }

    /// `data` is exactly `rows · cols` big-endian f32 (the header's check).
    fn from_parts(name: String, h: Header, data: &[u8]) -> Self {
        let values: Vec<f32> = data
            .chunks_exact(4)
            .map(|c| f32::from_be_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        debug_assert_eq!(values.len(), h.rows * h.cols);
        let has_nodata = values.iter().any(|&v| is_nodata(v));
        Self {
            name,
            lat0: h.lat0,
            lon0: h.lon0,
            dlat: h.dlat,
            dlon: h.dlon,
            inv_dlat: 1.0 / h.dlat,
            inv_dlon: 1.0 / h.dlon,
            rows: h.rows,
            cols: h.cols,
            values,
            global: h.cols as f64 * h.dlon >= 360.0 - EDGE_EPS_DEG,
            has_nodata,
        }
    }

    /// The file (or name) the grid was read from.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The geoid's height above the ellipsoid at a point, metres (h = H + N). Bilinear
    /// between the four surrounding nodes, as PROJ does: a world grid wraps in longitude
    /// (any longitude is accepted); latitude is clamped to the grid, as is longitude on
    /// a regional grid (where PROJ refuses the point). No-data nodes drop out and the others' weights are renormalised
    /// (PROJ's rule); NaN where all four are no data, or for a NaN coordinate.
    /// Deterministic, and bit-identical to [`Geoid::row`] and [`Geoid::undulation_row`].
    pub fn undulation(&self, lon_deg: f64, lat_deg: f64) -> f64 {
        self.row(lat_deg).undulation(lon_deg)
    }

    /// [`Geoid::undulation`] at each of `lons` on the parallel `lat_deg`, into `out`.
    /// Panics if the two slices' lengths differ.
    pub fn undulation_row(&self, lons: &[f64], lat_deg: f64, out: &mut [f64]) {
        assert_eq!(
            lons.len(),
            out.len(),
            "undulation_row: {} longitudes but {} outputs",
            lons.len(),
            out.len()
        );
        self.row(lat_deg).fill(lons, out);
    }

    /// The pair of grid rows around a parallel, found once, for many longitudes on it
    /// (the mesher's vertices come in rows).
    pub fn row(&self, lat_deg: f64) -> GeoidRow<'_> {
        let last = (self.rows - 1) as f64;
        // NaN stays NaN through clamp (no panic), becomes row 0 and a NaN weight.
        let y = ((lat_deg - self.lat0) * self.inv_dlat).clamp(0.0, last);
        let iy = (y as usize).min(self.rows - 1);
        let iy2 = (iy + 1).min(self.rows - 1);
        let cols = self.cols;
        GeoidRow {
            south: &self.values[iy * cols..(iy + 1) * cols],
            north: &self.values[iy2 * cols..(iy2 + 1) * cols],
            fy: y - iy as f64,
            lon0: self.lon0,
            inv_dlon: self.inv_dlon,
            period: 360.0 * self.inv_dlon,
            global: self.global,
            has_nodata: self.has_nodata,
        }
    }
}

/// Two grid rows and the weight between them: [`Geoid::row`]. It carries copies of
/// the grid's few scalars so that the per-point loop reads nothing else.
#[derive(Clone, Copy)]
pub struct GeoidRow<'a> {
    /// The rows south and north of the parallel (the same row at the grid's edges).
    south: &'a [f32],
    north: &'a [f32],
    /// The parallel's fraction of the way from the south row to the north one.
    fy: f64,
    lon0: f64,
    inv_dlon: f64,
    /// 360° in columns.
    period: f64,
    global: bool,
    has_nodata: bool,
}

impl fmt::Debug for GeoidRow<'_> {
    // By hand: the derived one would print both rows.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("GeoidRow")
            .field("fy", &self.fy)
            .field("cols", &self.south.len())
            .finish_non_exhaustive()
    }
}

impl GeoidRow<'_> {
    /// [`Geoid::undulation`] at `lon_deg` on this row's parallel.
    #[inline]
    pub fn undulation(&self, lon_deg: f64) -> f64 {
        match (self.global, self.has_nodata) {
            (true, false) => self.at::<true, false>(lon_deg),
            (true, true) => self.at::<true, true>(lon_deg),
            (false, false) => self.at::<false, false>(lon_deg),
            (false, true) => self.at::<false, true>(lon_deg),
        }
    }

    /// [`GeoidRow::undulation`] at each of `lons`, into `out`, deciding the grid's kind
    /// once rather than per point.
    fn fill(&self, lons: &[f64], out: &mut [f64]) {
        fn each(lons: &[f64], out: &mut [f64], f: impl Fn(f64) -> f64) {
            for (o, &lon) in out.iter_mut().zip(lons) {
                *o = f(lon);
            }
        }
        match (self.global, self.has_nodata) {
            (true, false) => each(lons, out, |lon| self.at::<true, false>(lon)),
            (true, true) => each(lons, out, |lon| self.at::<true, true>(lon)),
            (false, false) => each(lons, out, |lon| self.at::<false, false>(lon)),
            (false, true) => each(lons, out, |lon| self.at::<false, true>(lon)),
        }
    }

    /// The interpolation, specialised for a world grid (`GLOBAL`: wrap in longitude)
    /// or a regional one (clamp), and for a grid with no-data nodes (`HOLES`).
    #[inline]
    fn at<const GLOBAL: bool, const HOLES: bool>(&self, lon_deg: f64) -> f64 {
        let cols = self.south.len();
        let mut x = (lon_deg - self.lon0) * self.inv_dlon;
        let (ix, ix2) = if GLOBAL {
            // Most longitudes are already in range and skip the remainder.
            if !(0.0..self.period).contains(&x) {
                x = x.rem_euclid(self.period);
            }
            // x may round up to the period (just west of the origin): the last column
            // at weight 1 towards the wrapped first, i.e. column 0's value, as it should.
            // Through i32, not straight to usize: x is in 0…period ≤ cols ≤ i32::MAX
            // here, and the saturating f64 → u64 conversion cost a quarter of the time per point.
            let ix = (x as i32 as usize).min(cols - 1);
            (ix, if ix + 1 < cols { ix + 1 } else { 0 })
        } else {
            // Wrap into the 360° centred on the grid, so that a point off either side
            // clamps to the nearer edge; NaN survives the clamp as NaN, and row 0.
            let lo = 0.5 * (cols - 1) as f64 - 0.5 * self.period;
            if !(lo..lo + self.period).contains(&x) {
                x = (x - lo).rem_euclid(self.period) + lo;
            }
            x = x.clamp(0.0, (cols - 1) as f64);
            let ix = (x as i32 as usize).min(cols - 1);
            (ix, (ix + 1).min(cols - 1))
        };
        let fx = x - ix as f64;
        let fy = self.fy;
        let (a, b) = (self.south[ix], self.south[ix2]);
        let (c, d) = (self.north[ix], self.north[ix2]);
        // PROJ's weights and order (south-west, south-east, north-west, north-east),
        // expanded as it writes them so that one product serves all four.
        let fxy = fx * fy;
        let w = [1.0 - fx - fy + fxy, fx - fxy, fy - fxy, fxy];
        if !HOLES {
            return f64::from(a) * w[0]
                + f64::from(b) * w[1]
                + f64::from(c) * w[2]
                + f64::from(d) * w[3];
        }
        let (mut sum, mut total, mut n) = (0.0, 0.0, 0);
        for (value, weight) in [a, b, c, d].into_iter().zip(w) {
            if !is_nodata(value) {
                sum += f64::from(value) * weight;
                total += weight;
                n += 1;
            }
        }
        match n {
            0 => f64::NAN,
            4 => sum,
            _ => sum / total,
        }
    }
}

/// The geoid grid to use: `explicit` (a command-line flag), else `$TESSERA_GEOID`,
/// else the first of [`DEFAULT_PATHS`] that is a file. An explicit path or the
/// variable is returned whether or not it exists, so that [`Geoid::open`] reports a
/// mistyped path instead of a default silently standing in for it.
pub fn find(explicit: Option<&Path>) -> Option<PathBuf> {
    find_in(explicit, std::env::var_os(ENV_VAR), DEFAULT_PATHS)
}

/// [`find`] with its environment and defaults passed in (tests cannot set variables:
/// `set_var` is unsafe in edition 2024).
fn find_in(explicit: Option<&Path>, env: Option<OsString>, defaults: &[&str]) -> Option<PathBuf> {
    if let Some(p) = explicit {
        return Some(p.to_path_buf());
    }
    if let Some(p) = env.filter(|p| !p.is_empty()) {
        return Some(PathBuf::from(p));
    }
    defaults.iter().map(PathBuf::from).find(|p| p.is_file())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A GTX file in memory: the header, then `values` row by row from the south.
    fn gtx(
        lat0: f64,
        lon0: f64,
        dlat: f64,
        dlon: f64,
        rows: i32,
        cols: i32,
        values: &[f32],
    ) -> Vec<u8> {
        let mut b = Vec::with_capacity(HEADER_LEN + 4 * values.len());
        for v in [lat0, lon0, dlat, dlon] {
            b.extend_from_slice(&v.to_be_bytes());
        }
        b.extend_from_slice(&rows.to_be_bytes());
        b.extend_from_slice(&cols.to_be_bytes());
        for v in values {
            b.extend_from_slice(&v.to_be_bytes());
        }
        b
    }

    /// 3 rows × 4 columns from 10° N, 20° E, 0.5° by 1°: node (r, c) holds 10r + c,
    /// so every node and every halfway value is exact in binary.
    fn regional() -> Geoid {
        let values: Vec<f32> = (0..3)
            .flat_map(|r| (0..4).map(move |c| (10 * r + c) as f32))
            .collect();
        Geoid::from_bytes("regional.gtx", &gtx(10.0, 20.0, 0.5, 1.0, 3, 4, &values)).unwrap()
    }

    /// 3 rows × 4 columns covering the world: 90° apart from (−90°, −180°).
    fn world() -> Geoid {
        let values: Vec<f32> = (0..3)
            .flat_map(|r| (0..4).map(move |c| (10 * r + c) as f32))
            .collect();
        Geoid::from_bytes("world.gtx", &gtx(-90.0, -180.0, 90.0, 90.0, 3, 4, &values)).unwrap()
    }

    #[test]
    fn geoid_tiny_grid_is_exact_at_nodes_and_halfway() {
        let g = regional();
        assert!(!g.global);
        for r in 0..3 {
            for c in 0..4 {
                let (lon, lat) = (20.0 + c as f64, 10.0 + 0.5 * r as f64);
                assert_eq!(
                    g.undulation(lon, lat),
                    (10 * r + c) as f64,
                    "node ({r}, {c})"
                );
            }
        }
        // Row 0 is the south: the north-west node is 20, the south-east one 3.
        assert_eq!(g.undulation(20.0, 11.0), 20.0);
        assert_eq!(g.undulation(23.0, 10.0), 3.0);
        // Halfway along a row, along a column, and in the middle of a cell.
        assert_eq!(g.undulation(20.5, 10.0), 0.5);
        assert_eq!(g.undulation(22.0, 10.25), 7.0);
        assert_eq!(g.undulation(21.5, 10.75), 16.5);
        assert_eq!(g.undulation(20.25, 10.0), 0.25);
        // Clamped outside: south, north, and each side in longitude to the nearer edge.
        assert_eq!(g.undulation(21.0, -80.0), 1.0);
        assert_eq!(g.undulation(21.0, 89.0), 21.0);
        // 170° W is 190° west of the grid but 167° east of it.
        assert_eq!(g.undulation(-150.0, 10.0), 0.0);
        assert_eq!(g.undulation(-170.0, 10.0), 3.0);
        assert_eq!(g.undulation(19.0, 10.0), 0.0);
        assert_eq!(g.undulation(30.0, 10.0), 3.0);
        assert_eq!(g.undulation(20.0 + 360.0, 10.0), 0.0);
    }

    #[test]
    fn geoid_world_grid_wraps_across_the_antimeridian() {
        let g = world();
        assert!(g.global);
        // Column 3 is 90° E; halfway to column 0 (−180° = 180°) is 135° E.
        assert_eq!(g.undulation(90.0, 0.0), 13.0);
        assert_eq!(g.undulation(180.0, 0.0), 10.0);
        assert_eq!(g.undulation(-180.0, 0.0), 10.0);
        assert_eq!(g.undulation(135.0, 0.0), 11.5);
        for lon in [135.0 - 360.0, 135.0 + 360.0, 135.0 + 720.0, 135.0 - 1080.0] {
            assert_eq!(
                g.undulation(lon, 0.0).to_bits(),
                g.undulation(135.0, 0.0).to_bits()
            );
        }
        // Just west of −180° still interpolates with the last column, and just under
        // the wrap lands on column 0.
        assert_eq!(g.undulation(-180.0 - 1e-300, 0.0), 10.0);
        assert!((g.undulation(180.0 - 1e-13, 0.0) - 10.0).abs() < 1e-12);
        // The poles are the first and last rows.
        assert_eq!(g.undulation(-90.0, -90.0), 1.0);
        assert_eq!(g.undulation(-135.0, -90.0), 0.5);
        assert_eq!(g.undulation(0.0, 90.0), 22.0);
        assert_eq!(g.undulation(0.0, 95.0), 22.0);
    }

    #[test]
    fn geoid_row_is_bit_identical_to_points() {
        let g = world();
        let lons: Vec<f64> = (0..2000).map(|i| -400.0 + 0.4137 * i as f64).collect();
        for lat in [-90.0, -33.3, 0.0, 12.5, 89.999, 90.0] {
            let mut out = vec![0.0; lons.len()];
            g.undulation_row(&lons, lat, &mut out);
            for (&lon, &n) in lons.iter().zip(&out) {
                assert_eq!(n.to_bits(), g.undulation(lon, lat).to_bits(), "{lon} {lat}");
                assert_eq!(n.to_bits(), g.undulation(lon, lat).to_bits(), "repeatable");
            }
        }
    }

    #[test]
    fn geoid_nodata_nodes_drop_out() {
        // 2 × 2, one node no data: the others are renormalised, as PROJ does.
        let bytes = gtx(0.0, 0.0, 1.0, 1.0, 2, 2, &[1.0, NODATA, 3.0, 5.0]);
        let g = Geoid::from_bytes("holes.gtx", &bytes).unwrap();
        assert!(g.has_nodata);
        assert_eq!(g.undulation(0.0, 0.0), 1.0);
        assert_eq!(g.undulation(0.5, 0.0), 1.0);
        assert_eq!(g.undulation(0.5, 0.5), 3.0);
        let empty = gtx(
            0.0,
            0.0,
            1.0,
            1.0,
            2,
            2,
            &[NODATA, 1e9, f32::NAN, f32::INFINITY],
        );
        let g = Geoid::from_bytes("void.gtx", &empty).unwrap();
        assert!(g.undulation(0.5, 0.5).is_nan());
    }

    #[test]
    fn geoid_odd_coordinates_do_not_panic() {
        for g in [regional(), world()] {
            for (lon, lat) in [
                (f64::NAN, 0.0),
                (0.0, f64::NAN),
                (f64::INFINITY, 0.0),
                (f64::NEG_INFINITY, f64::INFINITY),
                (1e300, -1e300),
            ] {
                let _ = g.undulation(lon, lat);
            }
            assert!(g.undulation(f64::NAN, 0.0).is_nan());
            assert!(g.undulation(0.0, f64::NAN).is_nan());
        }
        // One row, one column: a constant.
        let one = Geoid::from_bytes("one.gtx", &gtx(5.0, 5.0, 1.0, 1.0, 1, 1, &[7.0])).unwrap();
        assert_eq!(one.undulation(-100.0, 80.0), 7.0);
    }

    fn error_of(bytes: &[u8]) -> String {
        format!("{:#}", Geoid::from_bytes("bad.gtx", bytes).unwrap_err())
    }

    #[test]
    fn geoid_bad_files_are_errors_naming_the_file_and_the_problem() {
        let good = gtx(10.0, 20.0, 0.5, 1.0, 3, 4, &[0.0; 12]);
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (Vec::new(), "too short"),
            (good[..39].to_vec(), "too short"),
            (good[..good.len() - 1].to_vec(), "truncated"),
            ([good.clone(), vec![0; 4]].concat(), "file is 92 bytes"),
            (
                gtx(10.0, 20.0, 0.5, 1.0, 4, 4, &[0.0; 12]),
                "4 rows × 4 columns",
            ),
            (
                gtx(10.0, 20.0, 0.5, 1.0, -3, -4, &[0.0; 12]),
                "must be positive",
            ),
            (gtx(10.0, 20.0, 0.5, 1.0, 0, 4, &[]), "must be positive"),
            (
                gtx(10.0, 20.0, 0.5, 1.0, i32::MAX, i32::MAX, &[]),
                "truncated",
            ),
            (
                gtx(10.0, 20.0, f64::NAN, 1.0, 3, 4, &[0.0; 12]),
                "latitude spacing is not a finite",
            ),
            (
                gtx(10.0, f64::INFINITY, 0.5, 1.0, 3, 4, &[0.0; 12]),
                "west longitude is not a finite",
            ),
            (
                gtx(10.0, 20.0, 0.5, 0.0, 3, 4, &[0.0; 12]),
                "must be positive",
            ),
            (
                gtx(10.0, 20.0, -0.5, 1.0, 3, 4, &[0.0; 12]),
                "must be positive",
            ),
            (
                gtx(-100.0, 20.0, 0.5, 1.0, 3, 4, &[0.0; 12]),
                "outside −90°…90°",
            ),
            (
                gtx(89.5, 20.0, 0.5, 1.0, 3, 4, &[0.0; 12]),
                "outside −90°…90°",
            ),
            (
                gtx(10.0, 400.0, 0.5, 1.0, 3, 4, &[0.0; 12]),
                "outside −360°…360°",
            ),
            (
                gtx(10.0, 20.0, 0.5, 200.0, 3, 4, &[0.0; 12]),
                "more than 360°",
            ),
            (
                b"P6\n3 4\n255\n0000000000000000000000000000000000000".to_vec(),
                "bad.gtx",
            ),
        ];
        for (bytes, want) in cases {
            let e = error_of(&bytes);
            assert!(e.contains("bad.gtx"), "{e}");
            assert!(e.contains(want), "wanted {want:?} in: {e}");
        }
    }

    #[test]
    fn geoid_garbled_bytes_never_panic() {
        let values: Vec<f32> = (0..12).map(|i| i as f32).collect();
        let good = gtx(10.0, 20.0, 0.5, 1.0, 3, 4, &values);
        for n in 0..good.len() {
            assert!(
                Geoid::from_bytes("cut.gtx", &good[..n]).is_err(),
                "{n} bytes"
            );
        }
        // Random bytes over the header (a fixed LCG, so a failure replays): each file
        // either opens and interpolates, or is an error.
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            (state >> 33) as u8
        };
        for _ in 0..20_000 {
            let mut b = good.clone();
            for _ in 0..=next() % 4 {
                let i = usize::from(next()) % HEADER_LEN;
                b[i] = next();
            }
            if let Ok(g) = Geoid::from_bytes("garbled.gtx", &b) {
                for (lon, lat) in [(0.0, 0.0), (20.5, 10.5), (-179.0, 89.0), (540.0, -90.0)] {
                    let _ = g.undulation(lon, lat);
                }
            }
        }
    }

    #[test]
    fn geoid_open_names_a_missing_or_short_file() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("nope.gtx");
        let e = format!("{:#}", Geoid::open(&missing).unwrap_err());
        assert!(e.contains("nope.gtx") && e.contains("cannot open"), "{e}");
        let short = dir.path().join("short.gtx");
        std::fs::write(&short, [0u8; 12]).unwrap();
        let e = format!("{:#}", Geoid::open(&short).unwrap_err());
        assert!(e.contains("short.gtx") && e.contains("too short"), "{e}");
        let ok = dir.path().join("ok.gtx");
        std::fs::write(&ok, gtx(0.0, 0.0, 1.0, 1.0, 1, 2, &[1.0, 2.0])).unwrap();
        assert_eq!(Geoid::open(&ok).unwrap().undulation(0.5, 0.0), 1.5);
    }

    #[test]
    fn geoid_find_prefers_flag_then_env_then_defaults() {
        let dir = tempfile::tempdir().unwrap();
        let present = dir.path().join("present.gtx");
        std::fs::write(&present, b"x").unwrap();
        let present_s = present.to_str().unwrap();
        let flag = Path::new("/flag/egm.gtx");
        let env = || Some(OsString::from("/env/egm.gtx"));
        let defaults = ["/nonexistent/a.gtx", present_s];
        assert_eq!(
            find_in(Some(flag), env(), &defaults),
            Some(flag.to_path_buf())
        );
        assert_eq!(
            find_in(None, env(), &defaults),
            Some(PathBuf::from("/env/egm.gtx"))
        );
        assert_eq!(
            find_in(None, Some(OsString::new()), &defaults),
            Some(present.clone())
        );
        assert_eq!(find_in(None, None, &defaults), Some(present));
        assert_eq!(find_in(None, None, &["/nonexistent/a.gtx"]), None);
        assert_eq!(DEFAULT_PATHS[0], "/usr/share/proj/egm96_15.gtx");
    }

    /// The real EGM96 grid against PROJ: `cs2cs` from WGS84 with EGM96 heights (the
    /// grid named explicitly, so both read the same file) to WGS84 3D (EPSG:4979, which
    /// prints latitude first) turns H = 0 into h = N.
    #[test]
    fn geoid_egm96_matches_cs2cs() {
        use std::fmt::Write as _;
        let Some(path) = find(None).filter(|p| p.is_file()) else {
            return skip("no EGM96 grid (apt-get install proj-data, or set TESSERA_GEOID)");
        };
        let has_cs2cs = std::process::Command::new("sh")
            .args(["-c", "command -v cs2cs"])
            .output()
            .is_ok_and(|o| o.status.success());
        if !has_cs2cs {
            return skip("cs2cs is not installed (apt-get install proj-bin)");
        }
        let g = Geoid::open(&path).unwrap();
        #[rustfmt::skip]
        let points: &[(f64, f64)] = &[
            (8.6, 46.9),        // Switzerland
            (8.5, 47.0),        // a grid node
            (86.925, 27.988),   // Everest
            (77.0, 32.5),       // western Himalaya
            (78.5, -1.0),       // the Indian Ocean low
            (-180.0, 0.0),      // the antimeridian, both ways
            (180.0, 0.0),
            (179.9, 10.0),
            (179.999, -10.0),
            (-179.87, -10.1),
            (-179.99, 65.5),    // Bering Strait
            (0.0, 90.0),        // the poles and next to them
            (0.0, -90.0),
            (45.0, 89.99),
            (-120.0, -89.9),
            (0.0, 0.0),
            (-74.0, 40.7),
            (147.3, -42.9),
            (-68.0, -23.0),
            (139.7, 35.7),
            (-0.125, 51.5),
            (-147.13, 64.2),
        ];
        let mut input = String::new();
        for (lon, lat) in points {
            writeln!(input, "{lon} {lat} 0").unwrap();
        }
        let proj_points = cs2cs(&path, &input);
        assert_eq!(
            proj_points.len(),
            points.len(),
            "cs2cs answered {proj_points:?}"
        );
        let mut worst = 0.0_f64;
        for (&(lon, lat), &proj) in points.iter().zip(&proj_points) {
            let ours = g.undulation(lon, lat);
            let diff = (ours - proj).abs();
            eprintln!("{lon:>9} {lat:>8}  ours {ours:>12.6}  PROJ {proj:>12.6}  |Δ| {diff:.2e}");
            assert!(diff <= 1e-3, "at {lon} {lat}: ours {ours}, PROJ {proj}");
            worst = worst.max(diff);
        }
        eprintln!(
            "EGM96 vs cs2cs: {} points, max |Δ| {worst:.3e} m",
            points.len()
        );
        // Central Switzerland's geoid lies some 48.6 m above the ellipsoid.
        assert!((48.0..49.5).contains(&g.undulation(8.6, 46.9)));
    }

    /// cs2cs's ellipsoidal heights for `input` (lines of "lon lat H").
    fn cs2cs(grid: &Path, input: &str) -> Vec<f64> {
        use std::io::Write;
        let source = format!(
            "+proj=longlat +datum=WGS84 +geoidgrids={} +type=crs",
            grid.display()
        );
        let mut child = std::process::Command::new("cs2cs")
            .args(["-f", "%.9f", &source, "+to", "EPSG:4979"])
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        child
            .stdin
            .take()
            .unwrap()
            .write_all(input.as_bytes())
            .unwrap();
        let out = child.wait_with_output().unwrap();
        assert!(out.status.success(), "cs2cs failed: {out:?}");
        String::from_utf8(out.stdout)
            .unwrap()
            .lines()
            .map(|l| {
                let h = l.split_whitespace().nth(2);
                h.and_then(|h| h.parse().ok())
                    .unwrap_or_else(|| panic!("cs2cs said {l:?}"))
            })
            .collect()
    }

    /// As `tessera_shared::testdata::dem_or_skip`: a visible line, but never under CI.
    fn skip(why: &str) {
        assert!(
            std::env::var_os("CI").is_none(),
            "{why}, and CI is set: the geoid comparison must run"
        );
        eprintln!("SKIPPED: {why}");
    }
}
