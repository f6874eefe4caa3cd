//! Building one part (`build INPUT --part K/N -o PARTS/`): the input spooled whole,
//! the part's subtrees cut, and its fingerprint of input, metadata and options.

use super::layout::{Section, Trailer};
use super::split::{PartSpec, Split, share};
use super::writer::PartWriter;
use crate::builder::prepare::Loaded;
use crate::builder::share::footprint::Footprint;
use crate::builder::tiling::Tiling;
use crate::builder::{BuildOptions, bar, meta_reserve};
use crate::ingest;
use anyhow::{Context, ensure};
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::time::Instant;
use tessera_shared::format;
use tessera_shared::{Level, Metadata, Morton, TileId};
use xxhash_rust::xxh3::Xxh3;

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
    /// As [`crate::builder::BuildReport::warnings`].
    pub warnings: Vec<String>,
    /// How much of the input the part read.
    pub read: PartRead,
    /// Bytes fetched from object storage or HTTP for the inputs.
    pub fetched: ingest::remote::Fetched,
}

/// How much of its input a part read (a share, or the whole when its share cannot
/// stand alone: no-data in it, or float samples without `--height-range`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PartRead {
    /// Only its share: `samples` of the input's `of`.
    Share { samples: u64, of: u64 },
    /// The whole input, and why.
    Whole(String),
    /// Synthetic terrain, generated where it is read.
    Generated,
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
    let _spools = ingest::remote::SpoolScope::new();
    let fetched_before = ingest::remote::fetched();
    let prepared = crate::builder::prepare(inputs, &folders, spec.n, opts)?;
    let warnings = prepared.warnings.clone();
    let geometry = prepared.geometry;
    let split = Split::new(&geometry, spec.n);
    let tops = split.tops(spec.k);
    let reserve = meta_reserve(&prepared.meta);
    let target = dir.join(spec.file_name());
    let mut writer = PartWriter::create(&target, spec, &geometry, split.level, tops.clone())?;
    let footprint = Footprint::of(&geometry, split.level, tops.clone());
    let whole = u64::from(geometry.width()) * u64::from(geometry.height());
    let (loaded, read) = match prepared.load_share(&scratch, &footprint, opts, started)? {
        Ok((loaded, None)) => (loaded, PartRead::Generated),
        Ok((loaded, Some(samples))) => (loaded, PartRead::Share { samples, of: whole }),
        Err(why) => {
            tracing::debug!(k = spec.k, n = spec.n, "reading the whole input: {why}");
            let prepared = crate::builder::prepare(inputs, &folders, spec.n, opts)?;
            (
                prepared.load(&scratch, opts, started)?,
                PartRead::Whole(why),
            )
        }
    };
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
    // The assembly stores every level above the split, which a multi-resolution
    // pyramid does only down to its coarsest input's level (`Support::stores`).
    if let Some(s) = &loaded.support
        && split.level.get() > s.floor() + 1
    {
        anyhow::bail!(
            "{} parts split the pyramid at level {}, below level {}, the deepest this \
             multi-resolution collection stores everywhere: use at most {} parts",
            spec.n,
            split.level.get(),
            s.floor(),
            (1u64 << (2 * u32::from(s.floor() + 1))) / 4
        );
    }
    let tiling = Tiling {
        raster,
        geometry,
        quant: loaded.meta.quantization,
        plan: loaded.plan,
        opts,
        bar: &tiles_bar,
        support: loaded.support.as_ref(),
    };
    let (min_q, max_q) = tiling.subtrees(&mut writer, split.level, tops.clone())?;
    tiles_bar.finish_and_clear();
    let depths = share(raster, &geometry, split.level, tops.clone())?;
    let trailer = Trailer {
        fingerprint: fingerprint(&loaded, opts, reserve, ingest::inputs::identity(inputs)?),
        tops: tops.clone(),
        meta_reserve: reserve,
        spacings: crate::builder::coarse::spacings(&geometry),
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
        read,
        fetched: ingest::remote::fetched().since(fetched_before),
    })
}

/// A digest of everything that shapes the pyramid's bytes and that every part knows
/// without reading samples (each may read only its share): the metadata (size, tile
/// size, quantization, CRS, the inputs' provenance, generator), the inputs' identity
/// (`inputs`: paths, sizes, ETags), the options, and the band height the no-data
/// fill of a whole read uses (`--memory` sets it).
pub(super) fn fingerprint(
    loaded: &Loaded,
    opts: &BuildOptions,
    reserve: u64,
    inputs: u64,
) -> [u8; 16] {
    let mut h = Xxh3::new();
    h.update(b"tessera part fingerprint 2\0");
    // The no-data count is the only field a part learns from the samples it reads
    // (a whole read counts the input's, a share none); the parts' own counts are
    // compared when they are added up.
    let meta = Metadata {
        nodata_count: 0,
        ..loaded.meta.clone()
    };
    h.update(&format::encode_metadata(&meta));
    h.update(&reserve.to_le_bytes());
    h.update(&inputs.to_le_bytes());
    h.update(&(loaded.plan.band_bytes as u64).to_le_bytes());
    h.update(&opts.scale.to_bits().to_le_bytes());
    h.update(&opts.offset.to_bits().to_le_bytes());
    h.update(&opts.nodata.map_or(u64::MAX, f64::to_bits).to_le_bytes());
    for v in opts.height_range.into_iter().flatten() {
        h.update(&v.to_bits().to_le_bytes());
    }
    h.update(
        format!(
            "{:?} {:?} {:?}",
            opts.overlap, opts.resampling, opts.spacing
        )
        .as_bytes(),
    );
    h.digest128().to_le_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::builder::parts::{FRAME_LEN, HEADER_LEN, PartFile};

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
