//! `build INPUTS… --update OLD.tess -o NEW.tess`: the pyramid of the updated inputs,
//! byte for byte what a whole build of them writes, from reading only the inputs that
//! changed and re-encoding only the tiles they touch (DECISIONS.md "Updates").
//!
//! - **What changed.** `OLD.tess.state` ([`state`]) lists the inputs the old build read
//!   (path, size, ETag or modification time, window on the grid). An input added, gone,
//!   moved or with another size or tag changed; its old and new windows (grown by two
//!   samples when inputs were resampled onto the grid) are the changed area.
//! - **What is rebuilt.** A tile's record depends only on the samples of its own
//!   closed footprint (its errors are measured against cells inside it), so the tiles
//!   to re-encode are exactly those whose footprint meets the changed area: the
//!   finest ones and their ancestors. Their finest samples (and the coarse-cell corners
//!   their errors are measured against) are read as a part reads its share
//!   (`share::read`).
//! - **What is copied.** Every other record is copied byte for byte with its index
//!   entry (so its checksum, the per-tile ETag, stays), and a tile that did not change
//!   but whose parent did becomes a node again from its record and its state entry.
//! - **When it cannot.** An update that could not give the whole build's bytes builds
//!   the whole pyramid instead and says why: another grid, tile size, CRS, datum or
//!   quantization; no-data in the old pyramid or in what is read (the fill reaches
//!   across the input); a multi-resolution pyramid; `--feather`; inputs reordered; a
//!   pyramid of another tessera-server version.

mod changes;
mod composite;
pub mod state;

use super::coarse::Aggregator;
use super::finest::finest_node;
use super::mesh_error::BlockErrors;
use super::node::{Node, encode};
use super::sink::Sink;
use super::{BuildOptions, BuildReport, bar, plausible, writer};
use crate::ingest;
use anyhow::{Context, ensure};
use changes::{changed_area, changed_tiles, dirty_ranges};
use rayon::prelude::*;
use state::{InputRecord, State, StateWriter};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;
use tessera_shared::reader::{FileSource, Pyramid};
use tessera_shared::tile::BLOCKS;
use tessera_shared::{Level, Morton, TileGeometry, TileId};

/// What an update did.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum UpdateReport {
    /// Copied `copied` records; measured and encoded `measured` tiles again, of which
    /// `rewritten` have new bytes; read `samples` input samples.
    Updated {
        measured: u64,
        rewritten: u64,
        copied: u64,
        samples: u64,
    },
    /// Built whole, and why.
    Whole(String),
}

/// The inputs as a state file records them.
pub(super) fn input_records(windows: &[(PathBuf, [u32; 4])]) -> anyhow::Result<Vec<InputRecord>> {
    windows
        .iter()
        .map(|(path, window)| {
            let (size, tag) = ingest::inputs::file_identity(path)?;
            Ok(InputRecord {
                path: path.to_string_lossy().into_owned(),
                size,
                tag,
                window: *window,
            })
        })
        .collect()
}

/// A pyramid writer that also writes the update state.
pub(super) struct StateSink<'a> {
    pub(super) pyramid: &'a mut writer::PyramidWriter,
    pub(super) state: &'a mut StateWriter,
    /// For an update: the old pyramid, and how many re-encoded records differ from
    /// its (a re-measured tile whose samples did not change encodes as before).
    pub(super) old: Option<(&'a Pyramid<FileSource>, u64)>,
}

impl Sink for StateSink<'_> {
    fn record(
        &mut self,
        level: Level,
        m: Morton,
        record: &[u8],
        summary: tessera_shared::format::IndexEntry,
    ) -> anyhow::Result<()> {
        if let Some((old, differ)) = &mut self.old {
            let same = TileId::from_morton(level, m)
                .and_then(|t| old.entry(t))
                .is_some_and(|e| {
                    e.length as usize == record.len()
                        && e.checksum == xxhash_rust::xxh3::xxh3_64(record)
                });
            *differ += u64::from(!same);
        }
        self.pyramid.push(level, m, record, summary)
    }

    fn top(&mut self, _m: Morton, _node: Option<Node>) -> anyhow::Result<()> {
        Ok(())
    }

    fn node(&mut self, level: Level, m: Morton, node: &Node) -> anyhow::Result<()> {
        self.state.push(level, m, node)
    }
}

