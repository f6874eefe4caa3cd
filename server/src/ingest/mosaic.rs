//! Many same-grid inputs read as one raster (issue 13): a [`RowSource`] over files
//! and GDAL VRTs ([`super::vrt`]) placed on one lattice.
//!
//! Every input's header is read once, up front, to check that it shares the first
//! input's CRS and grid and to place it; then it is closed. While rows are read, an
//! input is opened when the row cursor reaches its top row and dropped after its
//! bottom row, so only the inputs crossing the current row are open, and the memory
//! the mosaic holds is the largest sum of their buffers over the rows, whatever the
//! number of inputs ([`RowSource::buffer_bytes`]).
//!
//! Samples that no input covers are NaN (missing), and so is every input's own
//! no-data value (or `--nodata`), converted per input, so inputs with different
//! no-data values mix. Where inputs overlap, a missing sample never conflicts with a
//! valid one; two valid samples must be equal, or [`Overlap`] decides.

use super::vrt::{Rect, Vrt, is_vrt};
use super::{RowSource, SampleType, SourceInfo};
use anyhow::{Context, bail};
use std::path::{Path, PathBuf};
use tessera_shared::{GeoRef, RasterType, VerticalDatum};

/// What happens where two inputs overlap with different valid values.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Overlap {
    /// The input listed first wins.
    First,
    /// The input listed last wins (as GDAL draws VRT sources).
    Last,
    /// Stop with the sample, its coordinates and the two files.
    #[default]
    Error,
}

