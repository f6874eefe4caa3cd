//! The vertical datum of a mosaic's inputs together: the one they state, or an error
//! naming two that differ.

use super::Piece;
use crate::ingest::DatumClue;
use anyhow::bail;
use tessera_shared::VerticalDatum;

/// The datum the pieces state, when those that state one agree (pieces that state
/// nothing do not count), with where it is stated. Pieces in different datums cannot
/// be mixed: an error naming two of them and the flag that converts them. A piece that
/// names a datum the metadata cannot record leaves it unknown and says so.
pub(super) fn agreed_datum(pieces: &[Piece]) -> anyhow::Result<Option<DatumClue>> {
    let mut stating = pieces.iter().filter_map(|p| Some((p, p.datum.as_ref()?)));
    let Some((first, clue)) = stating.next() else {
        return Ok(None);
    };
    let count = 1 + stating.clone().count();
    let says = |c: &DatumClue| c.datum.map_or("another datum", VerticalDatum::name);
    if let Some((other, o)) = stating.clone().find(|(_, c)| c.datum != clue.datum) {
        if clue.datum.is_some() && o.datum.is_some() {
            bail!(
                "{} and {}: heights in different vertical datums (the first says {} ({}), the \
                 second says {} ({})): convert them to one with --to-vertical \
                 egm96|egm2008|ellipsoid, or say what they are with --vertical-datum",
                first.name,
                other.name,
                says(clue),
                clue.why,
                says(o),
                o.why
            );
        }
        return Ok(Some(DatumClue {
            datum: None,
            why: format!(
                "the inputs disagree: {} says {} ({}), {} says {} ({})",
                first.name,
                says(clue),
                clue.why,
                other.name,
                says(o),
                o.why
            ),
        }));
    }
    if pieces.len() == 1 {
        return Ok(Some(clue.clone()));
    }
    let whose = if count == pieces.len() {
        format!("all {count} inputs")
    } else {
        format!(
            "{count} of {} inputs, the others stating none",
            pieces.len()
        )
    };
    Ok(Some(DatumClue {
        datum: clue.datum,
        why: format!("{whose}, e.g. {}: {}", first.name, clue.why),
    }))
}
