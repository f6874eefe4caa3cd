//! Many same-grid inputs read as one raster (DECISIONS.md "Mosaics"): a [`RowSource`]
//! over files and GDAL VRTs ([`super::vrt`]) placed on one lattice.
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

use super::vertical_shift::VerticalOptions;
use super::vrt::is_vrt;
use super::{DatumClue, RowSource, SampleType, SourceInfo};
use anyhow::{Context, bail};
use conflict::conflict;
use datum::agreed_datum;
use feather::Edge;
use place::{file_group, names, vrt_group};
use std::path::{Path, PathBuf};
use summary::{log_mixed, summaries};
use tessera_shared::{GeoRef, VerticalDatum};

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
    /// The input with the finest ground spacing wins, ties by order (the default for
    /// inputs on different grids).
    Finest,
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
    /// What its heights are measured from, when it says, and where it says so.
    datum: Option<DatumClue>,
    /// Off the mosaic's grid: resampled onto its window ([`warp`]).
    warp: Option<Box<warp::Warp>>,
    /// Where its input ends, for `--feather`: the input's window on the mosaic
    /// `[x0, y0, x1, y1]` (cells; an input copied as it is), or, for a resampled one,
    /// the metres one of its source samples spans (its reader reports the distance to
    /// its source grid's edge in samples).
    edge: Edge,
    /// Metres one sample of its input spans, for inputs on different grids (what a
    /// multi-resolution pyramid stores it down to); `None` on one grid.
    metres: Option<f64>,
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
    /// The inputs' vertical datum, when those that state one agree ([`agreed_datum`]).
    datum: Option<DatumClue>,
    /// How build errors name the mosaic ("mosaic of 16 inputs", or the VRT).
    label: String,
    /// What the metadata's `source` names: the first file and the count.
    source_name: String,
    /// Where resampled inputs are spooled while open (inputs on different grids).
    spool_dir: Option<PathBuf>,
    /// Whether the inputs were on different grids and resampled onto one.
    resampled: bool,
    /// Converts each input's heights to one vertical datum as it is opened.
    vertical: VerticalOptions,
    /// Each input (file or VRT), in priority order, for the pyramid's provenance.
    inputs: Vec<super::InputSummary>,
    /// `--feather`, and the metres per mosaic cell `[x, y]` it measures windows with.
    feather: Option<(f64, [f64; 2])>,
    /// Per sample of a row while feathering: the weighted sum and the weight left.
    blend: Vec<(f64, f64)>,
    /// The columns read ([`RowSource::set_window`]; empty: all): inputs wholly
    /// outside them are not opened.
    columns: Vec<std::ops::Range<u32>>,
    /// The row before which the caller reads ([`RowSource::set_window`]).
    until: u32,
}

