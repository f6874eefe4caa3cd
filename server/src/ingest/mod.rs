//! DEM inputs. Every file format is read as a stream of rows, top to bottom, so
//! a DEM never has to fit in memory (docs/ARCHITECTURE.md#building-out-of-core); the
//! synthetic terrain is instead generated on demand for any window.

pub mod assign;
pub mod geotiff;
pub mod hgt;
pub mod inputs;
pub mod mosaic;
pub mod png16;
pub mod raster;
pub mod remote;
pub mod reproject;
pub mod synthetic;
pub mod vertical_shift;
pub mod vrt;

pub use inputs::InputSpec;
pub use mosaic::{GridOptions, Mosaic, MosaicOptions, Overlap};

use anyhow::{Context, bail};
use std::path::{Path, PathBuf};
use tessera_shared::GeoRef;

/// File extensions a directory's DEM files have. `.vrt` is left out: a folder holding
/// tiles and a VRT of them would list every tile twice.
pub const DEM_EXTENSIONS: &[&str] = &["tif", "tiff", "hgt", "png"];

/// The sample type of an input raster.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleType {
    Int16,
    UInt16,
    Float32,
}

impl SampleType {
    /// Integer samples are stored exactly (quantization error 0).
    pub const fn is_integer(self) -> bool {
        matches!(self, Self::Int16 | Self::UInt16)
    }

    pub const fn name(self) -> &'static str {
        match self {
            Self::Int16 => "int16",
            Self::UInt16 => "uint16",
            Self::Float32 => "float32",
        }
    }
}

/// What a row source knows about its raster before reading any sample.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceInfo {
    pub width: u32,
    pub height: u32,
    pub sample_type: SampleType,
    /// The raw value that marks a missing sample, if the format declares one.
    /// (NaN samples are always treated as missing.)
    pub nodata: Option<f64>,
    pub georef: Option<GeoRef>,
    /// A short description for the metadata, e.g. "GeoTIFF int16, LZW, tiled 256×256".
    pub description: String,
}

/// Memory the default [`RowSource::skip_rows`] reads rows into.
const SKIP_BUFFER: usize = 4 << 20;

/// A raster read as rows, top (north) to bottom.
pub trait RowSource: Send + std::fmt::Debug {
    fn info(&self) -> &SourceInfo;

    /// Fills `out` with the next `out.len() / width` rows as raw sample values
    /// (before any `--scale`/`--offset`). `out.len()` is a whole number of rows.
    /// Errors describe the problem (e.g. "truncated TIFF: strip 7 ends past the end
    /// of the file"); the caller adds the file name.
    fn read_rows(&mut self, out: &mut [f32]) -> anyhow::Result<()>;

    /// Passes over the next `n` rows without returning them (a part of a distributed
    /// build reads only its share). Readers that can jump ahead (a tiled GeoTIFF, a
    /// mosaic, which opens only the inputs it still needs) do; the default reads the
    /// rows and drops them.
    fn skip_rows(&mut self, n: u32) -> anyhow::Result<()> {
        let w = self.info().width as usize;
        let per = (SKIP_BUFFER / (4 * w)).max(1);
        let mut buf = vec![0f32; per.min(n as usize) * w];
        let mut left = n as usize;
        while left > 0 {
            let k = per.min(left);
            self.read_rows(&mut buf[..k * w])?;
            left -= k;
        }
        Ok(())
    }

    /// What the caller reads next: of the rows before row `until`, the columns
    /// `columns` (sorted, disjoint ranges); samples outside them may hold anything. A
    /// hint: a tiled GeoTIFF then fetches and decodes only the tiles under them and
    /// fetches nothing ahead past `until`, a mosaic opens only the inputs under them.
    /// The default reads every column.
    fn set_window(&mut self, _columns: &[std::ops::Range<u32>], _until: u32) -> anyhow::Result<()> {
        Ok(())
    }