/// Updates `old` to the pyramid of `inputs` at `output` (and its state).
pub fn update(
    inputs: &ingest::InputSpec,
    old: &Path,
    output: &Path,
    opts: &BuildOptions,
) -> anyhow::Result<(BuildReport, UpdateReport)> {
    let started = Instant::now();
    ensure!(
        !output.to_string_lossy().contains("://") && !old.to_string_lossy().contains("://"),
        "--update reads and writes local files (and their .state beside them)"
    );
    ensure!(
        old.canonicalize().ok() != output.canonicalize().ok() || !output.exists(),
        "{}: --update writes a new pyramid; give -o another file than the old one",
        output.display()
    );
    let pyramid = Pyramid::open_file(old).with_context(|| old.display().to_string())?;
    let state = State::open(&state::path_of(old))?;
    let old_meta = pyramid.metadata().clone();
    ensure!(
        state.content_hash == old_meta.content_hash,
        "{}: the state of another pyramid (content hash {}, {} has {})",
        state::path_of(old).display(),
        state.content_hash,
        old.display(),
        old_meta.content_hash
    );
    let _spools = ingest::remote::SpoolScope::new();
    let fetched_before = ingest::remote::fetched();
    let dir = super::output_dir(output);
    let folders = plausible::Folders {
        spool: dir.to_path_buf(),
        output: dir.to_path_buf(),
    };
    let prepared = super::prepare(inputs, &folders, 1, opts)?;
    let warnings = prepared.warnings.clone();
    let geometry = prepared.geometry;
    let records = input_records(&prepared.input_windows)?;
    refuse_other_options(old, &old_meta, &prepared.meta)?;
    let whole = |why: String| -> anyhow::Result<(BuildReport, UpdateReport)> {
        tracing::info!("building the whole pyramid: {why}");
        let report = super::build_inputs(
            inputs,
            output,
            &BuildOptions {
                state: true,
                ..opts.clone()
            },
        )?;
        Ok((report, UpdateReport::Whole(why)))
    };
    if let Some(why) = cannot_update(&old_meta, &prepared.meta, &geometry, &state, &records, opts)
        .or_else(|| {
            prepared
                .support
                .is_some()
                .then(|| "the pyramid is multi-resolution".into())
        })
    {
        drop(prepared);
        return whole(why);
    }
    let area = changed_area(&state.inputs, &records, prepared.resampled);
    let changed = changed_tiles(&geometry, &area);
    let finest_tiles = super::count_tiles(&geometry, std::iter::once(geometry.finest()));
    if changed.len() as u64 * 2 > finest_tiles {
        drop(prepared);
        return whole(format!(
            "{} of the {finest_tiles} finest tiles changed: a whole build reads and encodes \
             them as fast and in parallel",
            changed.len()
        ));
    }
    let dirty = dirty_ranges(&geometry, &area, &changed);
    // Only the changed area is read: every other sample a re-measured tile needs is
    // in the old pyramid's finest records (`composite`).
    let footprint = super::share::footprint::Footprint {
        windows: area
            .iter()
            .filter_map(|&[x0, y0, x1, y1]| {
                let (x1, y1) = (x1.min(geometry.width()), y1.min(geometry.height()));
                (x0 < x1 && y0 < y1).then_some(super::share::footprint::Window {
                    x: x0..x1,
                    y: y0..y1,
                })
            })
            .collect(),
        points: Vec::new(),
    };
    let (loaded, samples) = match prepared.load_share(dir, &footprint, opts, started)? {
        Ok((loaded, samples)) => (loaded, samples.unwrap_or(0)),
        Err(why) => return whole(why),
    };
    ensure!(
        loaded.meta.quantization == old_meta.quantization,
        "{}: its heights are stored as {:?}, this build's as {:?} (--scale, --offset, \
         --height-range): give the options it was built with, or build without --update",
        old.display(),
        old_meta.quantization,
        loaded.meta.quantization
    );
    let mut pyramid_out =
        super::create_output(output, geometry, super::meta_reserve(&loaded.meta))?;
    let mut state_out = StateWriter::create(&state::path_of(output), geometry)?;
    let tiles_bar = bar(
        opts.progress,
        super::count_tiles(&geometry, geometry.levels()),
        "updating",
    );
    let composite = composite::Composite::new(geometry, loaded.dem.raster(), &pyramid, &area);
    let mut u = Updater {
        g: geometry,
        old: &pyramid,
        state: &state,
        dirty: &dirty,
        changed: &changed,
        area: &area,
        raster: &composite,
        quant: loaded.meta.quantization,
        agg: Aggregator::new(geometry, Level::ROOT, &tiles_bar, None),
        copied: 0,
        copied_range: (u16::MAX, 0),
        measured: 0,
        opts,
        dirty_finest: dirty
            .iter()
            .flat_map(Clone::clone)
            .filter(|&c| {
                geometry.is_present(
                    TileId::from_morton(geometry.finest(), Morton::from_raw(c)).expect("c < 4^L"),
                )
            })
            .collect(),
        ready: std::collections::VecDeque::new(),
        batch: loaded.plan.batch.max(1),
    };
    let mut sink = StateSink {
        pyramid: &mut pyramid_out,
        state: &mut state_out,
        old: Some((&pyramid, 0)),
    };
    u.visit(&mut sink, Level::ROOT, Morton::from_raw(0))?;
    let differ = sink.old.map_or(0, |(_, d)| d);
    tiles_bar.finish_and_clear();
    let copied = u.copied;
    let (min_q, max_q) = (
        u.agg.min_q.min(u.copied_range.0),
        u.agg.max_q.max(u.copied_range.1),
    );
    let quant = u.quant;
    let mut meta = loaded.meta.clone();
    meta.min_height = quant.height(min_q);
    meta.max_height = quant.height(max_q);
    meta.level_counts = super::level_counts(&geometry, &loaded.dem.raster().depth_counts());
    let report = super::finish_output(pyramid_out, meta, &geometry, opts, started)?;
    state_out.finish(&report.metadata.content_hash, records)?;
    Ok((
        BuildReport {
            warnings,
            fetched: ingest::remote::fetched().since(fetched_before),
            ..report
        },
        UpdateReport::Updated {
            measured: u.measured,
            rewritten: differ,
            copied,
            samples,
        },
    ))
}

