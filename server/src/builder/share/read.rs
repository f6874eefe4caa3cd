//! Reading only a part's share of the input ([`super::footprint`]) into a spool of
//! the whole raster's layout, sparse: what is not read takes no disk and is never
//! asked for.
//!
//! The result is the whole build's only when nothing the part reads depends on
//! samples it does not read. Two things do, and the part then reads the whole input
//! instead, saying why:
//! - **No-data.** A void takes the value of its nearest valid sample, filled band by
//!   band from the top of the input (`spool.rs`), so its value depends on rows far
//!   above. A share with no void is exact.
//! - **Floating-point samples** are quantized over the input's height range, which
//!   only a whole read knows, unless `--height-range` states it (checked against
//!   every sample read). Integer samples are stored exactly, needing no range.

use crate::builder::share::footprint::Footprint;
use crate::builder::spool::{RawQuantizer, SPOOL_BUFFER, StatedRange};
use crate::ingest::RowSource;
use anyhow::Context;
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::Path;

/// What reading a share gave.
pub(crate) enum Share {
    /// The share's samples, in a sparse spool file of `width × height` raw `f32`.
    Read { file: File, samples: u64 },
    /// The share cannot stand alone: why.
    Whole(String),
}

/// Why a part of this input reads the whole of it, before a sample is read; `None`
/// when a share will do (unless it meets a void).
pub(crate) fn needs_whole(rows: &dyn RowSource, stated: Option<&StatedRange>) -> Option<String> {
    (!rows.info().sample_type.is_integer() && stated.is_none()).then(|| {
        "its samples are floating-point, quantized over the whole input's height range: \
         give --height-range for each part to read only its share"
            .to_string()
    })
}

/// The quantizer a share is read with: the one the whole build uses.
pub(crate) fn quantizer(rows: &dyn RowSource, stated: Option<&StatedRange>) -> RawQuantizer {
    let t = rows.info().sample_type;
    match stated {
        Some(r) if !t.is_integer() => r.quantizer(),
        _ => RawQuantizer::exact(t),
    }
}

/// Reads `footprint` of `rows` (from its first row) into a sparse spool in `dir`.
/// `nodata` overrides the source's own no-data value; `band_bytes` bounds the rows
/// held at once; `check` is called between bands (interrupts).
pub(crate) fn read(
    rows: &mut dyn RowSource,
    footprint: &Footprint,
    dir: &Path,
    nodata: Option<f64>,
    stated: Option<&StatedRange>,
    band_bytes: usize,
    mut check: impl FnMut() -> anyhow::Result<()>,
) -> anyhow::Result<Share> {
    let info = rows.info().clone();
    let w = info.width as usize;
    let nodata = nodata.or(info.nodata).map(|v| v as f32);
    let file = tempfile::tempfile_in(dir)
        .with_context(|| format!("cannot create a temporary file in {}", dir.display()))?;
    file.set_len(4 * w as u64 * u64::from(info.height))
        .context("cannot size the spooled share")?;
    let band_rows = (band_bytes / (4 * w)).max(1);
    let mut band = Vec::new();
    let mut bytes = Vec::with_capacity(SPOOL_BUFFER);
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    let mut row = 0u32;
    let mut samples = 0u64;
    for run in footprint.runs() {
        if run.rows.start > row {
            rows.skip_rows(run.rows.start - row)?;
            row = run.rows.start;
        }
        rows.set_window(&run.columns, run.rows.end)?;
        while row < run.rows.end {
            check()?;
            let n = band_rows.min((run.rows.end - row) as usize);
            band.resize(n * w, 0f32);
            rows.read_rows(&mut band)?;
            for (i, line) in band.chunks_exact(w).enumerate() {
                let y = u64::from(row) + i as u64;
                for c in &run.columns {
                    let span = &line[c.start as usize..c.end as usize];
                    if let Some(at) = span.iter().position(|v| v.is_nan() || Some(*v) == nodata) {
                        return Ok(Share::Whole(format!(
                            "its share holds no-data (sample {}, {y}), which is filled from \
                             the nearest valid sample across the whole input",
                            c.start as usize + at
                        )));
                    }
                    bytes.clear();
                    for v in span {
                        lo = lo.min(*v);
                        hi = hi.max(*v);
                        bytes.extend_from_slice(&v.to_le_bytes());
                    }
                    file.write_all_at(&bytes, 4 * (y * w as u64 + u64::from(c.start)))
                        .context("cannot write the spooled share")?;
                    samples += span.len() as u64;
                }
            }
            row += n as u32;
        }
    }
    if let Some(r) = stated
        && !info.sample_type.is_integer()
        && samples > 0
    {
        r.check(lo, hi)?;
    }
    Ok(Share::Read { file, samples })
}
