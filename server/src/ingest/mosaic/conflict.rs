//! The error for inputs that disagree where they overlap (`--overlap error`).

use super::{OpenPiece, Piece, crs_text};
use tessera_shared::GeoRef;

/// The error for two inputs that disagree at mosaic sample `(col, row)`: `kept` came
/// from one of the `earlier` open pieces, `new` from piece `later`.
#[allow(clippy::too_many_arguments)]
pub(super) fn conflict(
    pieces: &[Piece],
    georef: Option<&GeoRef>,
    earlier: &[OpenPiece],
    later: usize,
    (col, row): (u32, u32),
    kept: f32,
    new: f32,
) -> anyhow::Error {
    let other = earlier
        .iter()
        .find(|o| {
            let p = &pieces[o.index];
            (p.x..p.x + p.w).contains(&col) && o.row[(p.src_x + col - p.x) as usize] == kept
        })
        .map_or("an earlier input", |o| pieces[o.index].name.as_str());
    let at = georef.map_or_else(String::new, |g| {
        let gt = &g.geotransform;
        let x = gt[0] + (f64::from(col) + 0.5) * gt[1];
        let y = gt[3] + (f64::from(row) + 0.5) * gt[5];
        format!(" ({} {x}, {y})", crs_text(g))
    });
    anyhow::anyhow!(
        "{other} and {} disagree at sample (col {col}, row {row}){at}: {kept} vs {new} \
         (choose with --overlap first|last|finest)",
        pieces[later].name
    )
}