/// Refuses an update whose options differ from the old pyramid's: another tile size,
/// CRS (`--to`, `--crs`) or vertical datum (`--vertical-datum`, `--to-vertical`).
/// (Another quantization is refused once it is known, after the reading.) A user who
/// means a new pyramid builds without `--update`.
fn refuse_other_options(
    old_path: &Path,
    old: &tessera_shared::Metadata,
    new: &tessera_shared::Metadata,
) -> anyhow::Result<()> {
    let hint = "give the options it was built with, or build without --update";
    ensure!(
        old.tile_size == new.tile_size,
        "{}: built with --tile-size {}, this build asks for {}: {hint}",
        old_path.display(),
        old.tile_size,
        new.tile_size
    );
    let crs = |m: &tessera_shared::Metadata| {
        m.georef
            .as_ref()
            .map(|g| (g.epsg, g.proj.clone(), g.wkt.clone(), g.crs_name.clone()))
    };
    ensure!(
        crs(old) == crs(new),
        "{}: its grid is in {}, this build's in {} (--to, --crs, or other inputs): {hint}",
        old_path.display(),
        crs_name(old),
        crs_name(new)
    );
    ensure!(
        old.vertical_datum == new.vertical_datum,
        "{}: its heights are in {}, this build's in {} (--vertical-datum, \
         --to-vertical): {hint}",
        old_path.display(),
        old.vertical_datum.name(),
        new.vertical_datum.name()
    );
    Ok(())
}

fn crs_name(m: &tessera_shared::Metadata) -> String {
    m.georef
        .as_ref()
        .and_then(|g| {
            g.epsg
                .map(|e| format!("EPSG:{e}"))
                .or_else(|| g.crs_name.clone())
        })
        .unwrap_or_else(|| "no named CRS".into())
}

/// Why `old` cannot be updated to the pyramid `new` describes: `None` when it can.
fn cannot_update(
    old: &tessera_shared::Metadata,
    new: &tessera_shared::Metadata,
    g: &TileGeometry,
    state: &State,
    records: &[InputRecord],
    opts: &BuildOptions,
) -> Option<String> {
    if (old.width, old.height) != (g.width(), g.height())
        || (state.width, state.height) != (g.width(), g.height())
    {
        return Some(format!(
            "the grid changed ({}×{} samples in tiles of {}, was {}×{} in tiles of {})",
            g.width(),
            g.height(),
            g.tile_size(),
            old.width,
            old.height,
            old.tile_size
        ));
    }
    if old.georef != new.georef {
        return Some("the georeferencing changed (the inputs reach elsewhere)".into());
    }
    if old.generator != new.generator {
        return Some(format!(
            "the old pyramid was built by {}, this is {}",
            old.generator, new.generator
        ));
    }
    if old.nodata_count > 0 {
        return Some(format!(
            "the old pyramid has {} no-data samples, filled from their nearest valid sample across the input",
            old.nodata_count
        ));
    }
    if opts.feather.is_some() {
        return Some("--feather blends across inputs' edges".into());
    }
    // The inputs both lists hold must keep their order (it decides who wins in overlaps).
    let position: HashMap<&str, usize> = records
        .iter()
        .enumerate()
        .map(|(i, r)| (r.path.as_str(), i))
        .collect();
    let kept: Vec<usize> = state
        .inputs
        .iter()
        .filter_map(|r| position.get(r.path.as_str()).copied())
        .collect();
    if kept.windows(2).any(|w| w[0] > w[1]) {
        return Some("the inputs' order changed".into());
    }
    None
}

