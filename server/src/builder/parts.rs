//! The distributed build (issue 16, DESIGN §9): `build INPUT --part K/N -o PARTS/`
//! builds the subtrees of one slice of the split level's Morton codes into a part
//! file, and `build --assemble PARTS/ -o OUT.tess` writes the levels above the split
//! from the parts' roots and then the pyramid, byte for byte the file a single
//! `build` of the same input and options writes (FORMAT.md "Part files",
//! DECISIONS "Distributed build").
//!
//! - **Split.** The split level `S` is the smallest with `4^S ≥ 4N` (four subtrees
//!   a part at least, so the slices can be balanced), at least 1 and at most the
//!   finest. Part `K` gets a contiguous run of level-`S` Morton codes, cut so the
//!   parts hold about as many present finest tiles each ([`Split`]). A subtree is
//!   one contiguous Morton range at every level below `S`, so the pyramid's levels
//!   `≥ S` are the parts' records concatenated in part order.
//! - **Same numbers everywhere.** Every part reads (spools) the whole input, so its
//!   quantization and no-data fill are the single build's: the input is read `N`
//!   times, the known cost of this design. It then cuts and encodes only its own
//!   finest tiles, through the same code as a whole build ([`super::Tiling`]).
//! - **Counts.** A part records its share of the DEM-wide numbers: the samples its
//!   level-`S` tiles own, by depth, valid and filled ([`share`]), and the range of
//!   its finest records' heights. Assembling adds and bounds them exactly as the
//!   whole build counts them.
//! - **Safety.** A part file is written beside its final name and renamed into
//!   place only when complete and re-read, so a part that died leaves nothing under
//!   its name and is simply rerun. Assembling refuses a missing part, a duplicate, a
//!   part of another `N` or of other input or options (a fingerprint of the input's
//!   samples, metadata and options), and a truncated or corrupt one (header and
//!   trailer checksum, per-record and per-root checksums), naming the file.

use super::coarse::Aggregator;
use super::writer::{SINK_BUFFER, partial_prefix, publish, remove_stale_partials};
use super::{
    BuildOptions, BuildReport, Loaded, Node, Sink, Tiling, bar, count_tiles, create_output,
    finish_output, level_counts, memory, meta_reserve,
};
use crate::ingest::raster::{DepthCounts, Raster, depth};
use crate::ingest::{self, RowSource, SourceInfo};
use anyhow::{Context, bail, ensure};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::ops::Range;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::time::Instant;
use tempfile::NamedTempFile;
use tessera_shared::format::{self, INDEX_ENTRY_LEN, IndexEntry};
use tessera_shared::{CellMask, Level, Metadata, Morton, TileGeometry, TileId};
use xxhash_rust::xxh3::Xxh3;

use super::mesh_error::BlockErrors;

/// Part files end in `.tesspart`.
pub const EXTENSION: &str = "tesspart";
/// First bytes of a part file.
pub const MAGIC: [u8; 8] = *b"TESSPART";
/// Part file format version (FORMAT.md "Part files").
pub const VERSION: u32 = 1;
/// Fixed header at the start of a part file.
pub const HEADER_LEN: usize = 64;
/// The frame before each record: Morton code, length and index summary.
pub const FRAME_LEN: usize = INDEX_ENTRY_LEN;
/// Most parts one build may have (a Kubernetes Indexed Job's completions are
/// limited to about this many).
pub const MAX_PARTS: u32 = 100_000;
/// Bound on a trailer (its metadata's CRS texts are the only variable part).
const MAX_TRAILER: u64 = 16 << 20;
/// Write buffer of the split-level roots.
const ROOTS_BUFFER: usize = 256 << 10;

/// Which part of how many (`--part K/N`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PartSpec {
    pub k: u32,
    pub n: u32,
}

impl PartSpec {
    /// Parses `K/N`, or `/N` with `K` from `index` (the `JOB_COMPLETION_INDEX` a
    /// Kubernetes Indexed Job sets in each pod). An explicit `K` wins.
    pub fn parse(spec: &str, index: Option<&str>) -> anyhow::Result<Self> {
        let (k, n) = spec
            .split_once('/')
            .with_context(|| format!("--part {spec}: expected K/N (e.g. 3/16) or /N"))?;
        let n: u32 = n
            .trim()
            .parse()
            .ok()
            .filter(|n| (1..=MAX_PARTS).contains(n))
            .with_context(|| {
                format!("--part {spec}: N must be a whole number from 1 to {MAX_PARTS}")
            })?;
        let k: u32 = if k.trim().is_empty() {
            let index = index.with_context(|| {
                format!(
                    "--part {spec} gives no K: write --part K/{n}, or set JOB_COMPLETION_INDEX \
                     (a Kubernetes Indexed Job sets it in each pod)"
                )
            })?;
            index.trim().parse().with_context(|| {
                format!("JOB_COMPLETION_INDEX={index:?} (for --part {spec}) is not a whole number")
            })?
        } else {
            k.trim()
                .parse()
                .with_context(|| format!("--part {spec}: K is not a whole number"))?
        };
        ensure!(
            k < n,
            "--part {k}/{n}: K counts from 0, so it must be below N (0 to {})",
            n - 1
        );
        Ok(Self { k, n })
    }

    /// The part's file name in the parts folder: `part-KKKK-of-NNNN.tesspart`.
    pub fn file_name(&self) -> String {
        format!("part-{:04}-of-{:04}.{EXTENSION}", self.k, self.n)
    }
}

/// How `N` parts divide a pyramid: the split level and each part's run of its
/// Morton codes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Split {
    pub level: Level,
    /// `cuts[K]..cuts[K + 1]` are part `K`'s codes; `N + 1` entries.
    cuts: Vec<u64>,
}

impl Split {
    /// The split for `n` parts: level `S` is the smallest with `4^S ≥ 4n`, clamped to
    /// `1..=finest` (0 for a one-tile pyramid); the cuts balance the present finest
    /// tiles under each part's codes (their work), a part taking whole subtrees.
    pub fn new(geometry: &TileGeometry, n: u32) -> Self {
        let finest = geometry.finest().get();
        let mut s = 1u8;
        while (1u64 << (2 * u32::from(s))) < 4 * u64::from(n) {
            s += 1;
        }
        let level = Level::new(s.min(finest)).expect("at most the finest level");
        let weights = tile_weights(geometry, level);
        let total: u64 = weights.iter().sum();
        let mut cuts = Vec::with_capacity(n as usize + 1);
        let (mut i, mut prefix) = (0usize, 0u64);
        for k in 0..u64::from(n) {
            // The first code whose prefix holds k/n of the work.
            while u128::from(prefix) * u128::from(n) < u128::from(k) * u128::from(total) {
                prefix += weights[i];
                i += 1;
            }
            cuts.push(i as u64);
        }
        cuts.push(level.tile_slots());
        Self { level, cuts }
    }

    /// Part `k`'s level-`S` Morton codes.
    pub fn tops(&self, k: u32) -> Range<u64> {
        self.cuts[k as usize]..self.cuts[k as usize + 1]
    }
}

/// Present finest tiles under each tile of `level`, in Morton order.
fn tile_weights(g: &TileGeometry, level: Level) -> Vec<u64> {
    let d = u32::from(g.finest().get() - level.get());
    let t = u64::from(g.tile_size());
    // Finest tile x is present iff x·T < W − 1.
    let (nx, ny) = (
        u64::from(g.width() - 1).div_ceil(t),
        u64::from(g.height() - 1).div_ceil(t),
    );
    let span = |i: u32, n: u64| n.min(u64::from(i + 1) << d) - n.min(u64::from(i) << d);
    (0..level.tile_slots())
        .map(|m| {
            let (x, y) = Morton::from_raw(m).decode();
            span(x, nx) * span(y, ny)
        })
        .collect()
}

