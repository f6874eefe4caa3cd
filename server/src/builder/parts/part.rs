//! Building one part (`build INPUT --part K/N -o PARTS/`): the input spooled whole,
//! the part's subtrees cut, and its fingerprint of input, metadata and options.

use super::layout::{Section, Trailer};
use super::split::{PartSpec, Split, share};
use super::writer::PartWriter;
use crate::builder::{BuildOptions, Loaded, Tiling, bar, meta_reserve};
use crate::ingest::{self, RowSource, SourceInfo};
use anyhow::{Context, ensure};
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::time::Instant;
use tessera_shared::format;
use tessera_shared::{Level, Morton, TileGeometry, TileId};
use xxhash_rust::xxh3::Xxh3;

/// A row source that hashes every raw sample it hands on (its bits, little-endian):
/// a part's fingerprint of its input's content.
pub(in crate::builder) struct Digesting<'a> {
    inner: &'a mut dyn RowSource,
    hash: &'a mut Xxh3,
}

impl<'a> Digesting<'a> {
    pub(in crate::builder) fn new(inner: &'a mut dyn RowSource, hash: &'a mut Xxh3) -> Self {
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
    let folders = crate::builder::plausible::Folders {
        spool: scratch.clone(),
        output: dir.to_path_buf(),
    };
    let prepared = crate::builder::prepare(inputs, &folders, spec.n, opts)?;
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
pub(super) fn spacings(g: &TileGeometry) -> u32 {
    g.tile_log2() + u32::from(g.finest().get()) + 1
}

/// A digest of everything that shapes the pyramid's bytes: the metadata (size, tile
/// size, quantization, CRS, source, generator), the input's raw samples, the
/// options, and for an input with no-data the band height its fill used
/// (`--memory` sets it).
pub(super) fn fingerprint(
    loaded: &Loaded,
    opts: &BuildOptions,
    reserve: u64,
    digest: u64,
) -> [u8; 16] {
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