struct Updater<'a> {
    g: TileGeometry,
    old: &'a Pyramid<FileSource>,
    state: &'a State,
    /// Finest Morton ranges to measure again (sorted, disjoint): tiles whose samples
    /// or whose coarse cells' corners changed.
    dirty: &'a [std::ops::Range<u64>],
    /// The finest tiles whose samples changed (sorted), and the changed area.
    changed: &'a [u64],
    area: &'a [[u32; 4]],
    raster: &'a dyn ingest::raster::Raster,
    quant: tessera_shared::Quantization,
    agg: Aggregator<'a>,
    copied: u64,
    copied_range: (u16, u16),
    measured: u64,
    opts: &'a BuildOptions,
    /// The present finest tiles to measure again, in Morton order.
    dirty_finest: Vec<u64>,
    /// Finest tiles measured ahead, in parallel batches of `batch`, in Morton order.
    ready: std::collections::VecDeque<(u64, Node, super::node::Encoded)>,
    batch: usize,
}

impl Updater<'_> {
    /// Whether a finest descendant of the level-`level` tile `m` is to be measured
    /// again.
    fn changed(&self, level: Level, m: Morton) -> bool {
        let d = 2 * u32::from(self.g.finest().get() - level.get());
        let (a, b) = (m.get() << d, (m.get() + 1) << d);
        let i = self.dirty.partition_point(|r| r.end <= a);
        i < self.dirty.len() && self.dirty[i].start < b
    }

    /// The tile `m` of `level`, in Morton order: its subtree copied if nothing in it
    /// changed, else re-encoded (a finest tile from the samples read, a coarse one from
    /// its children).
    fn visit(&mut self, sink: &mut StateSink<'_>, level: Level, m: Morton) -> anyhow::Result<()> {
        self.opts.interrupt.check()?;
        let tile = TileId::from_morton(level, m).expect("m < 4^level");
        if !self.g.is_present(tile) {
            return self.agg.push_node(sink, level, m, None);
        }
        if !self.changed(level, m) {
            self.copy_subtree(sink, level, m)?;
            let node = self.node_from_old(level, m)?;
            return self.agg.push_node(sink, level, m, Some(node));
        }
        if level == self.g.finest() {
            let (node, enc) = self.measure(m)?;
            self.measured += 1;
            return self.agg.push(sink, level, m, Some((node, enc)));
        }
        let child = level.finer().expect("above the finest level");
        for q in 0..4 {
            self.visit(sink, child, Morton::from_raw(4 * m.get() + q))?;
        }
        Ok(())
    }

    /// The finest tile `m`, measured and encoded: from the batch measured ahead, or
    /// with the next batch (the tiles from `m` on, in parallel).
    fn measure(&mut self, m: Morton) -> anyhow::Result<(Node, super::node::Encoded)> {
        if self.ready.front().map(|r| r.0) != Some(m.get()) {
            self.ready.clear();
            let start = self.dirty_finest.partition_point(|&c| c < m.get());
            let end = (start + self.batch).min(self.dirty_finest.len());
            let this = &*self;
            let measured: Vec<_> = this.dirty_finest[start..end]
                .par_iter()
                .map(|&c| {
                    let node = this.measure_one(Morton::from_raw(c))?;
                    let enc = encode(&node, &this.g, this.g.finest());
                    Ok((c, node, enc))
                })
                .collect::<anyhow::Result<_>>()?;
            self.ready.extend(measured);
        }
        let (c, node, enc) = self
            .ready
            .pop_front()
            .context("a dirty tile was not measured")?;
        ensure!(c == m.get(), "finest tiles measured out of order");
        Ok((node, enc))
    }

    /// Measures finest tile `m`: whole if its samples changed; else from its old
    /// record and state entry, measuring again only the spacings whose cell around it
    /// has a corner in the changed area.
    fn measure_one(&self, m: Morton) -> anyhow::Result<Node> {
        let g = &self.g;
        let tile = TileId::from_morton(g.finest(), m).expect("m < 4^L");
        if self.changed.binary_search(&m.get()).is_ok() {
            return finest_node(self.raster, g, tile, self.agg.spacings, &self.quant);
        }
        let mut node = self.node_from_old(g.finest(), m)?;
        let (gx0, gy0) = g.origin(tile);
        let (last_x, last_y) = (u64::from(g.width() - 1), u64::from(g.height() - 1));
        let moved = |k: u32| {
            let s = 1u64 << k;
            let (cx, cy) = (gx0 / s * s, gy0 / s * s);
            [(cx, cy), (cx + s, cy), (cx, cy + s), (cx + s, cy + s)]
                .iter()
                .any(|&(x, y)| {
                    let (x, y) = (x.min(last_x) as u32, y.min(last_y) as u32);
                    self.area
                        .iter()
                        .any(|&[x0, y0, x1, y1]| (x0..x1).contains(&x) && (y0..y1).contains(&y))
                })
        };
        let t = g.tile_log2();
        let corners = super::finest::coarse_corners(self.raster, g, gx0, gy0, self.agg.spacings)?;
        let errors = super::mesh_error::finest_tile_errors_at(
            &node.heights,
            t,
            gx0,
            gy0,
            &corners,
            self.agg.spacings,
            |k| k > t && moved(k),
        );
        for k in (t + 1..self.agg.spacings).filter(|&k| moved(k)) {
            for by in 0..BLOCKS {
                for bx in 0..BLOCKS {
                    *node.errors.slot_mut(k, bx, by) =
                        f64::from(super::node::to_metres(errors.get(k, bx, by), &self.quant));
                }
            }
        }
        Ok(node)
    }

    /// Copies the records (and state entries) of the subtree of tile `m` of `level`.
    fn copy_subtree(
        &mut self,
        sink: &mut StateSink<'_>,
        level: Level,
        m: Morton,
    ) -> anyhow::Result<()> {
        for l in level.get()..=self.g.finest().get() {
            let lvl = Level::new(l).expect("a level of the pyramid");
            let d = 2 * u32::from(l - level.get());
            for code in m.get() << d..(m.get() + 1) << d {
                let tile = TileId::from_morton(lvl, Morton::from_raw(code)).expect("code < 4^l");
                let Some(&entry) = self.old.entry(tile) else {
                    continue;
                };
                if entry.length == 0 {
                    continue;
                }
                let record = self
                    .old
                    .read_record(tile)?
                    .context("an index entry without its record")?;
                sink.pyramid
                    .push(lvl, Morton::from_raw(code), &record, entry)?;
                let values = self.state.values(lvl, Morton::from_raw(code))?;
                sink.state.copy(lvl, Morton::from_raw(code), &values)?;
                self.copied += 1;
                self.copied_range = (
                    self.copied_range.0.min(entry.min),
                    self.copied_range.1.max(entry.max),
                );
                self.agg.bar.inc(1);
            }
        }
        Ok(())
    }

    /// The node the whole build held for tile `m` of `level`: heights, mask and block
    /// ranges from its record, errors from its record and its state entry.
    fn node_from_old(&self, level: Level, m: Morton) -> anyhow::Result<Node> {
        let tile = TileId::from_morton(level, m).expect("m < 4^level");
        let rec = self.old.read_tile(tile)?.with_context(|| {
            format!(
                "tile {m:?} of level {} has no record (no-data?)",
                level.get()
            )
        })?;
        let t = self.g.tile_log2();
        let below = u32::from(self.g.finest().get() - level.get());
        let mut node = Node {
            heights: rec.heights,
            errors: BlockErrors::zeros(self.agg.spacings as usize),
            min: [u16::MAX; 64],
            max: [0; 64],
            mask: rec.mask,
        };
        for n in 0..=t {
            for by in 0..BLOCKS {
                for bx in 0..BLOCKS {
                    *node.errors.slot_mut(t - n + below, bx, by) =
                        f64::from(rec.errors.error(n, bx, by));
                }
            }
        }
        for by in 0..BLOCKS {
            for bx in 0..BLOCKS {
                let (lo, hi) = rec.errors.block_range(bx, by);
                let i = (by * BLOCKS + bx) as usize;
                node.min[i] = lo;
                node.max[i] = hi;
            }
        }
        State::restore(&self.g, level, &self.state.values(level, m)?, &mut node)?;
        Ok(node)
    }
}