/// The samples a present level-`level` tile owns: its `span × span` block of the
/// DEM from its origin, to the DEM's edge for the last tile of a row or column
/// (where the next tile would be absent). Every sample has exactly one owner.
fn owned(g: &TileGeometry, tile: TileId) -> Option<(Range<u32>, Range<u32>)> {
    if !g.is_present(tile) {
        return None;
    }
    let span = g.spacing(tile.level()) * u64::from(g.tile_size());
    let (x0, y0) = g.origin(tile);
    let end = |o: u64, size: u32| {
        if o + span >= u64::from(size - 1) {
            size
        } else {
            (o + span) as u32
        }
    };
    Some((
        x0 as u32..end(x0, g.width()),
        y0 as u32..end(y0, g.height()),
    ))
}

/// Samples per depth in `xs × ys`, all counted valid.
fn rect_depths(xs: &Range<u32>, ys: &Range<u32>) -> DepthCounts {
    // Multiples of 2^d in a range (d = 32 counts 0 alone, as depth() does).
    let on = |r: &Range<u32>, d: u32| {
        let s = 1u64 << d;
        u64::from(r.end).div_ceil(s) - u64::from(r.start).div_ceil(s)
    };
    let mut c = [[0u64; 2]; 33];
    for d in 0..33u32 {
        let here = on(xs, d) * on(ys, d);
        let deeper = if d == 32 {
            0
        } else {
            on(xs, d + 1) * on(ys, d + 1)
        };
        c[d as usize][0] = here - deeper;
    }
    c
}

/// Samples of a row whose validity is read at once.
const VALIDITY_CHUNK: u32 = 1 << 16;

/// A part's share of the DEM's depth counts ([`Raster::depth_counts`]): the
/// samples its level-`level` tiles `tops` own, valid and filled. The parts' shares
/// add up to the whole raster's counts.
pub(super) fn share(
    raster: &dyn Raster,
    g: &TileGeometry,
    level: Level,
    tops: Range<u64>,
) -> anyhow::Result<DepthCounts> {
    let mut counts = [[0u64; 2]; 33];
    let mut valid = Vec::new();
    for m in tops {
        let tile = TileId::from_morton(level, Morton::from_raw(m)).expect("m < 4^S");
        let Some((xs, ys)) = owned(g, tile) else {
            continue;
        };
        for (c, r) in counts.iter_mut().zip(rect_depths(&xs, &ys)) {
            c[0] += r[0];
        }
        if !raster.has_nodata() {
            continue;
        }
        for y in ys.clone() {
            let mut x = xs.start;
            while x < xs.end {
                let w = VALIDITY_CHUNK.min(xs.end - x);
                valid.resize(w as usize, false);
                raster.read_validity(x, y, w, 1, &mut valid)?;
                for (i, _) in valid.iter().enumerate().filter(|(_, v)| !**v) {
                    let d = depth(x + i as u32, y);
                    counts[d][0] -= 1;
                    counts[d][1] += 1;
                }
                x += w;
            }
        }
    }
    Ok(counts)
}

/// A row source that hashes every raw sample it hands on (its bits, little-endian):
/// a part's fingerprint of its input's content.
pub(super) struct Digesting<'a> {
    inner: &'a mut dyn RowSource,
    hash: &'a mut Xxh3,
}

impl<'a> Digesting<'a> {
    pub(super) fn new(inner: &'a mut dyn RowSource, hash: &'a mut Xxh3) -> Self {
        Self { inner, hash }
    }
}

impl std::fmt::Debug for Digesting<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Digesting")
            .field("inner", &self.inner)
            .finish_non_exhaustive()
    }
}

impl RowSource for Digesting<'_> {
    fn info(&self) -> &SourceInfo {
        self.inner.info()
    }

    fn read_rows(&mut self, out: &mut [f32]) -> anyhow::Result<()> {
        self.inner.read_rows(out)?;
        let mut bytes = [0u8; 4 << 12];
        for chunk in out.chunks(1 << 12) {
            for (b, v) in bytes.chunks_exact_mut(4).zip(chunk) {
                b.copy_from_slice(&v.to_bits().to_le_bytes());
            }
            self.hash.update(&bytes[..4 * chunk.len()]);
        }
        Ok(())
    }

    fn buffer_bytes(&self) -> u64 {
        self.inner.buffer_bytes()
    }

    fn vertical_datum(&self) -> Option<tessera_shared::VerticalDatum> {
        self.inner.vertical_datum()
    }
}

/// What a part build did.
#[derive(Clone, Debug)]
pub struct PartReport {
    pub path: PathBuf,
    pub spec: PartSpec,
    pub split: Level,
    /// The part's level-`split` Morton codes.
    pub tops: Range<u64>,
    /// Records written (levels `split..=finest`).
    pub records: u64,
    pub file_bytes: u64,
    pub seconds: f64,
    /// As [`BuildReport::warnings`].
    pub warnings: Vec<String>,
}

/// Builds part `spec` of `inputs` into `dir` (created if missing) as
/// `dir/part-KKKK-of-NNNN.tesspart`, replacing an earlier file of that name only
/// once the new one is complete. The input is spooled in the temporary folder
/// (`TMPDIR`), not in `dir`.
pub fn build_part(
    inputs: &ingest::InputSpec,
    dir: &Path,
    spec: PartSpec,
    opts: &BuildOptions,
) -> anyhow::Result<PartReport> {
    let started = Instant::now();
    ensure!(
        !dir.to_string_lossy().contains("://"),
        "{}: --part writes its part file into a local (or mounted) folder; an object URL \
         is for the pyramid itself (-o of a whole build or of --assemble)",
        dir.display()
    );
    if !dir.is_dir() {
        ensure!(
            !dir.exists(),
            "{}: --part writes a part file into a folder, and this is a file",
            dir.display()
        );
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create the parts folder {}", dir.display()))?;
    }
    // The input is spooled (and reprojected) in TMPDIR, node-local scratch in an
    // Indexed Job: N parts would otherwise put N copies of it on the shared folder.
    let scratch = std::env::temp_dir();
    let folders = super::plausible::Folders {
        spool: scratch.clone(),
        output: dir.to_path_buf(),
    };
    let prepared = super::prepare(inputs, &folders, spec.n, opts)?;
    let warnings = prepared.warnings.clone();
    let geometry = prepared.geometry;
    let split = Split::new(&geometry, spec.n);
    let tops = split.tops(spec.k);
    let reserve = meta_reserve(&prepared.meta);
    let target = dir.join(spec.file_name());
    let mut writer = PartWriter::create(&target, spec, &geometry, split.level, tops.clone())?;
    let mut digest = Xxh3::new();
    let loaded = prepared.load(&scratch, opts, started, Some(&mut digest))?;
    let raster = loaded.dem.raster();
    let subtree_tiles: u64 = (split.level.get()..=geometry.finest().get())
        .map(|l| {
            let level = Level::new(l).expect("a level of the pyramid");
            let depth = 2 * u32::from(l - split.level.get());
            (tops.start << depth..tops.end << depth)
                .filter(|&m| {
                    geometry.is_present(TileId::from_morton(level, Morton::from_raw(m)).expect("m"))
                })
                .count() as u64
        })
        .sum();
    let tiles_bar = bar(opts.progress, subtree_tiles, "tiling");
    let tiling = Tiling {
        raster,
        geometry,
        quant: loaded.meta.quantization,
        plan: loaded.plan,
        opts,
        bar: &tiles_bar,
    };
    let (min_q, max_q) = tiling.subtrees(&mut writer, split.level, tops.clone())?;
    tiles_bar.finish_and_clear();
    let depths = share(raster, &geometry, split.level, tops.clone())?;
    let trailer = Trailer {
        fingerprint: fingerprint(&loaded, opts, reserve, digest.digest()),
        tops: tops.clone(),
        meta_reserve: reserve,
        spacings: spacings(&geometry),
        min_q,
        max_q,
        nodata: depths.iter().map(|d| d[1]).sum(),
        depths,
        sections: Vec::new(),
        roots: Section::default(),
        meta: loaded.meta.clone(),
    };
    let records = writer.records();
    let file_bytes = writer
        .finish(trailer, &opts.interrupt)
        .with_context(|| format!("cannot finish {}", target.display()))?;
    tracing::debug!(
        seconds = started.elapsed().as_secs_f64(),
        part = %target.display(),
        "part written and verified"
    );
    Ok(PartReport {
        path: target,
        spec,
        split: split.level,
        tops,
        records,
        file_bytes,
        seconds: started.elapsed().as_secs_f64(),
        warnings,
    })
}

