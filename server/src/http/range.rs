//! Parsing the HTTP `Range` request header for byte ranges (RFC 9110 §14.1–14.2).
//!
//! Only the `bytes` unit is understood. The outcome follows the RFC: a header that
//! does not parse (or names another unit) is ignored and the whole representation
//! is sent; a well-formed header none of whose ranges overlaps the representation
//! is unsatisfiable (416). Ranges are clamped to the representation and returned in
//! the order requested, unless two of them overlap or touch: then all are sorted and
//! merged (as nginx does, and RFC 9110 §14.2 allows), so that no byte is sent twice
//! and a response can never be larger than the representation plus part headers
//! (64 ranges of `0-` were 64 copies of the file before).

use http_range_header::SyntacticallyCorrectRange;
use std::num::NonZeroUsize;

/// Most range-specs accepted in one `Range` header. A request for more is rejected
/// with 416, which RFC 9110 §15.5.17 allows for "an excessive request of small or
/// overlapping ranges".
pub const MAX_RANGES: usize = 64;

/// An inclusive byte range `start..=end` inside the representation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ByteRange {
    pub start: u64,
    pub end: u64,
}

impl ByteRange {
    /// Number of bytes in the range (never zero).
    pub const fn byte_count(self) -> u64 {
        self.end - self.start + 1
    }

    /// `Content-Range` value for this range of a `size`-byte representation.
    pub fn content_range(self, size: u64) -> String {
        format!("bytes {}-{}/{size}", self.start, self.end)
    }
}

/// What a `Range` header asks of a `size`-byte representation.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum RangeRequest {
    /// Send the whole representation (no header, an invalid one, or another unit).
    Full,
    /// Send these ranges (at least one), clamped to the representation, as given.
    Partial(Vec<ByteRange>),
    /// Well-formed, but no range overlaps the representation: 416.
    Unsatisfiable,
    /// More than [`MAX_RANGES`] range-specs (this many): 416.
    TooMany(usize),
}

/// The bytes one syntactically valid range-spec selects of a `size`-byte
/// representation, if any. A position past `u64::MAX` was read as `u64::MAX`: past
/// any representation, and as a length "all of it".
fn resolve(spec: SyntacticallyCorrectRange, size: u64) -> Option<ByteRange> {
    match spec {
        SyntacticallyCorrectRange::FromStart(first) if first < size => Some(ByteRange {
            start: first,
            end: size - 1,
        }),
        SyntacticallyCorrectRange::Indexed(first, last) if first < size => Some(ByteRange {
            start: first,
            end: last.min(size - 1),
        }),
        SyntacticallyCorrectRange::FromLast(n) if n > 0 && size > 0 => Some(ByteRange {
            start: size.saturating_sub(n),
            end: size - 1,
        }),
        _ => None,
    }
}

/// Interprets the value of a `Range` header for a representation of `size` bytes.
///
/// `bytes=a-b`, `bytes=a-` and `bytes=-n` are understood, separated by commas
/// (optional whitespace around them; empty list elements are skipped). The unit
/// name is case-insensitive. `b` past the end is clamped to the last byte; a
/// suffix longer than the representation selects all of it. A zero-length
/// representation satisfies no range.
///
/// The syntax is the `http-range-header` crate's strict parser (a `+` sign, inner
/// whitespace, a reversed `a-b`, a position of more than 30 digits or more than 15
/// empty or malformed elements make the header ignored). What the ranges select,
/// the merge rule and the limit of [`MAX_RANGES`] are this module's: the crate's
/// own `validate` refuses more than two overlapping ranges, where this merges them.
pub fn parse(header: &str, size: u64) -> RangeRequest {
    // No limit of the crate's: every spec is counted, and a header over the limit
    // is still ignored when any of it does not parse.
    let Ok(specs) =
        http_range_header::parse_range_header_with_max_ranges(header, NonZeroUsize::MAX)
    else {
        return RangeRequest::Full;
    };
    let specs = specs.into_ranges();
    if specs.len() > MAX_RANGES {
        return RangeRequest::TooMany(specs.len());
    }
    let ranges: Vec<ByteRange> = specs.into_iter().filter_map(|s| resolve(s, size)).collect();
    if ranges.is_empty() {
        RangeRequest::Unsatisfiable
    } else {
        RangeRequest::Partial(coalesce(ranges))
    }
}

/// `ranges` as given if no two overlap or touch; otherwise sorted and merged.
fn coalesce(ranges: Vec<ByteRange>) -> Vec<ByteRange> {
    let mut sorted = ranges.clone();
    sorted.sort_by_key(|r| r.start);
    let disjoint = sorted
        .windows(2)
        .all(|w| w[0].end.saturating_add(1) < w[1].start);
    if disjoint {
        return ranges;
    }
    let mut merged: Vec<ByteRange> = Vec::with_capacity(sorted.len());
    for r in sorted {
        match merged.last_mut() {
            Some(last) if r.start <= last.end.saturating_add(1) => last.end = last.end.max(r.end),
            _ => merged.push(r),
        }
    }
    merged
}

#[cfg(test)]
mod tests {
    use super::*;

    fn r(start: u64, end: u64) -> ByteRange {
        ByteRange { start, end }
    }

