//! `tessera-server verify`: structure and every record's checksum
//! (docs/ARCHITECTURE.md#corrupt-records-are-detected). A DEM pyramid is checked here; an
//! imagery pyramid by [`imagery`].

pub mod imagery;

use rayon::prelude::*;
use std::path::Path;
use tessera_shared::codec::TileRecord;
use tessera_shared::format::{self, IndexEntry};
use tessera_shared::reader::{FileSource, ReadError};
use tessera_shared::{Pyramid, TileId, codec};

/// What `records_offset` is a multiple of (FORMAT.md "Layout").
pub const RECORDS_ALIGN: u64 = 4096;

/// What verification found.
#[derive(Debug, Default)]
pub struct VerifyReport {
    pub tiles: u64,
    pub bytes: u64,
    /// One line per bad tile, naming it and the problem.
    pub bad: Vec<(TileId, String)>,
    /// Problems of the file as a whole (header, metadata, content hash).
    pub problems: Vec<String>,
}

impl VerifyReport {
    pub fn is_ok(&self) -> bool {
        self.bad.is_empty() && self.problems.is_empty()
    }
}

/// Opens `path` (checking the header checksum, metadata and index structure), then
/// checks every byte that can be checked (docs/ARCHITECTURE.md#nothing-partial): each
/// record's checksum and decoding, every stored value's range (finite, non-negative
/// errors; min ≤ max; the index's summary equal to its record's), the reserved flags, and
/// the metadata against the records (content hash recomputed, heights equal to the
/// quantized extremes). Structural damage is an `Err`; everything else is listed in the
/// report.
pub fn verify(path: &Path) -> Result<VerifyReport, ReadError> {
    // An imagery pyramid (`.tessimg`) has its own record checks.
    if imagery::is_imagery(path)? {
        return imagery::verify(path);
    }
    let p = Pyramid::open_file(path)?;
    let g = *p.geometry();
    let tiles: Vec<TileId> = g
        .levels()
        .flat_map(|l| g.present_tiles(l).collect::<Vec<_>>())
        .collect();
    let results: Vec<(TileId, u64, Vec<String>)> = tiles
        .par_iter()
        .map(|&tile| {
            let entry = p.entry(tile).copied();
            match p.read_record(tile) {
                Ok(Some(bytes)) => {
                    let problems = match (codec::decode_record(&bytes, p.record_layout()), entry) {
                        (Ok(record), Some(e)) => record_problems(&record, &e),
                        (Err(e), _) => vec![format!("does not decode: {e}")],
                        (Ok(_), None) => vec!["missing from the index".into()],
                    };
                    (tile, bytes.len() as u64, problems)
                }
                // From format v2 a tile inside the DEM is absent when it is wholly
                // no-data (FORMAT.md "Validity mask").
                Ok(None) if p.record_layout().has_mask() => (tile, 0, Vec::new()),
                Ok(None) => (tile, 0, vec!["missing from the index".into()]),
                Err(ReadError::RecordChecksum { .. }) => {
                    (tile, 0, vec!["checksum mismatch".into()])
                }
                Err(e) => (tile, 0, vec![e.to_string()]),
            }
        })
        .collect();
    let mut report = VerifyReport {
        problems: file_problems(&p),
        ..VerifyReport::default()
    };
    for (tile, bytes, problems) in results {
        report.tiles += 1;
        report.bytes += bytes;
        for problem in problems {
            report.bad.push((tile, problem));
        }
    }
    Ok(report)
}

