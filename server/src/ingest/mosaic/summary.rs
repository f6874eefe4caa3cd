//! What a mosaic tells about its inputs: each one's summary for the pyramid's
//! provenance, and the log lines of a mixed-grid placement.

use super::{Group, Piece, crs_text, file_name, warp};
use std::path::Path;

/// Each group as an [`crate::ingest::InputSummary`], in the order its pieces were placed
/// (priority order for `--overlap finest`).
pub(super) fn summaries(groups: &[Group], pieces: &[Piece]) -> Vec<crate::ingest::InputSummary> {
    let group_of: std::collections::HashMap<&Path, usize> = groups
        .iter()
        .enumerate()
        .flat_map(|(i, g)| g.pieces.iter().map(move |p| (p.path.as_path(), i)))
        .collect();
    let mut seen = vec![false; groups.len()];
    let mut order: Vec<usize> = Vec::new();
    for p in pieces {
        if let Some(&g) = group_of.get(p.path.as_path())
            && !std::mem::replace(&mut seen[g], true)
        {
            order.push(g);
        }
    }
    order
        .into_iter()
        .map(|i| {
            let g = &groups[i];
            crate::ingest::InputSummary {
                name: file_name(Path::new(&g.name)),
                georef: g.georef.clone(),
                width: g.width,
                height: g.height,
                datum: g
                    .pieces
                    .first()
                    .and_then(|p| p.datum.as_ref())
                    .and_then(|c| c.datum),
            }
        })
        .collect()
}

/// Logs how inputs on different grids were put on one.
pub(super) fn log_mixed(groups: &[Group], placed: &warp::Placed) {
    let g = &placed.georef;
    tracing::info!(
        inputs = groups.len(),
        crs = crs_text(g),
        spacing = format!("{} × {}", g.geotransform[1], -g.geotransform[5]),
        size = format!("{} × {}", placed.width, placed.height),
        "inputs on different grids: resampled onto the finest input's grid (or --to/--spacing)"
    );
    for (grp, s) in groups.iter().zip(&placed.sources) {
        tracing::info!(
            input = grp.name,
            crs = s.crs.label(),
            spacing_m = format!("{:.3} × {:.3}", s.spacing.x, s.spacing.y),
            "source"
        );
    }
}
