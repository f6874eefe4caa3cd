//! Parsing `ranges=a-b,c-d,…`: inclusive Morton ranges of one level.

use super::error::ApiError;
use tessera_shared::{Level, Morton, MortonRange};

/// Limits on one request.
#[derive(Clone, Copy, Debug)]
pub struct RangeLimits {
    pub max_ranges: usize,
    pub max_tiles: u64,
}

/// Parses and checks the ranges of a request for `level`: well-formed, not
/// reversed, inside the level, not overlapping, and within the limits.
/// Returns them sorted by start.
pub fn parse_ranges(
    spec: Option<&str>,
    level: Level,
    limits: RangeLimits,
) -> Result<Vec<MortonRange>, ApiError> {
    let spec = spec.filter(|s| !s.is_empty()).ok_or_else(|| {
        ApiError::bad_request(
            "missing query parameter ranges (e.g. ranges=0-15,32-47: inclusive Morton ranges)",
        )
    })?;
    let parts: Vec<&str> = spec.split(',').collect();
    if parts.len() > limits.max_ranges {
        return Err(ApiError::bad_request(format!(
            "{} ranges requested; at most {} per request",
            parts.len(),
            limits.max_ranges
        )));
    }
    let slots = level.tile_slots();
    let mut ranges = Vec::with_capacity(parts.len());
    for p in parts {
        let (a, b) = match p.split_once('-') {
            Some((a, b)) => (a, b),
            None => (p, p),
        };
        // Digits only: `u64::from_str` would also take a sign (`+5`), and trimming
        // would take a decoded space (`%205`), so one range could be spelled many
        // ways and caches would see different URLs for the same request.
        let parse = |s: &str| {
            let malformed = || {
                ApiError::bad_request(format!(
                    "malformed range {p:?}: want START-END or CODE, decimal digits only"
                ))
            };
            if s.is_empty() || !s.bytes().all(|b| b.is_ascii_digit()) {
                return Err(malformed());
            }
            s.parse::<u64>().map_err(|_| malformed())
        };
        let (a, b) = (parse(a)?, parse(b)?);
        let r = MortonRange::new(Morton::from_raw(a), Morton::from_raw(b))
            .map_err(|e| ApiError::bad_request(format!("range {p:?}: {e}")))?;
        if b >= slots {
            return Err(ApiError::bad_request(format!(
                "range {p:?} is outside level {level}, whose Morton codes are 0-{}",
                slots - 1
            )));
        }
        ranges.push(r);
    }
    ranges.sort();
    for w in ranges.windows(2) {
        if w[1].start() <= w[0].end() {
            return Err(ApiError::bad_request(format!(
                "ranges {} and {} overlap",
                w[0], w[1]
            )));
        }
    }
    let tiles: u64 = ranges.iter().map(|r| r.len()).sum();
    if tiles > limits.max_tiles {
        return Err(ApiError::bad_request(format!(
            "{tiles} tiles requested; at most {} per request",
            limits.max_tiles
        )));
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

    fn parse(s: &str) -> Result<Vec<String>, String> {
        parse_ranges(Some(s), Level::new(3).unwrap(), LIMITS)
            .map(|v| v.iter().map(ToString::to_string).collect())
            .map_err(|e| e.message)
    }

    #[test]
    fn good_ranges_come_back_sorted() {
        assert_eq!(parse("20-30,0-3,7").unwrap(), ["0-3", "7-7", "20-30"]);
    }

    #[test]
    fn bad_ranges_say_why() {
        assert!(parse("5-2").unwrap_err().contains("reversed"));
        assert!(parse("a-b").unwrap_err().contains("malformed"));
        assert!(parse("1-2-3").unwrap_err().contains("malformed"));
        for sloppy in ["+5", " 5", "5 ", "0-+3", "1- 2", "-3", "3-", "0x1", "1_0"] {
            let e = parse(sloppy).unwrap_err();
            assert!(
                e.contains("malformed") && e.contains("digits only"),
                "{sloppy:?}: {e}"
            );
        }
        assert!(parse("0-64").unwrap_err().contains("outside level 3"));
        assert!(parse("0-10,5-6").unwrap_err().contains("overlap"));
        assert!(parse("1,2,3,4,5").unwrap_err().contains("at most 4"));
        let err = parse_ranges(Some("0-63,"), Level::new(3).unwrap(), LIMITS).unwrap_err();
        assert!(err.message.contains("malformed"));
        let lim = RangeLimits {
            max_ranges: 4,
            max_tiles: 10,
        };
        let err = parse_ranges(Some("0-63"), Level::new(3).unwrap(), lim).unwrap_err();
        assert!(err.message.contains("64 tiles requested"));
        assert!(
            parse_ranges(None, Level::ROOT, LIMITS)
                .unwrap_err()
                .message
                .contains("missing")
        );
    }
}