/// How [`Mosaic::open_with`] treats its inputs.
#[derive(Clone, Debug, Default)]
pub struct MosaicOptions {
    /// Overrides every input's own no-data value.
    pub nodata: Option<f64>,
    /// Who wins where inputs overlap; `None`: [`Overlap::Error`] for inputs on one
    /// grid, [`Overlap::Finest`] for inputs on different grids.
    pub overlap: Option<Overlap>,
    /// How inputs on different grids are put on one; `None`: they are refused,
    /// naming the two that differ.
    pub grid: Option<GridOptions>,
    /// The inputs' vertical datums and the one to convert them to.
    pub vertical: VerticalOptions,
    /// `--feather METRES`: within this distance of a higher-priority input's edge, its
    /// heights blend linearly into those below it instead of a hard seam.
    pub feather: Option<f64>,
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
        let opts = MosaicOptions {
            nodata,
            overlap: Some(overlap),
            ..MosaicOptions::default()
        };
        Self::open_with(inputs, &opts, opener)
    }

    /// Reads the headers of `inputs` (files or VRTs, in order) and places them: on
    /// their shared grid, or, with `opts.grid`, on one target grid that inputs on other
    /// grids are resampled onto ([`warp`]).
    pub fn open_with(
        inputs: &[PathBuf],
        opts: &MosaicOptions,
        opener: Opener,
    ) -> anyhow::Result<Self> {
        if inputs.is_empty() {
            bail!("no input to build from");
        }
        let nodata = opts.nodata;
        let groups = opening::open_all(inputs, |path| {
            if is_vrt(path) {
                vrt_group(path, nodata, &opts.vertical, opener)
            } else {
                file_group(path, nodata, &opts.vertical, opener)
            }
        })?;
        let (width, height, georef, pieces, overlap, resampled) =
            match (place::place(groups.as_slice()), &opts.grid) {
                (Ok((w, h, g, p)), _) => (w, h, g, p, opts.overlap.unwrap_or_default(), false),
                (Err(_), Some(grid)) if groups.len() > 1 => {
                    let overlap = opts.overlap.unwrap_or(Overlap::Finest);
                    let placed = warp::place_mixed(&groups, grid, overlap)?;
                    log_mixed(&groups, &placed);
                    (
                        placed.width,
                        placed.height,
                        Some(placed.georef),
                        placed.pieces,
                        overlap,
                        true,
                    )
                }
                (Err(e), _) => return Err(e),
            };
        let feather = match opts.feather {
            None => None,
            Some(f) if !(f.is_finite() && f > 0.0) => {
                bail!("--feather {f}: want a positive distance in metres")
            }
            Some(_) if !matches!(overlap, Overlap::First | Overlap::Finest) => {
                bail!("--feather blends by priority: it needs --overlap finest or first")
            }
            Some(f) => {
                let g = georef.as_ref().context(
                    "--feather needs georeferenced inputs (it measures distances in metres)",
                )?;
                let cell = crate::crs::ground_spacing(g, width, height)
                    .context("--feather: the mosaic's ground spacing")?;
                Some((f, [cell.x, cell.y]))
            }
        };
        let any_vrt = groups.iter().any(|g| g.is_vrt);
        let inputs = summaries(&groups, &pieces);
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
        let datum = match opts.vertical.to {
            Some(to) => {
                // Every input's datum must be known to convert it (checked here, before
                // anything is read).
                if let Some(p) = pieces.iter().find(|p| {
                    p.datum
                        .as_ref()
                        .and_then(|c| c.datum)
                        .is_none_or(|d| d == VerticalDatum::Unknown)
                }) {
                    bail!(
                        "{}: its heights' vertical datum is unknown ({}), so they cannot be \
                         converted to {}: give it with --vertical-datum 'FILE=DATUM'",
                        p.name,
                        p.datum
                            .as_ref()
                            .map_or("it states none", |c| c.why.as_str()),
                        to.name()
                    );
                }
                Some(DatumClue {
                    datum: Some(to),
                    why: format!("every input converted with --to-vertical {}", to.name()),
                })
            }
            None => agreed_datum(&pieces)?,
        };
        let mut by_top: Vec<usize> = (0..pieces.len()).collect();
        by_top.sort_by_key(|&i| (pieces[i].y, i));
        let buffer_bytes = peak_open_bytes(&pieces)
            + pieces
                .iter()
                .map(|p| {
                    let why = p.datum.as_ref().map_or(0, |c| c.why.len());
                    (size_of::<Piece>() + p.path.as_os_str().len() + p.name.len() + why) as u64
                })
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
            datum,
            label,
            source_name,
            spool_dir: opts.grid.as_ref().map(|g| g.spool_dir.clone()),
            resampled,
            vertical: opts.vertical.clone(),
            inputs,
            feather,
            blend: Vec::new(),
            columns: Vec::new(),
            until: u32::MAX,
        })
    }

    /// Whether the inputs were on different grids, resampled onto one.
    pub fn resampled(&self) -> bool {
        self.resampled
    }

    /// Each input (file or VRT) as its header describes it, in priority order.
    pub fn inputs(&self) -> &[super::InputSummary] {
        &self.inputs
    }

    /// Where each input lies on the mosaic's grid and how fine it is, for inputs on
    /// different grids (empty on one grid: every input is as fine as the mosaic).
    pub fn coverage(&self) -> Vec<super::Coverage> {
        self.pieces
            .iter()
            .filter_map(|p| {
                Some(super::Coverage {
                    window: [p.x, p.y, p.x + p.w, p.y + p.h],
                    metres: p.metres?,
                })
            })
            .collect()
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

    /// Whether input `i` lies over a column read.
    fn wanted(&self, i: usize) -> bool {
        wanted(&self.columns, &self.pieces[i])
    }

    /// Opens input `i`, passes over its first `skip` rows in the mosaic, and keeps it
    /// among the open inputs in input order.
    fn open_at(&mut self, i: usize, skip: u32) -> anyhow::Result<()> {
        let mut opened = self.open_piece(i)?;
        let p = &self.pieces[i];
        if !self.columns.is_empty() || self.until != u32::MAX {
            opened
                .reader
                .set_window(
                    &source_columns(&self.columns, p),
                    source_until(self.until, p),
                )
                .with_context(|| p.name.clone())?;
        }
        if skip > 0 {
            opened
                .reader
                .skip_rows(skip)
                .with_context(|| p.name.clone())?;
        }
        let at = self.open.partition_point(|o| o.index < i);
        self.open.insert(at, opened);
        Ok(())
    }

    fn open_piece(&self, index: usize) -> anyhow::Result<OpenPiece> {
        let p = &self.pieces[index];
        let (reader, _) = (self.opener)(&p.path).with_context(|| p.name.clone())?;
        let mut reader = self
            .vertical
            .convert(reader, &p.name, p.datum.as_ref(), &p.nodata)?;
        if let Some(w) = &p.warp {
            let i = reader.info();
            if (i.width as usize, i.height as usize) != (w.map.src_w, w.map.src_h) {
                bail!(
                    "{}: changed while the build ran (now {}×{}, was {}×{})",
                    p.name,
                    i.width,
                    i.height,
                    w.map.src_w,
                    w.map.src_h
                );
            }
            let dir = self.spool_dir.clone().unwrap_or_else(std::env::temp_dir);
            reader = Box::new(
                super::reproject::Reprojected::onto(
                    reader,
                    &w.map.source,
                    w.map.target.clone(),
                    w.map.out,
                    w.map.resampling,
                    w.nodata,
                    &dir,
                )
                .with_context(|| format!("{}: resampling onto the mosaic's grid", p.name))?,
            );
        }
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
        reader.skip_rows(p.src_y).with_context(|| p.name.clone())?;
        let row = vec![0f32; p.src_width as usize];
        Ok(OpenPiece { index, reader, row })
    }
}

