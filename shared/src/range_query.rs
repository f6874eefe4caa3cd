//! The `ranges=` query of the Morton-range endpoints (API.md): inclusive Morton
//! ranges of one level, `a-b,c-d,…` (a single code `c` is `c-c`). Formatted by
//! clients and parsed by the server here, so the two sides cannot drift.
//!
//! ```
//! use tessera_shared::range_query::{RangeLimits, format, parse};
//! use tessera_shared::{Level, Morton, MortonRange};
//!
//! let level = Level::new(3).unwrap();
//! let limits = RangeLimits { max_ranges: 8, max_tiles: 64 };
//! let ranges = parse(Some("20-30,0-3,7"), level, limits).unwrap();
//! assert_eq!(format(&ranges), "0-3,7-7,20-30");
//! assert!(parse(Some("+5"), level, limits).is_err());
//! ```

use crate::morton::{Morton, MortonRange};
use crate::tile::Level;

/// Limits on one request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RangeLimits {
    pub max_ranges: usize,
    pub max_tiles: u64,
}

/// Why a `ranges=` value was refused; the text is what a client is told.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum RangeQueryError {
    #[error("missing query parameter ranges (e.g. ranges=0-15,32-47: inclusive Morton ranges)")]
    Missing,
    #[error("{0} ranges requested; at most {1} per request")]
    TooManyRanges(usize, usize),
    #[error("malformed range {0:?}: want START-END or CODE, decimal digits only")]
    Malformed(String),
    #[error("range {0:?}: {1}")]
    Invalid(String, String),
    #[error("range {range:?} is outside level {level}, whose Morton codes are 0-{last}")]
    OutsideLevel {
        range: String,
        level: Level,
        last: u64,
    },
    #[error("ranges {0} and {1} overlap")]
    Overlap(MortonRange, MortonRange),
    #[error("{0} tiles requested; at most {1} per request")]
    TooManyTiles(u64, u64),
}

/// The query value for `ranges` (comma-separated, in the order given).
pub fn format(ranges: &[MortonRange]) -> String {
    ranges
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(",")
}

/// Parses and checks the ranges of a request for `level`: well-formed, not
/// reversed, inside the level, not overlapping, and within the limits. Returns them
/// sorted by start.
pub fn parse(
    spec: Option<&str>,
    level: Level,
    limits: RangeLimits,
) -> Result<Vec<MortonRange>, RangeQueryError> {
    let spec = spec
        .filter(|s| !s.is_empty())
        .ok_or(RangeQueryError::Missing)?;
    let parts: Vec<&str> = spec.split(',').collect();
    if parts.len() > limits.max_ranges {
        return Err(RangeQueryError::TooManyRanges(
            parts.len(),
            limits.max_ranges,
        ));
    }
    let slots = level.tile_slots();
    let mut ranges = Vec::with_capacity(parts.len());
    for p in parts {
        let (a, b) = p.split_once('-').unwrap_or((p, p));
        // Digits only: `u64::from_str` would also take a sign (`+5`), and trimming
        // would take a decoded space (`%205`), so one range could be spelled many
        // ways and caches would see different URLs for the same request.
        let code = |s: &str| {
            if s.is_empty() || !s.bytes().all(|b| b.is_ascii_digit()) {
                return Err(RangeQueryError::Malformed(p.to_string()));
            }
            s.parse::<u64>()
                .map_err(|_| RangeQueryError::Malformed(p.to_string()))
        };
        let (a, b) = (code(a)?, code(b)?);
        let r = MortonRange::new(Morton::from_raw(a), Morton::from_raw(b))
            .map_err(|e| RangeQueryError::Invalid(p.to_string(), e.to_string()))?;
        if b >= slots {
            return Err(RangeQueryError::OutsideLevel {
                range: p.to_string(),
                level,
                last: slots - 1,
            });
        }
        ranges.push(r);
    }
    ranges.sort();
    if let Some(w) = ranges.windows(2).find(|w| w[1].start() <= w[0].end()) {
        return Err(RangeQueryError::Overlap(w[0], w[1]));
    }
    let tiles: u64 = ranges.iter().map(|r| r.len()).sum();
    if tiles > limits.max_tiles {
        return Err(RangeQueryError::TooManyTiles(tiles, limits.max_tiles));
    }
    Ok(ranges)
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIMITS: RangeLimits = RangeLimits {
        max_ranges: 4,
        max_tiles: 100,
    };

    fn parsed(s: &str) -> Result<Vec<String>, String> {
        parse(Some(s), Level::new(3).unwrap(), LIMITS)
            .map(|v| v.iter().map(ToString::to_string).collect())
            .map_err(|e| e.to_string())
    }

    #[test]
    fn good_ranges_come_back_sorted_and_format_round_trips() {
        assert_eq!(parsed("20-30,0-3,7").unwrap(), ["0-3", "7-7", "20-30"]);
        let level = Level::new(3).unwrap();
        let ranges = parse(Some("20-30,0-3,7"), level, LIMITS).unwrap();
        assert_eq!(
            parse(Some(&format(&ranges)), level, LIMITS).unwrap(),
            ranges
        );
    }

    #[test]
    fn bad_ranges_say_why() {
        assert!(parsed("5-2").unwrap_err().contains("reversed"));
        assert!(parsed("a-b").unwrap_err().contains("malformed"));
        assert!(parsed("1-2-3").unwrap_err().contains("malformed"));
        for sloppy in ["+5", " 5", "5 ", "0-+3", "1- 2", "-3", "3-", "0x1", "1_0"] {
            let e = parsed(sloppy).unwrap_err();
            assert!(
                e.contains("malformed") && e.contains("digits only"),
                "{sloppy:?}: {e}"
            );
        }
        assert!(parsed("0-64").unwrap_err().contains("outside level 3"));
        assert!(parsed("0-10,5-6").unwrap_err().contains("overlap"));
        assert!(parsed("1,2,3,4,5").unwrap_err().contains("at most 4"));
        let err = parse(Some("0-63,"), Level::new(3).unwrap(), LIMITS).unwrap_err();
        assert!(err.to_string().contains("malformed"));
        let lim = RangeLimits {
            max_ranges: 4,
            max_tiles: 10,
        };
        let err = parse(Some("0-63"), Level::new(3).unwrap(), lim).unwrap_err();
        assert!(err.to_string().contains("64 tiles requested"));
        assert_eq!(
            parse(None, Level::ROOT, LIMITS).unwrap_err(),
            RangeQueryError::Missing
        );
    }
}