    /// For a reader that resamples another grid: for each sample of the last row
    /// read, its distance (in source samples) to the source grid's outer edge, which a
    /// mosaic feathers seams by (`--feather`). Others keep the default.
    fn edge_distance(&self) -> Option<&[f32]> {
        None
    }

    /// The files a mosaic is read from and each one's window on its grid, `[x, y,
    /// width, height]` (`build --state`). Others keep the default: none, and the
    /// build names its one input itself.
    fn input_windows(&self) -> Vec<(PathBuf, [u32; 4])> {
        Vec::new()
    }

    /// Bytes the reader itself holds while reading (decoded bands, chunk buffers),
    /// for the build's memory plan. Small row-at-a-time readers keep the default.
    fn buffer_bytes(&self) -> u64 {
        0
    }

    /// What the heights are measured from, when the format says (SRTM: EGM96).
    fn vertical_datum(&self) -> Option<tessera_shared::VerticalDatum> {
        None
    }

    /// What the input says about its vertical datum and where it says it, for the
    /// build's log: a GeoTIFF's GeoKeys, GDAL metadata or product file name
    /// ([`geotiff`]'s `vertical` module). Readers that only know a datum from their
    /// format keep the default, which names no more than that.
    fn datum_clue(&self) -> Option<DatumClue> {
        self.vertical_datum().map(|d| DatumClue {
            datum: Some(d),
            why: format!("the input's format gives {}", d.name()),
        })
    }
}

/// What an input states about the reference its heights are measured from, and how
/// it knows ([`RowSource::datum_clue`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DatumClue {
    /// The datum; `None` when the input names one the metadata cannot record
    /// (NAVD88, DTED's EGM84-based "MSL"), so the heights stay `unknown`.
    pub datum: Option<tessera_shared::VerticalDatum>,
    /// Where it is stated: "GeoTIFF GDAL metadata DTED_VerticalDatum=E96", "file name
    /// matches USGS SRTM GeoTIFF"; for a `None` datum, what was named instead.
    pub why: String,
}

/// One input as its header describes it, for the pyramid's provenance
/// (`builder::provenance`).
#[derive(Clone, Debug)]
pub struct InputSummary {
    /// The file name (without its folder).
    pub name: String,
    pub georef: Option<GeoRef>,
    pub width: u32,
    pub height: u32,
    /// What its heights are measured from, as the build reads it.
    pub datum: Option<tessera_shared::VerticalDatum>,
}

/// An input's window on the mosaic's grid (the pyramid's finest), `[x0, y0, x1, y1)`
/// in samples, and the metres one of its own samples spans (geometric mean of its two
/// spacings): what a multi-resolution pyramid stores it down to
/// (`builder::support`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Coverage {
    pub window: [u32; 4],
    pub metres: f64,
}

/// A parsed `INPUT` argument.
#[derive(Debug)]
pub enum Input {
    Rows(Box<dyn RowSource>),
    Synthetic(synthetic::Synthetic),
}

/// An opened input and how to name it.
#[derive(Debug)]
pub struct Opened {
    pub input: Input,
    /// How build errors name it: the argument as given, or "mosaic of 16 inputs".
    pub label: String,
    /// What the metadata's `source` names: the file, or the first file and the count.
    pub source_name: String,
    /// Inputs on different grids, resampled onto one (`--to` and `--spacing`, if
    /// given, are done).
    pub resampled: bool,
    /// A [`Mosaic`] (of files, or a VRT's sources): each input's vertical datum is
    /// settled and converted inside it.
    pub mosaic: bool,
    /// Each input (file or VRT) of a mosaic, in priority order; empty for one input
    /// (the caller describes it once it is georeferenced).
    pub inputs: Vec<InputSummary>,
    /// Where inputs on different grids lie and how fine each is (empty otherwise).
    pub coverage: Vec<Coverage>,
}