/// Opens a raster file for reading: its reader and its format's name ("GeoTIFF").
pub type Opener = fn(&Path) -> anyhow::Result<(Box<dyn RowSource>, &'static str)>;

/// Lattice origins (and spacings over an input's size) may differ by this fraction of a cell.
const LATTICE_TOLERANCE: f64 = 1e-6;
/// Memory an open input holds beyond its reader's `buffer_bytes()` and its row:
/// the file's read buffer (64 KiB) and decoder state.
const OPEN_INPUT_BYTES: u64 = 128 << 10;

/// One input file and where its samples go.
#[derive(Clone, Debug)]
struct Piece {
    path: PathBuf,
    /// How messages name it.
    name: String,
    format: &'static str,
    sample_type: SampleType,
    /// Its window in the mosaic.
    x: u32,
    y: u32,
    w: u32,
    h: u32,
    /// The window's first column and row in the source, and the source's size.
    src_x: u32,
    src_y: u32,
    src_width: u32,
    src_height: u32,
    /// Raw values that are missing (besides NaN).
    nodata: Vec<f32>,
    /// Memory while open.
    bytes: u64,
    /// What its heights are measured from, when its format says.
    vertical_datum: Option<VerticalDatum>,
}

/// An open piece: its reader and its current row (no-data already NaN).
#[derive(Debug)]
struct OpenPiece {
    index: usize,
    reader: Box<dyn RowSource>,
    row: Vec<f32>,
}

/// An argument of the mosaic before placement: one file, or a VRT's sources.
struct Group {
    name: String,
    georef: Option<GeoRef>,
    width: u32,
    height: u32,
    /// Pieces with `x`/`y` relative to the group.
    pieces: Vec<Piece>,
    is_vrt: bool,
}

/// Many inputs as one raster.
#[derive(Debug)]
pub struct Mosaic {
    info: SourceInfo,
    pieces: Vec<Piece>,
    /// Piece indices by top row.
    by_top: Vec<usize>,
    next_open: usize,
    /// Open pieces in input order.
    open: Vec<OpenPiece>,
    row: u32,
    overlap: Overlap,
    opener: Opener,
    buffer_bytes: u64,
    /// The inputs' vertical datum, when they all state the same one.
    vertical_datum: Option<VerticalDatum>,
    /// How build errors name the mosaic ("mosaic of 16 inputs", or the VRT).
    label: String,
    /// What the metadata's `source` names: the first file and the count.
    source_name: String,
}

fn file_name(p: &Path) -> String {
    p.file_name().map_or_else(
        || p.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

fn crs_text(g: &GeoRef) -> String {
    g.crs()
        .or_else(|| g.crs_name.clone())
        .unwrap_or_else(|| "an unnamed CRS".into())
}

fn same_crs(a: &GeoRef, b: &GeoRef) -> bool {
    match (a.epsg, b.epsg) {
        (Some(x), Some(y)) => x == y,
        (None, None) => a.crs_name == b.crs_name,
        _ => false,
    }
}

impl Mosaic {
    /// Reads the headers of `inputs` (files or VRTs, in order), checks that they share
    /// a CRS and a grid and places them. `nodata` overrides every input's own no-data.
    pub fn open(
        inputs: &[PathBuf],
        nodata: Option<f64>,
        overlap: Overlap,
        opener: Opener,
    ) -> anyhow::Result<Self> {
        if inputs.is_empty() {
            bail!("no input to build from");
        }
        let mut groups = Vec::with_capacity(inputs.len());
        for path in inputs {
            groups.push(if is_vrt(path) {
                vrt_group(path, nodata, opener)?
            } else {
                file_group(path, nodata, opener)?
            });
        }
        let (width, height, georef, pieces) = place(groups.as_slice())?;
        let any_vrt = groups.iter().any(|g| g.is_vrt);
        let (label, source_name) = names(&groups, &pieces);
        drop(groups);

        let first_type = pieces[0].sample_type;
        let sample_type = if pieces.iter().all(|p| p.sample_type == first_type) {
            first_type
        } else {
            SampleType::Float32
        };
        let mut formats: Vec<&str> = pieces.iter().map(|p| p.format).collect();
        formats.sort_unstable();
        formats.dedup();
        let mut types: Vec<&str> = pieces.iter().map(|p| p.sample_type.name()).collect();
        types.sort_unstable();
        types.dedup();
        let description = format!(
            "{}mosaic of {} {} {} inputs",
            if any_vrt && inputs.len() == 1 {
                "VRT "
            } else {
                ""
            },
            pieces.len(),
            formats.join("/"),
            types.join("/"),
        );
        // The datum the inputs state, when those that state one agree.
        let mut datums = pieces.iter().filter_map(|p| p.vertical_datum);
        let vertical_datum = datums.next().filter(|d| datums.all(|e| e == *d));
        let mut by_top: Vec<usize> = (0..pieces.len()).collect();
        by_top.sort_by_key(|&i| (pieces[i].y, i));
        let buffer_bytes = peak_open_bytes(&pieces)
            + pieces
                .iter()
                .map(|p| (size_of::<Piece>() + p.path.as_os_str().len() + p.name.len()) as u64)
                .sum::<u64>();
        Ok(Self {
            info: SourceInfo {
                width,
                height,
                sample_type,
                nodata: None,
                georef,
                description,
            },
            pieces,
            by_top,
            next_open: 0,
            open: Vec::new(),
            row: 0,
            overlap,
            opener,
            buffer_bytes,
            vertical_datum,
            label,
            source_name,
        })
    }

    /// How build errors name the mosaic.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// The first file and the count, for the metadata's `source`.
    pub fn source_name(&self) -> &str {
        &self.source_name
    }

    /// Inputs (files) in the mosaic.
    pub fn len(&self) -> usize {
        self.pieces.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pieces.is_empty()
    }

    /// Inputs open now (for tests of the lazy opening).
    pub fn open_count(&self) -> usize {
        self.open.len()
    }

    fn open_piece(&self, index: usize) -> anyhow::Result<OpenPiece> {
        let p = &self.pieces[index];
        let (mut reader, _) = (self.opener)(&p.path).with_context(|| p.name.clone())?;
        let i = reader.info();
        if (i.width, i.height) != (p.src_width, p.src_height) {
            bail!(
                "{}: changed while the build ran (now {}×{}, was {}×{})",
                p.name,
                i.width,
                i.height,
                p.src_width,
                p.src_height
            );
        }
        let mut row = vec![0f32; p.src_width as usize];
        for _ in 0..p.src_y {
            reader.read_rows(&mut row).with_context(|| p.name.clone())?;
        }
        Ok(OpenPiece { index, reader, row })
    }
}

/// The error for two inputs that disagree at mosaic sample `(col, row)`: `kept` came
/// from one of the `earlier` open pieces, `new` from piece `later`.
#[allow(clippy::too_many_arguments)]
fn conflict(
    pieces: &[Piece],
    georef: Option<&GeoRef>,
    earlier: &[OpenPiece],
    later: usize,
    (col, row): (u32, u32),
    kept: f32,
    new: f32,
) -> anyhow::Error {
    let other = earlier
        .iter()
        .find(|o| {
            let p = &pieces[o.index];
            (p.x..p.x + p.w).contains(&col) && o.row[(p.src_x + col - p.x) as usize] == kept
        })
        .map_or("an earlier input", |o| pieces[o.index].name.as_str());
    let at = georef.map_or_else(String::new, |g| {
        let gt = &g.geotransform;
        let x = gt[0] + (f64::from(col) + 0.5) * gt[1];
        let y = gt[3] + (f64::from(row) + 0.5) * gt[5];
        format!(" ({} {x}, {y})", crs_text(g))
    });
    anyhow::anyhow!(
        "{other} and {} disagree at sample (col {col}, row {row}){at}: {kept} vs {new} \
         (choose with --overlap first|last)",
        pieces[later].name
    )
}

/// The largest sum of open pieces' memory over the rows: pieces are open from their
/// top row to their bottom row.
fn peak_open_bytes(pieces: &[Piece]) -> u64 {
    let mut events: Vec<(u32, i64)> = Vec::with_capacity(2 * pieces.len());
    for p in pieces {
        events.push((p.y, p.bytes as i64));
        events.push((p.y + p.h, -(p.bytes as i64)));
    }
    // Closing before opening at the same row: a piece is dropped after its last row,
    // before the next piece's first.
    events.sort_unstable_by_key(|&(row, delta)| (row, delta));
    let (mut now, mut peak) = (0i64, 0i64);
    for (_, delta) in events {
        now += delta;
        peak = peak.max(now);
    }
    peak as u64
}

fn nodata_values(nodata: Option<f64>, own: &[Option<f64>]) -> Vec<f32> {
    let mut v: Vec<f32> = match nodata {
        Some(n) => vec![n as f32],
        None => own.iter().flatten().map(|&n| n as f32).collect(),
    };
    v.retain(|n| !n.is_nan());
    v.sort_unstable_by(f32::total_cmp);
    v.dedup();
    v
}

fn piece_bytes(reader: &dyn RowSource) -> u64 {
    reader.buffer_bytes() + u64::from(reader.info().width) * 4 + OPEN_INPUT_BYTES
}

fn file_group(path: &Path, nodata: Option<f64>, opener: Opener) -> anyhow::Result<Group> {
    let name = path.display().to_string();
    let (reader, format) = opener(path).with_context(|| name.clone())?;
    let info = reader.info().clone();
    let piece = Piece {
        path: path.to_path_buf(),
        name: name.clone(),
        format,
        sample_type: info.sample_type,
        x: 0,
        y: 0,
        w: info.width,
        h: info.height,
        src_x: 0,
        src_y: 0,
        src_width: info.width,
        src_height: info.height,
        nodata: nodata_values(nodata, &[info.nodata]),
        bytes: piece_bytes(reader.as_ref()),
        vertical_datum: reader.vertical_datum(),
    };
    Ok(Group {
        name,
        georef: info.georef,
        width: info.width,
        height: info.height,
        pieces: vec![piece],
        is_vrt: false,
    })
}

fn vrt_group(path: &Path, nodata: Option<f64>, opener: Opener) -> anyhow::Result<Group> {
    let vrt_name = path.display().to_string();
    let vrt = Vrt::open(path).with_context(|| vrt_name.clone())?;
    let mut pieces = Vec::with_capacity(vrt.sources.len());
    let mut crs: Option<GeoRef> = None;
    for s in &vrt.sources {
        let name = s.path.display().to_string();
        if is_vrt(&s.path) {
            bail!("{vrt_name}: names {name}, another VRT: nested VRTs are not supported");
        }
        let (reader, format) = opener(&s.path)
            .with_context(|| format!("{vrt_name}: names {name}, which cannot be read"))?;
        let info = reader.info().clone();
        if crs.is_none() {
            crs.clone_from(&info.georef);
        }
        let whole = Rect {
            x: 0,
            y: 0,
            w: u64::from(info.width),
            h: u64::from(info.height),
        };
        let src = s.src.unwrap_or(whole);
        let dst = s.dst.unwrap_or(src);
        // Clip the copy to the source and to the VRT (1:1, so one shift maps both).
        let (dx, dy) = (dst.x - src.x, dst.y - src.y);
        let x0 = src.x.max(0).max(-dx);
        let y0 = src.y.max(0).max(-dy);
        let x1 = (src.x + src.w as i64)
            .min(i64::from(info.width))
            .min(i64::from(vrt.width) - dx);
        let y1 = (src.y + src.h as i64)
            .min(i64::from(info.height))
            .min(i64::from(vrt.height) - dy);
        if x1 <= x0 || y1 <= y0 {
            tracing::warn!("{vrt_name}: source {name} draws nothing inside the VRT; skipped");
            continue;
        }
        pieces.push(Piece {
            path: s.path.clone(),
            name: format!("{vrt_name}: {name}"),
            format,
            sample_type: info.sample_type,
            x: (x0 + dx) as u32,
            y: (y0 + dy) as u32,
            w: (x1 - x0) as u32,
            h: (y1 - y0) as u32,
            src_x: x0 as u32,
            src_y: y0 as u32,
            src_width: info.width,
            src_height: info.height,
            nodata: nodata_values(nodata, &[info.nodata, s.nodata, vrt.nodata]),
            bytes: piece_bytes(reader.as_ref()),
            vertical_datum: reader.vertical_datum(),
        });
    }
    if pieces.is_empty() {
        bail!("{vrt_name}: no source draws anything inside the VRT");
    }
    // The CRS is the one our readers find in the sources; the VRT gives the grid.
    let georef = match (vrt.geotransform, crs) {
        (Some(geotransform), Some(crs)) => {
            if let (Some(vrt_code), Some(src_code)) = (vrt.srs_epsg, crs.epsg)
                && vrt_code != src_code
            {
                bail!(
                    "{vrt_name}: its SRS is EPSG:{vrt_code} but its source {} is EPSG:{src_code}",
                    pieces[0].name
                );
            }
            let raster_type = match vrt.pixel_is_point {
                Some(true) => RasterType::PixelIsPoint,
                Some(false) => RasterType::PixelIsArea,
                None => crs.raster_type,
            };
            Some(GeoRef {
                geotransform,
                raster_type,
                ..crs
            })
        }
        (Some(_), None) => {
            tracing::warn!(
                "{vrt_name}: its sources carry no CRS; the pyramid will have no georeferencing"
            );
            None
        }
        (None, _) => None,
    };
    Ok(Group {
        name: vrt_name,
        georef,
        width: vrt.width,
        height: vrt.height,
        pieces,
        is_vrt: true,
    })
}

/// Checks that every group shares the first's CRS and grid, and places them: the
/// mosaic's size, georeferencing and pieces in mosaic coordinates (in input order).
fn place(groups: &[Group]) -> anyhow::Result<(u32, u32, Option<GeoRef>, Vec<Piece>)> {
    let first = &groups[0];
    if groups.len() == 1 {
        return Ok((
            first.width,
            first.height,
            first.georef.clone(),
            first.pieces.clone(),
        ));
    }
    let georef_of = |g: &Group| -> anyhow::Result<GeoRef> {
        g.georef.clone().with_context(|| {
            format!(
                "{}: has no georeferencing, so it cannot be placed in a mosaic",
                g.name
            )
        })
    };
    let g0 = georef_of(first)?;
    let gt0 = g0.geotransform;
    let (sx, sy) = (gt0[1], gt0[5]);
    if sx <= 0.0 || sy >= 0.0 {
        bail!(
            "{}: not north-up (pixel size {sx} × {sy}); only north-up rasters can be mosaicked",
            first.name
        );
    }
    let mut offsets = Vec::with_capacity(groups.len());
    for g in groups {
        let gi = georef_of(g)?;
        let gt = gi.geotransform;
        if !same_crs(&g0, &gi) {
            bail!(
                "{} and {}: different CRS ({} vs {})",
                first.name,
                g.name,
                crs_text(&g0),
                crs_text(&gi)
            );
        }
        // Spacings agree when the drift they cause over this input stays inside the
        // lattice tolerance.
        let drift_x = (gt[1] - sx).abs() * f64::from(g.width) / sx.abs();
        let drift_y = (gt[5] - sy).abs() * f64::from(g.height) / sy.abs();
        if drift_x > LATTICE_TOLERANCE
            || drift_y > LATTICE_TOLERANCE
            || gt[2] != 0.0
            || gt[4] != 0.0
        {
            bail!(
                "{} and {}: different spacing ({} × {} vs {} × {})",
                first.name,
                g.name,
                sx,
                -sy,
                gt[1],
                -gt[5]
            );
        }
        let ox = (gt[0] - gt0[0]) / sx;
        let oy = (gt[3] - gt0[3]) / sy;
        let (fx, fy) = (ox - ox.round(), oy - oy.round());
        if fx.abs() > LATTICE_TOLERANCE || fy.abs() > LATTICE_TOLERANCE {
            bail!(
                "{} and {}: origins are not on the same lattice ({} is {fx:.6} × {fy:.6} cells off)",
                first.name,
                g.name,
                g.name
            );
        }
        offsets.push((ox.round() as i64, oy.round() as i64));
    }
    let min_x = offsets.iter().map(|o| o.0).min().unwrap_or(0);
    let min_y = offsets.iter().map(|o| o.1).min().unwrap_or(0);
    let mut width = 0i64;
    let mut height = 0i64;
    for (g, (ox, oy)) in groups.iter().zip(&offsets) {
        width = width.max(ox - min_x + i64::from(g.width));
        height = height.max(oy - min_y + i64::from(g.height));
    }
    let (Ok(width), Ok(height)) = (u32::try_from(width), u32::try_from(height)) else {
        bail!("the inputs span {width}×{height} samples, more than a pyramid can hold");
    };
    // The origin: exactly the coordinates of the inputs that lie furthest west and north.
    let west = groups[offsets.iter().position(|o| o.0 == min_x).unwrap_or(0)]
        .georef
        .as_ref()
        .map_or(gt0[0], |g| g.geotransform[0]);
    let north = groups[offsets.iter().position(|o| o.1 == min_y).unwrap_or(0)]
        .georef
        .as_ref()
        .map_or(gt0[3], |g| g.geotransform[3]);
    let georef = GeoRef {
        geotransform: [west, sx, 0.0, north, 0.0, sy],
        ..g0
    };
    let mut pieces = Vec::new();
    for (g, (ox, oy)) in groups.iter().zip(&offsets) {
        for p in &g.pieces {
            pieces.push(Piece {
                x: p.x + (ox - min_x) as u32,
                y: p.y + (oy - min_y) as u32,
                ..p.clone()
            });
        }
    }
    Ok((width, height, Some(georef), pieces))
}

fn names(groups: &[Group], pieces: &[Piece]) -> (String, String) {
    let more = |n: usize| {
        if n > 1 {
            format!(" and {} more", n - 1)
        } else {
            String::new()
        }
    };
    let first_file = file_name(&pieces[0].path);
    if let [g] = groups
        && g.is_vrt
    {
        let vrt = file_name(Path::new(&g.name));
        return (
            g.name.clone(),
            format!("{vrt}: {first_file}{}", more(pieces.len())),
        );
    }
    (
        format!("mosaic of {} inputs", pieces.len()),
        format!("{first_file}{}", more(pieces.len())),
    )
}

impl RowSource for Mosaic {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn read_rows(&mut self, out: &mut [f32]) -> anyhow::Result<()> {
        let w = self.info.width as usize;
        for out_row in out.chunks_exact_mut(w) {
            let r = self.row;
            if r >= self.info.height {
                bail!("read past the mosaic's last row");
            }
            // Open the inputs whose top row this is, keeping `open` in input order.
            while let Some(&i) = self.by_top.get(self.next_open)
                && self.pieces[i].y == r
            {
                let opened = self.open_piece(i)?;
                let at = self.open.partition_point(|o| o.index < i);
                self.open.insert(at, opened);
                self.next_open += 1;
            }
            out_row.fill(f32::NAN);
            for k in 0..self.open.len() {
                let (earlier, rest) = self.open.split_at_mut(k);
                let o = &mut rest[0];
                let p = &self.pieces[o.index];
                o.reader
                    .read_rows(&mut o.row)
                    .with_context(|| p.name.clone())?;
                let window = &mut o.row[p.src_x as usize..(p.src_x + p.w) as usize];
                if !p.nodata.is_empty() {
                    for v in window.iter_mut() {
                        if p.nodata.contains(v) {
                            *v = f32::NAN;
                        }
                    }
                }
                let dst = &mut out_row[p.x as usize..(p.x + p.w) as usize];
                for (j, (d, &v)) in dst.iter_mut().zip(window.iter()).enumerate() {
                    if v.is_nan() || *d == v {
                        continue;
                    }
                    if d.is_nan() {
                        *d = v;
                        continue;
                    }
                    match self.overlap {
                        Overlap::First => {}
                        Overlap::Last => *d = v,
                        Overlap::Error => {
                            let (kept, index) = (*d, o.index);
                            let col = p.x + j as u32;
                            return Err(conflict(
                                &self.pieces,
                                self.info.georef.as_ref(),
                                earlier,
                                index,
                                (col, r),
                                kept,
                                v,
                            ));
                        }
                    }
                }
            }
            // Drop the inputs whose bottom row this was.
            let pieces = &self.pieces;
            self.open
                .retain(|o| pieces[o.index].y + pieces[o.index].h > r + 1);
            self.row += 1;
        }
        Ok(())
    }

    fn buffer_bytes(&self) -> u64 {
        self.buffer_bytes
    }

    fn vertical_datum(&self) -> Option<VerticalDatum> {
        self.vertical_datum
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;
    use std::sync::{Mutex, MutexGuard};

    /// In-memory rasters the test opener serves by path.
    static RASTERS: Mutex<Option<HashMap<PathBuf, Mem>>> = Mutex::new(None);
    /// Tests share `RASTERS`: one at a time.
    static SERIAL: Mutex<()> = Mutex::new(());

    #[derive(Clone, Debug)]
    struct Mem {
        info: SourceInfo,
        values: Vec<f32>,
        next: usize,
    }

    impl RowSource for Mem {
        fn info(&self) -> &SourceInfo {
            &self.info
        }
        fn read_rows(&mut self, out: &mut [f32]) -> anyhow::Result<()> {
            out.copy_from_slice(&self.values[self.next..self.next + out.len()]);
            self.next += out.len();
            Ok(())
        }
        fn buffer_bytes(&self) -> u64 {
            1000
        }
    }

    fn mem_open(path: &Path) -> anyhow::Result<(Box<dyn RowSource>, &'static str)> {
        let guard = RASTERS.lock().unwrap();
        let m = guard
            .as_ref()
            .and_then(|r| r.get(path))
            .with_context(|| format!("{}: no such raster", path.display()))?;
        Ok((Box::new(m.clone()), "Mem"))
    }

    /// Some EPSG:4326 georeferencing (an SRTM tile's header; nothing is read).
    fn hgt_georef() -> GeoRef {
        crate::ingest::hgt::Hgt::from_reader("N00E000", 2_884_802, std::io::empty())
            .unwrap()
            .info()
            .georef
            .clone()
            .unwrap()
    }

    /// A raster at lattice cell `(col, row)` of a 1-unit grid, filled by `f(x, y)`.
    fn put(name: &str, col: i32, row: i32, w: u32, h: u32, f: impl Fn(u32, u32) -> f32) -> PathBuf {
        let values = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| f(x, y))
            .collect();
        let georef = GeoRef {
            geotransform: [
                100.0 + f64::from(col),
                1.0,
                0.0,
                200.0 - f64::from(row),
                0.0,
                -1.0,
            ],
            ..hgt_georef()
        };
        let m = Mem {
            info: SourceInfo {
                width: w,
                height: h,
                sample_type: SampleType::Int16,
                nodata: Some(-99.0),
                georef: Some(georef),
                description: String::new(),
            },
            values,
            next: 0,
        };
        let path = PathBuf::from(name);
        RASTERS
            .lock()
            .unwrap()
            .get_or_insert_with(HashMap::new)
            .insert(path.clone(), m);
        path
    }

    fn serial() -> MutexGuard<'static, ()> {
        let g = SERIAL
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        *RASTERS.lock().unwrap() = None;
        g
    }

    fn read_all(m: &mut Mosaic) -> anyhow::Result<Vec<f32>> {
        let mut out = vec![0f32; (m.info.width * m.info.height) as usize];
        m.read_rows(&mut out)?;
        Ok(out)
    }

    #[test]
    fn pieces_sharing_borders_read_as_one_raster_with_gaps_missing() {
        let _g = serial();
        // A 5×3 raster of x + 10·y cut into a left 3×3 and a right 3×2 piece sharing
        // column 2; the right piece's missing bottom row is a gap.
        let a = put("a", 0, 0, 3, 3, |x, y| (x + 10 * y) as f32);
        let b = put("b", 2, 0, 3, 2, |x, y| (x + 2 + 10 * y) as f32);
        let mut m = Mosaic::open(&[a, b], None, Overlap::Error, mem_open).unwrap();
        assert_eq!((m.info.width, m.info.height), (5, 3));
        assert_eq!(m.info.georef.as_ref().unwrap().geotransform[0], 100.0);
        let v = read_all(&mut m).unwrap();
        assert_eq!(&v[..10], &[0., 1., 2., 3., 4., 10., 11., 12., 13., 14.]);
        assert_eq!(&v[10..13], &[20., 21., 22.]);
        assert!(v[13].is_nan() && v[14].is_nan());
        assert_eq!(m.open_count(), 0);
        assert_eq!(m.info.description, "mosaic of 2 Mem int16 inputs");
        assert_eq!(m.source_name(), "a and 1 more");
    }

    #[test]
    fn each_inputs_nodata_is_missing_and_does_not_conflict() {
        let _g = serial();
        // `a` says -99 (its no-data) where `b` has 7.
        let a = put("a", 0, 0, 2, 1, |x, _| if x == 1 { -99.0 } else { 1.0 });
        let b = put("b", 1, 0, 2, 1, |_, _| 7.0);
        let mut m = Mosaic::open(&[a.clone(), b.clone()], None, Overlap::Error, mem_open).unwrap();
        assert_eq!(read_all(&mut m).unwrap(), vec![1.0, 7.0, 7.0]);
        // --nodata 7 overrides: b's 7s are missing, a's -99 is a value.
        let mut m = Mosaic::open(&[a, b], Some(7.0), Overlap::Error, mem_open).unwrap();
        let v = read_all(&mut m).unwrap();
        assert_eq!(&v[..2], &[1.0, -99.0]);
        assert!(v[2].is_nan());
    }

    #[test]
    fn disagreeing_overlaps_follow_the_overlap_rule() {
        let _g = serial();
        let a = put("a", 0, 0, 2, 2, |_, _| 1.0);
        let b = put("b", 1, 1, 2, 2, |_, _| 2.0);
        let both = [a, b];
        let mut m = Mosaic::open(&both, None, Overlap::First, mem_open).unwrap();
        assert_eq!(read_all(&mut m).unwrap()[4], 1.0);
        let mut m = Mosaic::open(&both, None, Overlap::Last, mem_open).unwrap();
        assert_eq!(read_all(&mut m).unwrap()[4], 2.0);
        let mut m = Mosaic::open(&both, None, Overlap::Error, mem_open).unwrap();
        let e = read_all(&mut m).unwrap_err().to_string();
        assert!(
            e.contains(
                "a and b disagree at sample (col 1, row 1) (EPSG:4326 101.5, 198.5): 1 vs 2"
            ),
            "{e}"
        );
    }

    #[test]
    fn only_inputs_crossing_the_row_are_open_and_memory_counts_them() {
        let _g = serial();
        // A column of 4 pieces, each 2 rows, sharing a row with the next.
        let paths: Vec<PathBuf> = (0..4)
            .map(|i| put(&format!("p{i}"), 0, i, 2, 2, |_, _| 5.0))
            .collect();
        let mut m = Mosaic::open(&paths, None, Overlap::Error, mem_open).unwrap();
        assert_eq!(m.info.height, 5);
        let per = 1000 + 2 * 4 + OPEN_INPUT_BYTES;
        assert_eq!(
            peak_open_bytes(&m.pieces),
            2 * per,
            "two pieces share each border row"
        );
        assert!(m.buffer_bytes() > 2 * per, "the table of pieces counts too");
        let mut row = [0f32; 2];
        let mut most = 0;
        for _ in 0..5 {
            m.read_rows(&mut row).unwrap();
            most = most.max(m.open_count());
            assert_eq!(row, [5.0, 5.0]);
        }
        assert!(most <= 2, "{most} open at once");
        assert_eq!(m.open_count(), 0);
    }

    #[test]
    fn different_grids_are_refused_naming_both_files() {
        let _g = serial();
        let a = put("a", 0, 0, 2, 2, |_, _| 1.0);
        let b = put("b", 1, 0, 2, 2, |_, _| 1.0);
        // Off the lattice by half a cell.
        {
            let mut r = RASTERS.lock().unwrap();
            let m = r.as_mut().unwrap().get_mut(&b).unwrap();
            m.info.georef.as_mut().unwrap().geotransform[0] += 0.5;
        }
        let e = Mosaic::open(&[a.clone(), b.clone()], None, Overlap::Error, mem_open)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("a and b: origins are not on the same lattice"),
            "{e}"
        );
        {
            let mut r = RASTERS.lock().unwrap();
            let m = r.as_mut().unwrap().get_mut(&b).unwrap();
            let g = m.info.georef.as_mut().unwrap();
            g.geotransform[0] -= 0.5;
            g.geotransform[1] = 2.0;
        }
        let e = Mosaic::open(&[a.clone(), b.clone()], None, Overlap::Error, mem_open)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("a and b: different spacing (1 × 1 vs 2 × 1)"),
            "{e}"
        );
        {
            let mut r = RASTERS.lock().unwrap();
            let m = r.as_mut().unwrap().get_mut(&b).unwrap();
            let g = m.info.georef.as_mut().unwrap();
            g.geotransform[1] = 1.0;
            g.epsg = Some(32632);
        }
        let e = Mosaic::open(&[a, b], None, Overlap::Error, mem_open)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("a and b: different CRS (EPSG:4326 vs EPSG:32632)"),
            "{e}"
        );
    }
}