/// Mesh spacings a node's block errors hold: `t + L_max + 1`.
fn spacings(g: &TileGeometry) -> u32 {
    g.tile_log2() + u32::from(g.finest().get()) + 1
}

/// A digest of everything that shapes the pyramid's bytes: the metadata (size, tile
/// size, quantization, CRS, source, generator), the input's raw samples, the
/// options, and for an input with no-data the band height its fill used
/// (`--memory` sets it).
fn fingerprint(loaded: &Loaded, opts: &BuildOptions, reserve: u64, digest: u64) -> [u8; 16] {
    let mut h = Xxh3::new();
    h.update(b"tessera part fingerprint 1\0");
    h.update(&format::encode_metadata(&loaded.meta));
    h.update(&reserve.to_le_bytes());
    h.update(&digest.to_le_bytes());
    let raster = loaded.dem.raster();
    for [v, f] in raster.depth_counts() {
        h.update(&v.to_le_bytes());
        h.update(&f.to_le_bytes());
    }
    h.update(&[u8::from(raster.has_nodata())]);
    if raster.has_nodata() {
        h.update(&(loaded.plan.band_bytes as u64).to_le_bytes());
    }
    h.update(&opts.scale.to_bits().to_le_bytes());
    h.update(&opts.offset.to_bits().to_le_bytes());
    h.update(&opts.nodata.map_or(u64::MAX, f64::to_bits).to_le_bytes());
    h.update(format!("{:?}", opts.overlap).as_bytes());
    h.digest128().to_le_bytes()
}

/// Where one run of bytes lies in a part file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Section {
    offset: u64,
    len: u64,
    /// Records (a level's section) or roots (the roots' section).
    count: u64,
}

/// A part file's fixed header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Header {
    n: u32,
    k: u32,
    split: u8,
    finest: u8,
    trailer_offset: u64,
    trailer_len: u64,
    file_len: u64,
    checksum: u64,
}

impl Header {
    fn to_bytes(self) -> [u8; HEADER_LEN] {
        let mut b = [0u8; HEADER_LEN];
        b[0..8].copy_from_slice(&MAGIC);
        b[8..12].copy_from_slice(&VERSION.to_le_bytes());
        b[16..20].copy_from_slice(&self.n.to_le_bytes());
        b[20..24].copy_from_slice(&self.k.to_le_bytes());
        b[24] = self.split;
        b[25] = self.finest;
        b[32..40].copy_from_slice(&self.trailer_offset.to_le_bytes());
        b[40..48].copy_from_slice(&self.trailer_len.to_le_bytes());
        b[48..56].copy_from_slice(&self.file_len.to_le_bytes());
        b[56..64].copy_from_slice(&self.checksum.to_le_bytes());
        b
    }

    fn parse(b: &[u8; HEADER_LEN]) -> anyhow::Result<Self> {
        ensure!(
            b[0..8] == MAGIC,
            "not a Tessera part file (its first bytes are not {:?})",
            String::from_utf8_lossy(&MAGIC)
        );
        let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().expect("4 bytes"));
        let u64_at = |o: usize| u64::from_le_bytes(b[o..o + 8].try_into().expect("8 bytes"));
        let version = u32_at(8);
        ensure!(
            version == VERSION,
            "part file version {version}; this tessera-server reads version {VERSION}"
        );
        Ok(Self {
            n: u32_at(16),
            k: u32_at(20),
            split: b[24],
            finest: b[25],
            trailer_offset: u64_at(32),
            trailer_len: u64_at(40),
            file_len: u64_at(48),
            checksum: u64_at(56),
        })
    }

    /// XXH3-64 of header bytes 0..56 followed by the trailer.
    fn compute_checksum(&self, trailer: &[u8]) -> u64 {
        let mut h = Xxh3::new();
        h.update(&self.to_bytes()[..56]);
        h.update(trailer);
        h.digest()
    }
}

/// A part file's trailer: what assembling needs besides the records and roots.
#[derive(Clone, Debug, PartialEq)]
struct Trailer {
    fingerprint: [u8; 16],
    tops: Range<u64>,
    meta_reserve: u64,
    spacings: u32,
    /// Range of the part's finest records' quantized heights (`u16::MAX, 0`: none).
    min_q: u16,
    max_q: u16,
    /// The part's share of the no-data samples (the sum of `depths`' filled counts).
    nodata: u64,
    depths: DepthCounts,
    /// One per level from the split level to the finest.
    sections: Vec<Section>,
    roots: Section,
    /// The pyramid's metadata but for its counts and content hash.
    meta: Metadata,
}

impl Trailer {
    fn to_bytes(&self, split: u8) -> Vec<u8> {
        let mut b = Vec::new();
        b.extend_from_slice(&self.fingerprint);
        b.extend_from_slice(&self.tops.start.to_le_bytes());
        b.extend_from_slice(&self.tops.end.to_le_bytes());
        b.extend_from_slice(&self.meta_reserve.to_le_bytes());
        b.extend_from_slice(&self.spacings.to_le_bytes());
        b.extend_from_slice(&self.min_q.to_le_bytes());
        b.extend_from_slice(&self.max_q.to_le_bytes());
        b.extend_from_slice(&self.nodata.to_le_bytes());
        for [v, f] in self.depths {
            b.extend_from_slice(&v.to_le_bytes());
            b.extend_from_slice(&f.to_le_bytes());
        }
        b.push(self.sections.len() as u8);
        for (i, s) in self.sections.iter().enumerate() {
            b.push(split + i as u8);
            for v in [s.offset, s.len, s.count] {
                b.extend_from_slice(&v.to_le_bytes());
            }
        }
        for v in [self.roots.offset, self.roots.len, self.roots.count] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        let meta = format::encode_metadata(&self.meta);
        b.extend_from_slice(&(meta.len() as u32).to_le_bytes());
        b.extend_from_slice(&meta);
        b
    }

    fn parse(bytes: &[u8], split: u8) -> anyhow::Result<Self> {
        let mut r = Bytes(bytes);
        let fingerprint = r.take(16)?.try_into().expect("16 bytes");
        let tops = r.u64()?..r.u64()?;
        let meta_reserve = r.u64()?;
        let spacings = r.u32()?;
        let (min_q, max_q) = (r.u16()?, r.u16()?);
        let nodata = r.u64()?;
        let mut depths = [[0u64; 2]; 33];
        for d in &mut depths {
            *d = [r.u64()?, r.u64()?];
        }
        let count = r.take(1)?[0];
        let mut sections = Vec::new();
        for i in 0..count {
            let level = r.take(1)?[0];
            ensure!(
                level == split.wrapping_add(i),
                "its trailer lists level {level} where level {} belongs",
                split.wrapping_add(i)
            );
            sections.push(Section {
                offset: r.u64()?,
                len: r.u64()?,
                count: r.u64()?,
            });
        }
        let roots = Section {
            offset: r.u64()?,
            len: r.u64()?,
            count: r.u64()?,
        };
        let meta_len = r.u32()? as usize;
        let meta = format::decode_metadata(r.take(meta_len)?)
            .map_err(|e| anyhow::anyhow!("its metadata does not decode: {e}"))?;
        ensure!(r.0.is_empty(), "its trailer has {} extra bytes", r.0.len());
        Ok(Self {
            fingerprint,
            tops,
            meta_reserve,
            spacings,
            min_q,
            max_q,
            nodata,
            depths,
            sections,
            roots,
            meta,
        })
    }
}