/// Opens what `build` was asked to read: one file (read exactly as before mosaics),
/// a synthetic terrain, or a [`Mosaic`] of several files or a VRT, on their shared
/// grid or, when they are on different grids, resampled onto one
/// ([`mosaic::warp`]). `opts` gives the no-data override, the overlap rule and the
/// target grid's options.
pub fn open_inputs(spec: &InputSpec, opts: &MosaicOptions) -> anyhow::Result<Opened> {
    let files = match inputs::expand(spec)? {
        inputs::Expanded::Synthetic(s) => {
            return Ok(Opened {
                input: open(&s)?,
                source_name: file_name(&s),
                label: s,
                resampled: false,
                mosaic: false,
                inputs: Vec::new(),
                coverage: Vec::new(),
            });
        }
        inputs::Expanded::Files(files) => files,
    };
    if let [one] = files.as_slice()
        && !vrt::is_vrt(one)
    {
        let label = one.display().to_string();
        return Ok(Opened {
            input: open(&label)?,
            source_name: file_name(&label),
            label,
            resampled: false,
            mosaic: false,
            inputs: Vec::new(),
            coverage: Vec::new(),
        });
    }
    let mosaic = Mosaic::open_with(&files, opts, open_raster)?;
    Ok(Opened {
        label: mosaic.label().to_string(),
        source_name: mosaic.source_name().to_string(),
        resampled: mosaic.resampled(),
        mosaic: true,
        inputs: mosaic.inputs().to_vec(),
        coverage: mosaic.coverage(),
        input: Input::Rows(Box::new(mosaic)),
    })
}

/// The file name of an input argument, for the metadata.
pub fn file_name(input: &str) -> String {
    Path::new(input)
        .file_name()
        .map_or_else(|| input.to_string(), |n| n.to_string_lossy().into_owned())
}

/// Opens an input by name: `synthetic:SIZE[:SEED]`, a GDAL VRT (as a [`Mosaic`] of its
/// sources), or a file whose format is found from its content (TIFF and PNG
/// signatures) or, for SRTM, its `.hgt` name.
pub fn open(input: &str) -> anyhow::Result<Input> {
    if let Some(spec) = input.strip_prefix("synthetic:") {
        return Ok(Input::Synthetic(
            synthetic::Synthetic::parse(spec).with_context(|| {
                format!("{input}: bad synthetic terrain spec (want synthetic:SIZE[:SEED])")
            })?,
        ));
    }
    let path = PathBuf::from(input);
    if vrt::is_vrt(&path) {
        let mosaic = Mosaic::open(&[path], None, Overlap::default(), open_raster)?;
        return Ok(Input::Rows(Box::new(mosaic)));
    }
    let (source, _) = open_raster(&path).with_context(|| path.display().to_string())?;
    Ok(Input::Rows(source))
}

/// What kind of file `meta` describes, when it is not a regular file.
fn special_kind(meta: &std::fs::Metadata) -> Option<&'static str> {
    use std::os::unix::fs::FileTypeExt;
    let t = meta.file_type();
    if t.is_file() {
        None
    } else if t.is_dir() {
        Some("a directory")
    } else if t.is_fifo() {
        Some("a FIFO (named pipe)")
    } else if t.is_socket() {
        Some("a socket")
    } else if t.is_char_device() {
        Some("a character device")
    } else if t.is_block_device() {
        Some("a block device")
    } else {
        Some("not a regular file")
    }
}

/// Opens an input file for reading, refusing anything but a regular file (a symlink
/// to one is fine) before reading a byte: opening a FIFO for reading waits for a
/// writer (a `tiles.vrt` that is a pipe blocked `build` forever), and a device,
/// socket or directory is no DEM. The file is opened non-blocking and checked again
/// once open, so one swapped for a pipe in between cannot block either. Errors say
/// what the path is; callers name the file.
pub fn open_regular(path: &Path) -> anyhow::Result<(std::fs::File, std::fs::Metadata)> {
    use std::os::unix::fs::OpenOptionsExt;
    let refuse = |kind: &str| {
        anyhow::anyhow!(
            "is {kind}, not a regular file: inputs are read from regular files (or symlinks to them)"
        )
    };
    let meta = std::fs::metadata(path).context("cannot read input")?;
    if let Some(kind) = special_kind(&meta) {
        return Err(refuse(kind));
    }
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(rustix::fs::OFlags::NONBLOCK.bits() as i32)
        .open(path)
        .context("cannot open")?;
    let meta = file.metadata().context("cannot read input")?;
    if let Some(kind) = special_kind(&meta) {
        return Err(refuse(kind));
    }
    Ok((file, meta))
}