    fn partial(v: &[(u64, u64)]) -> RangeRequest {
        RangeRequest::Partial(v.iter().map(|&(a, b)| r(a, b)).collect())
    }

    #[test]
    fn single_range() {
        assert_eq!(parse("bytes=0-499", 1000), partial(&[(0, 499)]));
        assert_eq!(parse("bytes=999-999", 1000), partial(&[(999, 999)]));
        assert_eq!(parse("Bytes=10-19", 1000), partial(&[(10, 19)]));
        assert_eq!(r(10, 19).byte_count(), 10);
        assert_eq!(r(10, 19).content_range(1000), "bytes 10-19/1000");
    }

    #[test]
    fn open_ended() {
        assert_eq!(parse("bytes=900-", 1000), partial(&[(900, 999)]));
        assert_eq!(parse("bytes=0-", 1000), partial(&[(0, 999)]));
    }

    #[test]
    fn suffix() {
        assert_eq!(parse("bytes=-100", 1000), partial(&[(900, 999)]));
        assert_eq!(parse("bytes=-1", 1000), partial(&[(999, 999)]));
    }

    #[test]
    fn suffix_longer_than_the_file_is_all_of_it() {
        assert_eq!(parse("bytes=-5000", 1000), partial(&[(0, 999)]));
        assert_eq!(
            parse("bytes=-99999999999999999999999", 1000),
            partial(&[(0, 999)])
        );
    }

    #[test]
    fn end_past_the_file_is_clamped() {
        assert_eq!(parse("bytes=500-5000", 1000), partial(&[(500, 999)]));
        assert_eq!(
            parse("bytes=0-99999999999999999999999", 1000),
            partial(&[(0, 999)])
        );
    }

    #[test]
    fn multiple_ranges_in_the_order_given() {
        assert_eq!(
            parse("bytes=500-599, 0-9,-10 ,\t20-20", 1000),
            partial(&[(500, 599), (0, 9), (990, 999), (20, 20)])
        );
        // Overlapping or touching ranges are sorted and merged.
        assert_eq!(parse("bytes=0-10,5-15", 1000), partial(&[(0, 15)]));
        assert_eq!(
            parse("bytes=20-29,0-9,10-12", 1000),
            partial(&[(0, 12), (20, 29)])
        );
        assert_eq!(parse("bytes=-10,0-,5-6", 1000), partial(&[(0, 999)]));
        // Disjoint ones keep the order they were asked in.
        assert_eq!(parse("bytes=20-29,0-9", 1000), partial(&[(20, 29), (0, 9)]));
        // Empty list elements are skipped (RFC 9110 §5.6.1).
        assert_eq!(parse("bytes=,0-1,,4-5,", 1000), partial(&[(0, 1), (4, 5)]));
        // Unsatisfiable members are dropped when another one is satisfiable.
        assert_eq!(parse("bytes=2000-2001,0-1", 1000), partial(&[(0, 1)]));
    }

    #[test]
    fn invalid_syntax_is_ignored() {
        for h in [
            "",
            "bytes",
            "bytes=",
            "bytes=,",
            "bytes=-",
            "bytes=a-b",
            "bytes=1-2-3",
            "bytes=5-1",
            "bytes=0-1,x",
            "bytes=+1-2",
            "bytes=1 -2",
            "bytes=0x10-",
            "bytes =0-1",
            "bytes=--5",
            "items=0-1",
            "0-499",
        ] {
            assert_eq!(parse(h, 1000), RangeRequest::Full, "{h:?}");
        }
    }

    #[test]
    fn unsatisfiable() {
        assert_eq!(parse("bytes=1000-", 1000), RangeRequest::Unsatisfiable);
        assert_eq!(parse("bytes=1000-2000", 1000), RangeRequest::Unsatisfiable);
        assert_eq!(
            parse("bytes=5000-6000,1000-", 1000),
            RangeRequest::Unsatisfiable
        );
        assert_eq!(
            parse("bytes=99999999999999999999999-", 1000),
            RangeRequest::Unsatisfiable
        );
        assert_eq!(parse("bytes=-0", 1000), RangeRequest::Unsatisfiable);
        assert_eq!(parse("bytes=0-0", 0), RangeRequest::Unsatisfiable);
        assert_eq!(parse("bytes=-5", 0), RangeRequest::Unsatisfiable);
    }

    #[test]
    fn repeated_whole_file_ranges_are_one_range() {
        let h = format!("bytes={}", vec!["0-"; MAX_RANGES].join(","));
        assert_eq!(parse(&h, 3_300_000), partial(&[(0, 3_299_999)]));
    }

    #[test]
    fn too_many_ranges() {
        let at_cap: Vec<String> = (0..MAX_RANGES)
            .map(|i| format!("{}-{}", 2 * i, 2 * i))
            .collect();
        assert!(matches!(
            parse(&format!("bytes={}", at_cap.join(",")), 1000),
            RangeRequest::Partial(v) if v.len() == MAX_RANGES
        ));
        let over = vec!["0-0"; MAX_RANGES + 1].join(",");
        assert_eq!(
            parse(&format!("bytes={over}"), 10),
            RangeRequest::TooMany(MAX_RANGES + 1)
        );
        // Syntax is still checked first: an invalid header is ignored.
        assert_eq!(parse(&format!("bytes={over},oops"), 10), RangeRequest::Full);
    }
}