/// Whether `p` lies over one of `columns` (empty: every column).
fn wanted(columns: &[std::ops::Range<u32>], p: &Piece) -> bool {
    columns.is_empty() || columns.iter().any(|c| c.start < p.x + p.w && p.x < c.end)
}

/// `columns` (of the mosaic) as columns of `p`'s source, clipped to its window.
fn source_columns(columns: &[std::ops::Range<u32>], p: &Piece) -> Vec<std::ops::Range<u32>> {
    columns
        .iter()
        .filter_map(|c| {
            let (a, b) = (c.start.max(p.x), c.end.min(p.x + p.w));
            (a < b).then(|| a - p.x + p.src_x..b - p.x + p.src_x)
        })
        .collect()
}

/// Row `until` of the mosaic as a row of `p`'s source (`u32::MAX`: none).
fn source_until(until: u32, p: &Piece) -> u32 {
    if until == u32::MAX {
        return until;
    }
    until.clamp(p.y, p.y + p.h) - p.y + p.src_y
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
                if self.wanted(i) {
                    self.open_at(i, 0)?;
                }
                self.next_open += 1;
            }
            out_row.fill(f32::NAN);
            if let Some((band, cell)) = self.feather {
                self.read_feathered_row(out_row, band, cell)?;
            } else {
                self.read_row(out_row)?;
            }
            // Drop the inputs whose bottom row this was.
            let pieces = &self.pieces;
            self.open
                .retain(|o| pieces[o.index].y + pieces[o.index].h > r + 1);
            self.row += 1;
        }
        Ok(())
    }

    fn skip_rows(&mut self, n: u32) -> anyhow::Result<()> {
        let target = self.row + n;
        if target > self.info.height {
            bail!("skipped past the mosaic's last row");
        }
        let pieces = &self.pieces;
        self.open
            .retain(|o| pieces[o.index].y + pieces[o.index].h > target);
        for o in &mut self.open {
            o.reader
                .skip_rows(n)
                .with_context(|| pieces[o.index].name.clone())?;
        }
        // Inputs whose top row is skipped are opened (and skipped to `target`) only
        // if they reach past it and lie over a column read.
        while let Some(&i) = self.by_top.get(self.next_open)
            && self.pieces[i].y < target
        {
            let p = &self.pieces[i];
            if p.y + p.h > target && self.wanted(i) {
                self.open_at(i, target - p.y)?;
            }
            self.next_open += 1;
        }
        self.row = target;
        Ok(())
    }

    fn set_window(&mut self, columns: &[std::ops::Range<u32>], until: u32) -> anyhow::Result<()> {
        if self.columns == columns && self.until == until {
            return Ok(());
        }
        self.columns = columns.to_vec();
        self.until = until;
        let pieces = &self.pieces;
        let cols = &self.columns;
        self.open.retain(|o| wanted(cols, &pieces[o.index]));
        for o in &mut self.open {
            let p = &pieces[o.index];
            o.reader
                .set_window(&source_columns(cols, p), source_until(until, p))
                .with_context(|| p.name.clone())?;
        }
        // Inputs passed over while they lay outside the columns, wanted now: opened
        // at the current row.
        let late: Vec<usize> = (0..self.next_open)
            .map(|k| self.by_top[k])
            .filter(|&i| {
                let p = &self.pieces[i];
                p.y + p.h > self.row
                    && wanted(&self.columns, p)
                    && !self.open.iter().any(|o| o.index == i)
            })
            .collect();
        for i in late {
            self.open_at(i, self.row - self.pieces[i].y)?;
        }
        Ok(())
    }

    fn input_windows(&self) -> Vec<(PathBuf, [u32; 4])> {
        self.pieces
            .iter()
            .map(|p| (p.path.clone(), [p.x, p.y, p.w, p.h]))
            .collect()
    }

    fn buffer_bytes(&self) -> u64 {
        self.buffer_bytes + self.feather.map_or(0, |_| u64::from(self.info.width) * 16)
    }

    fn vertical_datum(&self) -> Option<VerticalDatum> {
        self.datum.as_ref().and_then(|c| c.datum)
    }

    fn datum_clue(&self) -> Option<DatumClue> {
        self.datum.clone()
    }
}

impl Mosaic {
    /// Reads row `self.row` of every open piece into `out_row` by the overlap rule.
    fn read_row(&mut self, out_row: &mut [f32]) -> anyhow::Result<()> {
        let r = self.row;
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
                    Overlap::First | Overlap::Finest => {}
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
        Ok(())
    }
}

mod conflict;
mod datum;
mod feather;
mod opening;
mod place;
mod summary;
#[cfg(test)]
mod tests;
pub mod warp;

pub use warp::GridOptions;