/// A bounds-checked little-endian reader.
struct Bytes<'a>(&'a [u8]);

impl<'a> Bytes<'a> {
    fn take(&mut self, n: usize) -> anyhow::Result<&'a [u8]> {
        ensure!(self.0.len() >= n, "its trailer ends early");
        let (a, b) = self.0.split_at(n);
        self.0 = b;
        Ok(a)
    }
    fn u16(&mut self) -> anyhow::Result<u16> {
        Ok(u16::from_le_bytes(self.take(2)?.try_into()?))
    }
    fn u32(&mut self) -> anyhow::Result<u32> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into()?))
    }
    fn u64(&mut self) -> anyhow::Result<u64> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into()?))
    }
}

/// The frame before each record: its Morton code, length and index summary.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Frame {
    m: u64,
    length: u32,
    min: u16,
    max: u16,
    checksum: u64,
    full_res_error: f32,
    flags: u32,
}

impl Frame {
    /// The pyramid index entry's layout (FORMAT.md), with the Morton code in the
    /// offset's place: one encoding for both.
    fn as_entry(self) -> IndexEntry {
        IndexEntry {
            offset: self.m,
            length: self.length,
            min: self.min,
            max: self.max,
            checksum: self.checksum,
            full_res_error: self.full_res_error,
            flags: self.flags,
        }
    }

    fn to_bytes(self) -> [u8; FRAME_LEN] {
        self.as_entry().to_bytes()
    }

    fn parse(b: &[u8; FRAME_LEN]) -> Self {
        let e = IndexEntry::parse(b);
        Self {
            m: e.offset,
            length: e.length,
            min: e.min,
            max: e.max,
            checksum: e.checksum,
            full_res_error: e.full_res_error,
            flags: e.flags,
        }
    }

    /// The index summary a pyramid writer takes (it fills in offset, length and
    /// checksum itself).
    fn summary(&self) -> IndexEntry {
        IndexEntry {
            min: self.min,
            max: self.max,
            full_res_error: self.full_res_error,
            flags: self.flags,
            ..IndexEntry::default()
        }
    }
}

/// One level's records as they are made.
struct Stream {
    out: BufWriter<File>,
    len: u64,
    records: u64,
}

/// A part being written: records stream to one file per level (the finest straight
/// into the part file, the others into unnamed spill files appended at the end), the
/// split level's nodes to a spill file of their own; then the trailer and header.
/// Nothing grows with the number of tiles.
struct PartWriter {
    target: PathBuf,
    partial: NamedTempFile,
    spec: PartSpec,
    split: Level,
    finest: Level,
    tops: Range<u64>,
    next_top: u64,
    /// Split level first.
    levels: Vec<Stream>,
    roots: BufWriter<File>,
    roots_len: u64,
    scratch: Vec<u8>,
}

impl PartWriter {
    fn create(
        target: &Path,
        spec: PartSpec,
        geometry: &TileGeometry,
        split: Level,
        tops: Range<u64>,
    ) -> anyhow::Result<Self> {
        let dir = target.parent().context("a part file has a folder")?;
        let name = spec.file_name();
        remove_stale_partials(dir, &name);
        let partial = tempfile::Builder::new()
            .prefix(&partial_prefix(&name, std::process::id()))
            .tempfile_in(dir)
            .with_context(|| format!("cannot create a file in {}", dir.display()))?;
        let finest = geometry.finest();
        let mut levels = Vec::new();
        for l in split.get()..=finest.get() {
            let file = if l == finest.get() {
                let mut f = partial.reopen()?;
                f.seek(SeekFrom::Start(HEADER_LEN as u64))?;
                f
            } else {
                tempfile::tempfile_in(dir)
                    .with_context(|| format!("cannot create a spill file in {}", dir.display()))?
            };
            levels.push(Stream {
                out: BufWriter::with_capacity(SINK_BUFFER, file),
                len: 0,
                records: 0,
            });
        }
        let roots = tempfile::tempfile_in(dir)
            .with_context(|| format!("cannot create a spill file in {}", dir.display()))?;
        Ok(Self {
            target: target.to_path_buf(),
            partial,
            spec,
            split,
            finest,
            next_top: tops.start,
            tops,
            levels,
            roots: BufWriter::with_capacity(ROOTS_BUFFER, roots),
            roots_len: 0,
            scratch: Vec::new(),
        })
    }

    fn records(&self) -> u64 {
        self.levels.iter().map(|s| s.records).sum()
    }

    /// Writes `bytes` to the roots' spill file, hashing them.
    fn put_root_bytes(&mut self, bytes: &[u8], hash: &mut Xxh3) -> anyhow::Result<()> {
        self.roots
            .write_all(bytes)
            .context("writing a split-level tile")?;
        hash.update(bytes);
        Ok(())
    }

    /// Appends the spill files, the trailer and the header, re-reads the whole part
    /// and renames it into place. Returns its size.
    fn finish(
        self,
        mut trailer: Trailer,
        interrupt: &super::interrupt::Interrupt,
    ) -> anyhow::Result<u64> {
        let Self {
            target,
            partial,
            spec,
            split,
            finest,
            tops,
            next_top,
            levels,
            roots,
            roots_len,
            ..
        } = self;
        ensure!(
            next_top == tops.end,
            "the part's split-level tiles stopped at {next_top} of {}",
            tops.end
        );
        let mut files = Vec::new();
        for s in levels {
            let f = s
                .out
                .into_inner()
                .map_err(std::io::IntoInnerError::into_error)
                .context("writing a record")?;
            files.push((f, s.len, s.records));
        }
        let mut roots = roots
            .into_inner()
            .map_err(std::io::IntoInnerError::into_error)
            .context("writing a split-level tile")?;
        // Finest level first (already in place), then the coarser ones, then roots.
        let mut sections = vec![Section::default(); files.len()];
        let last = files.len() - 1;
        sections[last] = Section {
            offset: HEADER_LEN as u64,
            len: files[last].1,
            count: files[last].2,
        };
        let mut at = HEADER_LEN as u64 + files[last].1;
        let mut out = partial.reopen()?;
        for (i, (spill, len, count)) in files.iter_mut().enumerate().rev().skip(1) {
            interrupt.check()?;
            spill.seek(SeekFrom::Start(0))?;
            out.seek(SeekFrom::Start(at))?;
            let copied = std::io::copy(spill, &mut out).context("appending a level's records")?;
            ensure!(copied == *len, "a level's spill file lost bytes");
            sections[i] = Section {
                offset: at,
                len: *len,
                count: *count,
            };
            at += *len;
        }
        drop(files);
        roots.seek(SeekFrom::Start(0))?;
        out.seek(SeekFrom::Start(at))?;
        let copied = std::io::copy(&mut roots, &mut out).context("appending the roots")?;
        ensure!(copied == roots_len, "the roots' spill file lost bytes");
        trailer.sections = sections;
        trailer.roots = Section {
            offset: at,
            len: roots_len,
            count: tops.end - tops.start,
        };
        at += roots_len;
        let trailer_bytes = trailer.to_bytes(split.get());
        out.write_all_at(&trailer_bytes, at)
            .context("writing the trailer")?;
        let file_len = at + trailer_bytes.len() as u64;
        let mut header = Header {
            n: spec.n,
            k: spec.k,
            split: split.get(),
            finest: finest.get(),
            trailer_offset: at,
            trailer_len: trailer_bytes.len() as u64,
            file_len,
            checksum: 0,
        };
        header.checksum = header.compute_checksum(&trailer_bytes);
        out.write_all_at(&header.to_bytes(), 0)
            .context("writing the header")?;
        out.set_len(file_len)?;
        out.sync_all().context("syncing the part to disk")?;
        // Re-read what is on disk before it becomes visible under its name.
        let written = PartFile::open(partial.path()).context("re-reading the written part")?;
        written
            .check(interrupt)
            .context("re-reading the written part")?;
        interrupt.check()?;
        publish(partial, &target, "part")?;
        Ok(file_len)
    }
}

