//! `build --assemble PARTS/ -o OUT.tess`: the parts found and checked against each
//! other, the levels above the split made from their roots, and the pyramid written.

use super::EXTENSION;
use super::reader::PartFile;
use super::split::{PartSpec, Split};
use crate::builder::coarse::Aggregator;
use crate::builder::{
    BuildOptions, BuildReport, bar, count_tiles, create_output, finish_output, level_counts, memory,
};
use anyhow::{Context, bail, ensure};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;
use tessera_shared::{Level, Metadata, Morton, TileGeometry};

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
        "its input files (their sizes or ETags) or the build options differ (--nodata, \
         --overlap, --height-range or --memory)"
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
    // Above the split every tile is stored (the parts refuse a split below the levels
    // a multi-resolution pyramid stores everywhere).
    let mut agg = Aggregator::new(geometry, Level::ROOT, &tiles_bar, None);
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
    // The levels above the split count in the heights' range, as in a whole build
    // (they matter in a multi-resolution pyramid, whose coarse-only places have no
    // deeper records).
    let (mut min_q, mut max_q) = (agg.min_q, agg.max_q);
    drop(agg);
    tiles_bar.finish_and_clear();
    // The DEM-wide numbers, as a whole build counts them.
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