/// Opens a raster file (not a VRT): its reader and its format's name. A file that
/// states a geotransform but no CRS takes one from a `.prj` beside it
/// ([`sidecar_crs`]).
pub fn open_raster(path: &Path) -> anyhow::Result<(Box<dyn RowSource>, &'static str)> {
    if let Some(url) = remote::url_of(path) {
        return remote::open_raster(url);
    }
    let (reader, format) = open_raster_file(path)?;
    Ok((sidecar_crs(reader, path)?, format))
}

/// The largest `.prj` read: a WKT is a few kilobytes.
const MAX_PRJ_BYTES: u64 = 1 << 20;

/// ESRI's `.prj` sidecar (`dem.prj` beside `dem.tif`; one WKT, often ESRI's dialect),
/// for an input whose own file has a geotransform but names no CRS PROJ can read.
/// GDAL reads `.prj` for ESRI's formats; we read it for every format, since a
/// GeoTIFF or world-file PNG without CRS keys next to one means just that. A `.prj`
/// PROJ cannot read is an error naming it: a silently ignored CRS would misplace the
/// DEM.
pub fn sidecar_crs(reader: Box<dyn RowSource>, path: &Path) -> anyhow::Result<Box<dyn RowSource>> {
    let Some(g) = reader.info().georef.as_ref() else {
        return Ok(reader);
    };
    if g.epsg.is_some() || g.proj.is_some() || g.wkt.is_some() {
        return Ok(reader);
    }
    let Some(prj) = ["prj", "PRJ"]
        .iter()
        .map(|e| path.with_extension(e))
        .find(|p| p.is_file())
    else {
        return Ok(reader);
    };
    let name = prj.display().to_string();
    let len = std::fs::metadata(&prj).with_context(|| name.clone())?.len();
    if len > MAX_PRJ_BYTES {
        bail!("{name}: {len} bytes is too large for a .prj (a WKT is a few kilobytes)");
    }
    let text = std::fs::read_to_string(&prj).with_context(|| format!("{name}: cannot read"))?;
    let crs = crate::crs::Crs::from_definition(&text)
        .with_context(|| format!("{name}: PROJ cannot read this .prj as a CRS"))?;
    tracing::info!(input = %path.display(), crs = crs.label(), "CRS from the .prj sidecar");
    assign::assign(reader, Some(&crs), None, &path.display().to_string())
}

fn open_raster_file(path: &Path) -> anyhow::Result<(Box<dyn RowSource>, &'static str)> {
    let (mut file, meta) = open_regular(path)?;
    if meta.len() == 0 {
        bail!("input file is empty");
    }
    let mut magic = [0u8; 8];
    let n = std::io::Read::read(&mut file, &mut magic)?;
    let magic = &magic[..n];
    let is_hgt = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("hgt"));
    Ok(
        if magic.starts_with(b"II*\0")
            || magic.starts_with(b"MM\0*")
            || magic.starts_with(b"II+\0")
            || magic.starts_with(b"MM\0+")
        {
            (Box::new(geotiff::GeoTiff::open(path)?), "GeoTIFF")
        } else if magic.starts_with(b"\x89PNG\r\n\x1a\n") {
            (Box::new(png16::Png16::open(path)?), "PNG")
        } else if is_hgt {
            (Box::new(hgt::Hgt::open(path)?), "SRTM .hgt")
        } else {
            bail!(
                "unrecognised input format (expected a GeoTIFF, a 16-bit grayscale PNG, an SRTM .hgt file, a GDAL .vrt or synthetic:SIZE)"
            );
        },
    )
}