impl Sink for PartWriter {
    fn record(
        &mut self,
        level: Level,
        m: Morton,
        record: &[u8],
        summary: IndexEntry,
    ) -> anyhow::Result<()> {
        let s = &mut self.levels[usize::from(level.get() - self.split.get())];
        let frame = Frame {
            m: m.get(),
            length: u32::try_from(record.len()).context("record over 4 GiB")?,
            min: summary.min,
            max: summary.max,
            checksum: format::checksum(record),
            full_res_error: summary.full_res_error,
            flags: summary.flags,
        };
        s.out
            .write_all(&frame.to_bytes())
            .and_then(|()| s.out.write_all(record))
            .with_context(|| format!("cannot write {}", self.target.display()))?;
        s.len += (FRAME_LEN + record.len()) as u64;
        s.records += 1;
        Ok(())
    }

    /// Root frame: `0` (absent), or `1`, the payload's length (u64), the payload
    /// (heights, block errors, block min/max, mask) and its XXH3-64.
    fn top(&mut self, m: Morton, node: Option<Node>) -> anyhow::Result<()> {
        ensure!(
            m.get() == self.next_top && m.get() < self.tops.end,
            "split-level tile {m} arrived out of order (expected {})",
            self.next_top
        );
        self.next_top += 1;
        let Some(node) = node else {
            self.roots
                .write_all(&[0])
                .context("writing a split-level tile")?;
            self.roots_len += 1;
            return Ok(());
        };
        let mask = node.mask.encode();
        let payload = root_fixed_len(node.heights.len(), node.errors.values.len()) + mask.len();
        self.roots
            .write_all(&[1])
            .context("writing a split-level tile")?;
        self.roots
            .write_all(&(payload as u64).to_le_bytes())
            .context("writing a split-level tile")?;
        let mut hash = Xxh3::new();
        let mut scratch = std::mem::take(&mut self.scratch);
        for chunk in node.heights.chunks(1 << 14) {
            scratch.clear();
            scratch.extend(chunk.iter().flat_map(|v| v.to_le_bytes()));
            self.put_root_bytes(&scratch, &mut hash)?;
        }
        for chunk in node.errors.values.chunks(1 << 13) {
            scratch.clear();
            scratch.extend(chunk.iter().flat_map(|v| v.to_bits().to_le_bytes()));
            self.put_root_bytes(&scratch, &mut hash)?;
        }
        scratch.clear();
        scratch.extend(
            node.min
                .iter()
                .chain(&node.max)
                .flat_map(|v| v.to_le_bytes()),
        );
        scratch.extend_from_slice(&(mask.len() as u32).to_le_bytes());
        scratch.extend_from_slice(&mask);
        self.put_root_bytes(&scratch, &mut hash)?;
        self.scratch = scratch;
        self.roots
            .write_all(&hash.digest().to_le_bytes())
            .context("writing a split-level tile")?;
        self.roots_len += 1 + 8 + payload as u64 + 8;
        Ok(())
    }
}

/// A root payload's length but for its mask bytes: heights, errors, min/max and
/// the mask's length.
fn root_fixed_len(heights: usize, errors: usize) -> usize {
    2 * heights + 8 * errors + 2 * 2 * 64 + 4
}

/// A part file opened and checked (header, trailer, length) without reading its
/// records.
#[derive(Debug)]
pub struct PartFile {
    pub path: PathBuf,
    file: File,
    header: Header,
    trailer: Trailer,
}

impl PartFile {
    /// Opens a part file; errors say what is wrong (the caller names the file).
    pub fn open(path: &Path) -> anyhow::Result<Self> {
        let file = File::open(path)?;
        let len = file.metadata()?.len();
        ensure!(
            len >= HEADER_LEN as u64,
            "truncated: {len} bytes, shorter than a part header"
        );
        let mut hb = [0u8; HEADER_LEN];
        file.read_exact_at(&mut hb, 0)?;
        let header = Header::parse(&hb)?;
        ensure!(
            header.file_len == len,
            "{}: {len} bytes where its header says {}",
            if len < header.file_len {
                "truncated"
            } else {
                "wrong length"
            },
            header.file_len
        );
        ensure!(
            header.trailer_len <= MAX_TRAILER
                && header.trailer_offset >= HEADER_LEN as u64
                && header.trailer_offset.checked_add(header.trailer_len) == Some(len),
            "corrupt: its header places the trailer outside the file"
        );
        let mut tb = vec![0u8; header.trailer_len as usize];
        file.read_exact_at(&mut tb, header.trailer_offset)?;
        ensure!(
            header.compute_checksum(&tb) == header.checksum,
            "corrupt: the checksum of its header and trailer does not match"
        );
        let trailer = Trailer::parse(&tb, header.split)?;
        ensure!(
            header.n >= 1 && header.k < header.n,
            "corrupt: part {} of {}",
            header.k,
            header.n
        );
        ensure!(
            header.split <= header.finest
                && usize::from(header.finest - header.split) + 1 == trailer.sections.len()
                && trailer.meta.levels.checked_sub(1) == Some(header.finest),
            "corrupt: its levels do not fit together"
        );
        let mut end = HEADER_LEN as u64;
        let mut spans: Vec<Section> = trailer.sections.clone();
        spans.push(trailer.roots);
        spans.sort_by_key(|s| s.offset);
        for s in &spans {
            ensure!(
                s.offset >= end && s.offset.checked_add(s.len).is_some_and(|e| e <= len),
                "corrupt: its sections overlap or lie outside the file"
            );
            end = s.offset + s.len;
        }
        Ok(Self {
            path: path.to_path_buf(),
            file,
            header,
            trailer,
        })
    }

    /// Part `k` of `n`.
    pub fn spec(&self) -> PartSpec {
        PartSpec {
            k: self.header.k,
            n: self.header.n,
        }
    }

    fn split(&self) -> Level {
        Level::new(self.header.split).expect("checked against the finest level")
    }

    /// The records of `level` (at least the split level), in Morton order.
    fn records(&self, level: Level) -> anyhow::Result<Records> {
        let i = usize::from(level.get() - self.header.split);
        let s = self.trailer.sections[i];
        let mut reader = BufReader::with_capacity(SINK_BUFFER, self.file.try_clone()?);
        reader.seek(SeekFrom::Start(s.offset))?;
        let shift = 2 * u32::from(level.get() - self.header.split);
        Ok(Records {
            reader,
            level,
            remaining: s.len,
            left: s.count,
            next: self.trailer.tops.start << shift,
            end: self.trailer.tops.end << shift,
            buf: Vec::new(),
        })
    }