/// A decoded record against itself and its index entry.
fn record_problems(record: &TileRecord, e: &IndexEntry) -> Vec<String> {
    let mut out = Vec::new();
    let table = &record.errors;
    let t = table.tile_log2();
    let bad_errors = (0..=t)
        .flat_map(|n| table.level_errors(n).iter())
        .filter(|v| !(v.is_finite() && **v >= 0.0))
        .count();
    if bad_errors > 0 {
        out.push(format!(
            "error table holds {bad_errors} values that are not finite non-negative metres"
        ));
    }
    let (tmin, tmax) = table.tile_range();
    if tmin > tmax {
        out.push(format!(
            "error table's height range is empty ({tmin} > {tmax})"
        ));
    }
    let (hmin, hmax) = record
        .heights
        .iter()
        .fold((u16::MAX, 0u16), |(lo, hi), &q| (lo.min(q), hi.max(q)));
    // The table's ranges cover the finest samples under each block; a coarse tile's
    // heights are a decimation of those, so they lie inside (equal at the finest level).
    if hmin < tmin || hmax > tmax {
        out.push(format!(
            "heights span {hmin}..={hmax}, outside the error table's {tmin}..={tmax}"
        ));
    }
    if (e.min, e.max) != (tmin, tmax) {
        out.push(format!(
            "index says heights {}..={} but the record holds {tmin}..={tmax}",
            e.min, e.max
        ));
    }
    if !(e.full_res_error.is_finite() && e.full_res_error >= 0.0) {
        out.push(format!(
            "index error {} is not a finite non-negative number of metres",
            e.full_res_error
        ));
    } else if e.full_res_error != table.full_resolution_error() {
        out.push(format!(
            "index error {} differs from the record's {}",
            e.full_res_error,
            table.full_resolution_error()
        ));
    }
    let partial = !record.mask.is_all_valid();
    if record.mask.is_none_valid() {
        out.push("record is stored but its mask has no terrain cell".into());
    }
    if (e.flags & format::FLAG_PARTIAL != 0) != partial {
        out.push(format!(
            "index flags {:#x} disagree with the mask ({} of {} cells are terrain)",
            e.flags,
            record.mask.valid_cells(),
            u64::from(record.mask.side()).pow(2)
        ));
    }
    if e.flags & !format::FLAG_PARTIAL != 0 {
        out.push(format!("reserved index flags are set ({:#x})", e.flags));
    }
    out
}

/// The header's reserved fields and the metadata against the index.
fn file_problems(p: &Pyramid<FileSource>) -> Vec<String> {
    let mut out = Vec::new();
    let meta = p.metadata();
    let g = p.geometry();
    if p.header().flags != 0 {
        out.push(format!(
            "reserved header flags are set ({:#x})",
            p.header().flags
        ));
    }
    // Readers do not need it, but FORMAT.md promises it: records start on a page, so a
    // file whose header region ends elsewhere was not written by our writer.
    let records_offset = p.header().records_offset;
    if !records_offset.is_multiple_of(RECORDS_ALIGN) {
        out.push(format!(
            "records_offset {records_offset} is not a multiple of {RECORDS_ALIGN} (FORMAT.md \
             \"Layout\": the header region is zero-padded to a {RECORDS_ALIGN}-byte boundary)"
        ));
    }
    if let Err(e) = meta.check_content_hash() {
        out.push(e.to_string());
    } else {
        let checksums: Vec<u64> = g
            .levels()
            .filter_map(|l| p.index(l))
            .flat_map(|i| i.iter().filter(|e| e.is_present()).map(|e| e.checksum))
            .collect();
        let recomputed = format::content_hash(meta, p.header().version, checksums.iter());
        if recomputed != meta.content_hash {
            out.push(format!(
                "content_hash {} does not match the file's content ({recomputed})",
                meta.content_hash
            ));
        }
    }
    let q = &meta.quantization;
    if !(q.scale.is_finite() && q.scale > 0.0 && q.offset.is_finite()) {
        out.push(format!(
            "quantization scale {} / offset {} is not a positive scale and a finite offset",
            q.scale, q.offset
        ));
    }
    if !(q.max_error.is_finite() && q.max_error >= 0.0) {
        out.push(format!(
            "quantization error {} is not a finite non-negative number",
            q.max_error
        ));
    }
    // NaN compares as neither: it is a problem too.
    if meta
        .min_height
        .partial_cmp(&meta.max_height)
        .is_none_or(std::cmp::Ordering::is_gt)
    {
        out.push(format!(
            "min_height {} is above max_height {}",
            meta.min_height, meta.max_height
        ));
    }
    // The builder records the extremes of the stored records' quantized heights, every
    // level (a whole pyramid's coarse levels are decimations of its finest; a
    // multi-resolution one stores coarse-only places only at coarse levels).
    if g.levels().any(|l| p.index(l).is_some()) {
        let (lo, hi) = g
            .levels()
            .filter_map(|l| p.index(l))
            .flatten()
            .filter(|e| e.is_present())
            .fold((u16::MAX, 0u16), |(lo, hi), e| {
                (lo.min(e.min), hi.max(e.max))
            });
        let (want_lo, want_hi) = (q.height(lo), q.height(hi));
        if meta.min_height != want_lo || meta.max_height != want_hi {
            out.push(format!(
                "metadata heights {}..{} m disagree with the quantized records ({want_lo}..{want_hi} m): \
                 the quantization or the heights were changed",
                meta.min_height, meta.max_height
            ));
        }
    }
    out
}
