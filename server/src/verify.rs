//! `tessera-server verify`: structure and every record's checksum (DESIGN §6 invariant 6).

use rayon::prelude::*;
use std::path::Path;
use tessera_shared::reader::ReadError;
use tessera_shared::{Pyramid, TileId, codec};

/// What verification found.
#[derive(Debug, Default)]
pub struct VerifyReport {
    pub tiles: u64,
    pub bytes: u64,
    /// One line per bad tile, naming it and the problem.
    pub bad: Vec<(TileId, String)>,
}

/// Opens `path` (checking the header, metadata and index structure), then reads,
/// checksums and decodes every record. Structural damage is an `Err`; bad records
/// are listed in the report.
pub fn verify(path: &Path) -> Result<VerifyReport, ReadError> {
    let p = Pyramid::open_file(path)?;
    let g = *p.geometry();
    let tiles: Vec<TileId> = g
        .levels()
        .flat_map(|l| g.present_tiles(l).collect::<Vec<_>>())
        .collect();
    let results: Vec<(TileId, u64, Option<String>)> = tiles
        .par_iter()
        .map(|&tile| match p.read_record(tile) {
            Ok(Some(bytes)) => {
                let problem = codec::decode_record(&bytes, g.tile_log2())
                    .err()
                    .map(|e| format!("does not decode: {e}"));
                (tile, bytes.len() as u64, problem)
            }
            Ok(None) => (tile, 0, Some("missing from the index".into())),
            Err(ReadError::RecordChecksum { .. }) => (tile, 0, Some("checksum mismatch".into())),
            Err(e) => (tile, 0, Some(e.to_string())),
        })
        .collect();
    let mut report = VerifyReport::default();
    for (tile, bytes, problem) in results {
        report.tiles += 1;
        report.bytes += bytes;
        if let Some(p) = problem {
            report.bad.push((tile, p));
        }
    }
    Ok(report)
}