    /// The split level's nodes, one per code of the part's slice.
    fn roots(&self, g: &TileGeometry) -> anyhow::Result<Roots> {
        let s = self.trailer.roots;
        let mut reader = BufReader::with_capacity(SINK_BUFFER, self.file.try_clone()?);
        reader.seek(SeekFrom::Start(s.offset))?;
        ensure!(
            s.count == self.trailer.tops.end - self.trailer.tops.start,
            "corrupt: {} split-level tiles for a slice of {}",
            s.count,
            self.trailer.tops.end - self.trailer.tops.start
        );
        Ok(Roots {
            reader,
            remaining: s.len,
            next: self.trailer.tops.start,
            end: self.trailer.tops.end,
            side: g.tile_samples(),
            spacings: self.trailer.spacings as usize,
        })
    }

    /// Reads every record and root, checking their checksums.
    pub fn check(&self, interrupt: &super::interrupt::Interrupt) -> anyhow::Result<()> {
        let g = TileGeometry::new(
            self.trailer.meta.width,
            self.trailer.meta.height,
            self.trailer.meta.tile_size,
        )?;
        for l in self.header.split..=self.header.finest {
            interrupt.check()?;
            let mut r = self.records(Level::new(l).expect("a level"))?;
            while r.next()?.is_some() {}
        }
        let mut roots = self.roots(&g)?;
        for _ in self.trailer.tops.clone() {
            roots.next()?;
        }
        roots.finish()
    }
}

/// A level's records in a part, checked as they are read.
struct Records {
    reader: BufReader<File>,
    level: Level,
    remaining: u64,
    left: u64,
    /// The smallest code the next record may have, and the end of the slice.
    next: u64,
    end: u64,
    buf: Vec<u8>,
}

impl Records {
    fn next(&mut self) -> anyhow::Result<Option<(Morton, &[u8], Frame)>> {
        let level = self.level;
        if self.left == 0 {
            ensure!(
                self.remaining == 0,
                "corrupt: level {level} has {} bytes after its last record",
                self.remaining
            );
            return Ok(None);
        }
        ensure!(
            self.remaining >= FRAME_LEN as u64,
            "corrupt: level {level} ends {} records early",
            self.left
        );
        let mut fb = [0u8; FRAME_LEN];
        self.reader
            .read_exact(&mut fb)
            .with_context(|| format!("reading level {level}"))?;
        let frame = Frame::parse(&fb);
        self.remaining -= FRAME_LEN as u64;
        ensure!(
            frame.m >= self.next && frame.m < self.end,
            "corrupt: level {level} holds a record for Morton code {} out of order or outside \
             the part's slice",
            frame.m
        );
        ensure!(
            frame.length > 0 && u64::from(frame.length) <= self.remaining,
            "corrupt: level {level} Morton code {}: record length {} does not fit",
            frame.m,
            frame.length
        );
        self.buf.resize(frame.length as usize, 0);
        self.reader
            .read_exact(&mut self.buf)
            .with_context(|| format!("reading level {level}"))?;
        ensure!(
            format::checksum(&self.buf) == frame.checksum,
            "corrupt: level {level} Morton code {}: the record's checksum does not match",
            frame.m
        );
        self.remaining -= u64::from(frame.length);
        self.left -= 1;
        self.next = frame.m + 1;
        Ok(Some((Morton::from_raw(frame.m), &self.buf, frame)))
    }
}

/// A part's split-level nodes, checked as they are read.
struct Roots {
    reader: BufReader<File>,
    remaining: u64,
    next: u64,
    end: u64,
    side: usize,
    spacings: usize,
}

impl Roots {
    /// The next code's node (`None`: absent).
    fn next(&mut self) -> anyhow::Result<Option<Node>> {
        let m = self.next;
        ensure!(m < self.end, "corrupt: more split-level tiles than codes");
        self.next += 1;
        let mut tag = [0u8; 1];
        self.take(&mut tag, m)?;
        match tag[0] {
            0 => return Ok(None),
            1 => {}
            t => bail!("corrupt: split-level tile {m} has tag {t}"),
        }
        let mut lb = [0u8; 8];
        self.take(&mut lb, m)?;
        let len = u64::from_le_bytes(lb);
        let fixed = root_fixed_len(self.side * self.side, self.spacings * 64);
        ensure!(
            len >= fixed as u64 && len.saturating_add(8) <= self.remaining,
            "corrupt: split-level tile {m} has a payload of {len} bytes"
        );
        let mut payload = vec![0u8; len as usize];
        self.take(&mut payload, m)?;
        self.take(&mut lb, m)?;
        ensure!(
            format::checksum(&payload) == u64::from_le_bytes(lb),
            "corrupt: split-level tile {m}: its checksum does not match"
        );
        let (heights, rest) = payload.split_at(2 * self.side * self.side);
        let (errors, rest) = rest.split_at(8 * self.spacings * 64);
        let (ranges, rest) = rest.split_at(256);
        let (mask_len, mask) = rest.split_at(4);
        ensure!(
            u32::from_le_bytes(mask_len.try_into()?) as usize == mask.len(),
            "corrupt: split-level tile {m}: its mask length does not match"
        );
        let u16s = |b: &[u8]| -> Vec<u16> {
            b.chunks_exact(2)
                .map(|c| u16::from_le_bytes([c[0], c[1]]))
                .collect()
        };
        let ranges = u16s(ranges);
        let mut min = [0u16; 64];
        let mut max = [0u16; 64];
        min.copy_from_slice(&ranges[..64]);
        max.copy_from_slice(&ranges[64..]);
        let mask = CellMask::decode(mask, self.side as u32 - 1)
            .map_err(|e| anyhow::anyhow!("corrupt: split-level tile {m}: {e}"))?;
        Ok(Some(Node {
            heights: u16s(heights),
            errors: BlockErrors {
                values: errors
                    .chunks_exact(8)
                    .map(|c| f64::from_bits(u64::from_le_bytes(c.try_into().expect("8 bytes"))))
                    .collect(),
            },
            min,
            max,
            mask,
        }))
    }

    /// Checks that every code's node was read and nothing follows.
    fn finish(&self) -> anyhow::Result<()> {
        ensure!(
            self.next == self.end && self.remaining == 0,
            "corrupt: {} bytes after the last split-level tile",
            self.remaining
        );
        Ok(())
    }

    fn take(&mut self, buf: &mut [u8], m: u64) -> anyhow::Result<()> {
        ensure!(
            buf.len() as u64 <= self.remaining,
            "corrupt: split-level tile {m} runs past its section"
        );
        self.reader
            .read_exact(buf)
            .with_context(|| format!("reading split-level tile {m}"))?;
        self.remaining -= buf.len() as u64;
        Ok(())
    }
}

/// The part files in `dir` (`*.tesspart`, not hidden), sorted by name.
fn list_parts(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    ensure!(
        dir.is_dir(),
        "{}: not a folder of part files (build them with `build INPUT --part K/N -o {}`)",
        dir.display(),
        dir.display()
    );
    let mut paths = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("cannot read {}", dir.display()))? {
        let path = entry?.path();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if !name.starts_with('.') && path.extension().is_some_and(|e| e == EXTENSION) {
            paths.push(path);
        }
    }
    paths.sort();
    ensure!(
        !paths.is_empty(),
        "{}: no part files (*.{EXTENSION}) (build them with `build INPUT --part K/N -o {}`)",
        dir.display(),
        dir.display()
    );
    Ok(paths)
}

/// What differs between two parts' metadata, for a mismatch's message.
fn differences(a: &Metadata, b: &Metadata) -> String {
    let mut d = Vec::new();
    if a.source != b.source {
        d.push(format!(
            "its source is {:?}, the others' {:?}",
            a.source, b.source
        ));
    }
    if (a.width, a.height) != (b.width, b.height) {
        d.push(format!(
            "its DEM is {}×{}, the others' {}×{}",
            a.width, a.height, b.width, b.height
        ));
    }
    if a.tile_size != b.tile_size {
        d.push(format!(
            "its --tile-size is {}, the others' {}",
            a.tile_size, b.tile_size
        ));
    }
    if a.quantization != b.quantization {
        d.push(format!(
            "its height quantization (--scale/--offset) is {:?}, the others' {:?}",
            a.quantization, b.quantization
        ));
    }
    if a.generator != b.generator {
        d.push(format!(
            "it was built by {}, the others by {}",
            a.generator, b.generator
        ));
    }
    if a.vertical_datum != b.vertical_datum || a.georef != b.georef {
        d.push("its georeferencing or vertical datum differs".into());
    }
    if d.is_empty() {
        "its input's samples or the build options differ (--nodata, --overlap, or --memory \
         with an input that has no-data)"
            .into()
    } else {
        d.join(", ")
    }
}

/// Opens every part in `dir` and checks they make one whole: one `N`, one
/// fingerprint, each `K` once, the slices the split gives. Every problem found is
/// reported, each naming its file.
fn open_parts(dir: &Path) -> anyhow::Result<Vec<PartFile>> {
    let mut problems = Vec::new();
    let mut parts = Vec::new();
    for path in list_parts(dir)? {
        match PartFile::open(&path) {
            Ok(p) => parts.push(p),
            Err(e) => problems.push(format!("{}: {e:#}", path.display())),
        }
    }
    if !problems.is_empty() {
        bail!("{}", problems.join("; "));
    }
    // The N and the fingerprint most parts have are the build's.
    let most = |keys: Vec<Vec<u8>>| -> Vec<u8> {
        let mut count: BTreeMap<&Vec<u8>, usize> = BTreeMap::new();
        for k in &keys {
            *count.entry(k).or_default() += 1;
        }
        let best = count.values().copied().max().unwrap_or(0);
        keys.iter()
            .find(|k| count[k] == best)
            .cloned()
            .unwrap_or_default()
    };
    let n_bytes = most(
        parts
            .iter()
            .map(|p| p.header.n.to_le_bytes().to_vec())
            .collect(),
    );
    let n = u32::from_le_bytes(n_bytes.try_into().expect("4 bytes"));
    let mut same_n = Vec::new();
    for p in parts {
        if p.header.n == n {
            same_n.push(p);
        } else {
            problems.push(format!(
                "{}: part {} of a {}-part build, where the other parts are of a {n}-part build",
                p.path.display(),
                p.header.k,
                p.header.n
            ));
        }
    }
    let fingerprint = most(
        same_n
            .iter()
            .map(|p| p.trailer.fingerprint.to_vec())
            .collect(),
    );
    let reference = same_n
        .iter()
        .find(|p| p.trailer.fingerprint[..] == fingerprint[..])
        .map(|p| p.trailer.meta.clone());
    let mut by_k: BTreeMap<u32, Vec<PartFile>> = BTreeMap::new();
    // Ks some file claims, matching or not: a mismatched part is not also "missing".
    let claimed: std::collections::BTreeSet<u32> = same_n.iter().map(|p| p.header.k).collect();
    for p in same_n {
        if p.trailer.fingerprint[..] == fingerprint[..] {
            by_k.entry(p.header.k).or_default().push(p);
        } else {
            let other = reference
                .as_ref()
                .expect("the most common fingerprint has a part");
            problems.push(format!(
                "{}: built from another input or with other options than the other parts: {}",
                p.path.display(),
                differences(&p.trailer.meta, other)
            ));
        }
    }
    for (k, ps) in &by_k {
        if ps.len() > 1 {
            let names: Vec<String> = ps.iter().map(|p| p.path.display().to_string()).collect();
            problems.push(format!(
                "{}: duplicate part {k} of {n} (keep one)",
                names.join(" and ")
            ));
        }
    }
    for k in 0..n {
        if !claimed.contains(&k) {
            let spec = PartSpec { k, n };
            problems.push(format!(
                "{}: missing (part {k} of {n}; build it with --part {k}/{n})",
                dir.join(spec.file_name()).display()
            ));
        }
    }
    if !problems.is_empty() {
        bail!("{}", problems.join("; "));
    }
    let parts: Vec<PartFile> = by_k
        .into_values()
        .map(|mut v| v.pop().expect("one part"))
        .collect();
    let meta = &parts[0].trailer.meta;
    let geometry = TileGeometry::new(meta.width, meta.height, meta.tile_size)?;
    let split = Split::new(&geometry, n);
    for p in &parts {
        let tops = split.tops(p.header.k);
        ensure!(
            p.header.split == split.level.get() && p.trailer.tops == tops,
            "{}: it covers codes {:?} of level {} where part {} of {n} covers {:?} of level {}",
            p.path.display(),
            p.trailer.tops,
            p.header.split,
            p.header.k,
            tops,
            split.level
        );
    }
    Ok(parts)
}

/// Assembles the parts in `dir` into the pyramid `output`: the parts' records for
/// the split level and below, the levels above built from their roots, the metadata
/// from their counts; written, verified and moved into place as a whole build is.
pub fn assemble(dir: &Path, output: &Path, opts: &BuildOptions) -> anyhow::Result<BuildReport> {
    let started = Instant::now();
    let parts = open_parts(dir)?;
    let mut meta = parts[0].trailer.meta.clone();
    let geometry = TileGeometry::new(meta.width, meta.height, meta.tile_size)?;
    memory::Plan::new(&geometry, 0, opts.memory_budget)
        .with_context(|| format!("assembling {}", dir.display()))?;
    let split = parts[0].split();
    let finest = geometry.finest();
    let mut writer = create_output(output, geometry, parts[0].trailer.meta_reserve)?;
    let tiles_bar = bar(
        opts.progress,
        count_tiles(&geometry, geometry.levels()),
        "assembling",
    );
    // The split level and below: each level's records, part after part.
    for p in &parts {
        let named = || p.path.display().to_string();
        for l in split.get()..=finest.get() {
            opts.interrupt.check()?;
            let level = Level::new(l).expect("a level");
            let mut records = p.records(level).with_context(named)?;
            while let Some((m, record, frame)) = records.next().with_context(named)? {
                writer.push(level, m, record, frame.summary())?;
                tiles_bar.inc(1);
            }
        }
    }
    // Above it: the parts' roots, through the same aggregation as a whole build.
    let mut agg = Aggregator {
        geometry,
        quant: meta.quantization,
        spacings: spacings(&geometry),
        top: Level::ROOT,
        pending: (0..=finest.get())
            .map(|_| [None, None, None, None])
            .collect(),
        min_q: u16::MAX,
        max_q: 0,
        bar: &tiles_bar,
    };
    for p in &parts {
        let named = || p.path.display().to_string();
        ensure!(
            p.trailer.spacings == agg.spacings,
            "{}: corrupt: its tiles hold {} error spacings, not {}",
            named(),
            p.trailer.spacings,
            agg.spacings
        );
        opts.interrupt.check()?;
        let mut roots = p.roots(&geometry).with_context(named)?;
        for m in p.trailer.tops.clone() {
            let node = roots.next().with_context(named)?;
            agg.push_node(&mut writer, split, Morton::from_raw(m), node)?;
        }
        roots.finish().with_context(named)?;
    }
    drop(agg);
    tiles_bar.finish_and_clear();
    // The DEM-wide numbers, as a whole build counts them.
    let (mut min_q, mut max_q) = (u16::MAX, 0u16);
    let mut depths = [[0u64; 2]; 33];
    let mut nodata = 0u64;
    for p in &parts {
        let t = &p.trailer;
        min_q = min_q.min(t.min_q);
        max_q = max_q.max(t.max_q);
        nodata += t.nodata;
        for (d, s) in depths.iter_mut().zip(t.depths) {
            d[0] += s[0];
            d[1] += s[1];
        }
    }
    ensure!(
        nodata == depths.iter().map(|d| d[1]).sum::<u64>(),
        "the parts' no-data counts do not add up"
    );
    meta.min_height = meta.quantization.height(min_q);
    meta.max_height = meta.quantization.height(max_q);
    meta.nodata_count = nodata;
    meta.level_counts = level_counts(&geometry, &depths);
    finish_output(writer, meta, &geometry, opts, started)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::raster::all_valid_depth_counts;

    #[test]
    fn part_specs_parse_with_and_without_the_job_index() {
        assert_eq!(
            PartSpec::parse("3/16", None).unwrap(),
            PartSpec { k: 3, n: 16 }
        );
        assert_eq!(
            PartSpec::parse("/16", Some("15")).unwrap(),
            PartSpec { k: 15, n: 16 }
        );
        // An explicit K wins over the environment.
        assert_eq!(PartSpec::parse("2/4", Some("3")).unwrap().k, 2);
        let e = PartSpec::parse("/16", None).unwrap_err().to_string();
        assert!(e.contains("JOB_COMPLETION_INDEX"), "{e}");
        assert!(PartSpec::parse("16/16", None).is_err());
        assert!(PartSpec::parse("1/0", None).is_err());
        assert!(PartSpec::parse("/4", Some("x")).is_err());
        assert!(PartSpec::parse("3", None).is_err());
        assert_eq!(
            PartSpec { k: 3, n: 16 }.file_name(),
            "part-0003-of-0016.tesspart"
        );
    }

    #[test]
    fn splits_cover_every_code_once_and_balance_the_work() {
        for (w, h, t, n) in [
            (1025, 1025, 64, 16),
            (1025, 1025, 64, 1),
            (1025, 1025, 64, 5),
            (1201, 700, 64, 4),
            (3000, 200, 64, 7),
            (65, 65, 64, 4),
            (100, 100, 128, 3),
        ] {
            let g = TileGeometry::new(w, h, t).unwrap();
            let s = Split::new(&g, n);
            let wts = tile_weights(&g, s.level);
            assert!(s.level.get() >= 1.min(g.finest().get()));
            assert!(s.level <= g.finest());
            assert_eq!(s.tops(0).start, 0);
            assert_eq!(s.tops(n - 1).end, s.level.tile_slots());
            for k in 1..n {
                assert_eq!(s.tops(k - 1).end, s.tops(k).start);
            }
            let total: u64 = wts.iter().sum();
            assert_eq!(total, g.present_tiles(g.finest()).count() as u64, "{w}×{h}");
            // No part holds more than its share plus one subtree's work.
            let biggest = *wts.iter().max().unwrap();
            for k in 0..n {
                let r = s.tops(k);
                let work: u64 = wts[r.start as usize..r.end as usize].iter().sum();
                assert!(
                    work <= total.div_ceil(u64::from(n)) + biggest,
                    "{w}×{h}/{n}: part {k} has {work} of {total}"
                );
            }
        }
    }

    #[test]
    fn shares_of_the_counts_add_up_to_the_whole() {
        for (w, h, t, n) in [
            (1025, 1025, 64, 16),
            (1201, 700, 64, 4),
            (130, 67, 64, 3),
            (129, 129, 64, 2),
        ] {
            let g = TileGeometry::new(w, h, t).unwrap();
            let split = Split::new(&g, n);
            let mut sum = [[0u64; 2]; 33];
            for k in 0..n {
                for m in split.tops(k) {
                    let tile = TileId::from_morton(split.level, Morton::from_raw(m)).unwrap();
                    if let Some((xs, ys)) = owned(&g, tile) {
                        for (s, r) in sum.iter_mut().zip(rect_depths(&xs, &ys)) {
                            s[0] += r[0];
                        }
                    }
                }
            }
            assert_eq!(sum, all_valid_depth_counts(w, h), "{w}×{h}");
        }
        // A rectangle away from the origin, against counting sample by sample.
        let (xs, ys) = (5..77, 64..130);
        let mut brute = [[0u64; 2]; 33];
        for y in ys.clone() {
            for x in xs.clone() {
                brute[depth(x, y)][0] += 1;
            }
        }
        assert_eq!(rect_depths(&xs, &ys), brute);
    }

    #[test]
    fn headers_trailers_and_frames_read_back() {
        let meta = tessera_shared::fixtures::metadata(1025, 1025, 64);
        let t = Trailer {
            fingerprint: [7; 16],
            tops: 4..9,
            meta_reserve: 4242,
            spacings: 11,
            min_q: 3,
            max_q: 60000,
            nodata: 5,
            depths: {
                let mut d = [[1u64, 0]; 33];
                d[0][1] = 5;
                d
            },
            sections: vec![
                Section {
                    offset: 64,
                    len: 10,
                    count: 1,
                },
                Section {
                    offset: 74,
                    len: 20,
                    count: 2,
                },
            ],
            roots: Section {
                offset: 94,
                len: 5,
                count: 5,
            },
            meta,
        };
        let bytes = t.to_bytes(3);
        assert_eq!(Trailer::parse(&bytes, 3).unwrap(), t);
        assert!(Trailer::parse(&bytes[..bytes.len() - 1], 3).is_err());
        assert!(Trailer::parse(&bytes, 2).is_err(), "levels are checked");
        let h = Header {
            n: 16,
            k: 3,
            split: 3,
            finest: 4,
            trailer_offset: 99,
            trailer_len: bytes.len() as u64,
            file_len: 99 + bytes.len() as u64,
            checksum: 12345,
        };
        assert_eq!(Header::parse(&h.to_bytes()).unwrap(), h);
        let mut bad = h.to_bytes();
        bad[0] = b'X';
        assert!(Header::parse(&bad).is_err());
        let f = Frame {
            m: 77,
            length: 1000,
            min: 1,
            max: 2,
            checksum: 99,
            full_res_error: 0.5,
            flags: 1,
        };
        assert_eq!(Frame::parse(&f.to_bytes()), f);
    }

    #[test]
    fn a_part_file_round_trips_and_damage_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let opts = BuildOptions {
            tile_size: 64,
            ..BuildOptions::default()
        };
        let spec = PartSpec { k: 1, n: 4 };
        let r = build_part(
            &ingest::InputSpec::one("synthetic:257:5"),
            dir.path(),
            spec,
            &opts,
        )
        .unwrap();
        assert_eq!(r.path, dir.path().join("part-0001-of-0004.tesspart"));
        let p = PartFile::open(&r.path).unwrap();
        assert_eq!(p.spec(), spec);
        p.check(&opts.interrupt).unwrap();
        assert!(r.records > 0);
        // Flip one byte of the first record: the part opens (header and trailer are
        // intact) but reading it names the tile.
        let mut bytes = std::fs::read(&r.path).unwrap();
        bytes[HEADER_LEN + FRAME_LEN + 10] ^= 0xff;
        let damaged = dir.path().join("damaged.tesspart");
        std::fs::write(&damaged, &bytes).unwrap();
        let e = format!(
            "{:#}",
            PartFile::open(&damaged)
                .unwrap()
                .check(&opts.interrupt)
                .unwrap_err()
        );
        assert!(e.contains("checksum does not match"), "{e}");
        // Cut short: refused when opened.
        std::fs::write(&damaged, &bytes[..bytes.len() - 3]).unwrap();
        let e = format!("{:#}", PartFile::open(&damaged).unwrap_err());
        assert!(e.contains("truncated"), "{e}");
    }
}
