//! `{{meta}}`: when, where and with what the results were measured, so every
//! number in the report can be traced to a commit and a machine. A quick (smoke)
//! run is flagged first, in bold, because its numbers must not be quoted.

use crate::results::Meta;
use std::fmt::Write as _;

/// Seconds since 1970-01-01T00:00:00Z of an RFC 3339 time such as
/// `2026-11-23T10:04:05Z`, `2026-11-23T11:04:05.25+01:00` or with a space for
/// the `T`; `None` if it is not one.
pub fn parse_rfc3339(s: &str) -> Option<f64> {
    let s = s.trim();
    let b = s.as_bytes();
    if b.len() < 20 || b[4] != b'-' || b[7] != b'-' || !matches!(b[10], b'T' | b't' | b' ') {
        return None;
    }
    if b[13] != b':' || b[16] != b':' {
        return None;
    }
    let int = |r: std::ops::Range<usize>| -> Option<i64> {
        let t = s.get(r)?;
        t.bytes()
            .all(|c| c.is_ascii_digit())
            .then(|| t.parse().ok())?
    };
    let (year, month, day) = (int(0..4)?, int(5..7)?, int(8..10)?);
    let (hour, minute, second) = (int(11..13)?, int(14..16)?, int(17..19)?);
    if !(1..=12).contains(&month)
        || !(1..=31).contains(&day)
        || hour > 23
        || minute > 59
        || second > 60
    {
        return None;
    }
    let mut rest = &s[19..];
    let mut fraction = 0.0;
    if let Some(r) = rest.strip_prefix('.') {
        let digits = r.bytes().take_while(u8::is_ascii_digit).count();
        if digits == 0 {
            return None;
        }
        fraction = format!("0.{}", &r[..digits]).parse().ok()?;
        rest = &r[digits..];
    }
    let offset = match rest {
        "Z" | "z" => 0,
        _ => {
            let sign = match rest.as_bytes().first()? {
                b'+' => 1,
                b'-' => -1,
                _ => return None,
            };
            let r = &rest[1..];
            if r.len() != 5 || r.as_bytes()[2] != b':' {
                return None;
            }
            let h: i64 = r[..2].parse().ok()?;
            let m: i64 = r[3..].parse().ok()?;
            sign * (h * 3600 + m * 60)
        }
    };
    let days = days_from_civil(year, month, day);
    Some((days * 86_400 + hour * 3600 + minute * 60 + second - offset) as f64 + fraction)
}

/// Days since 1970-01-01 of a proleptic Gregorian date (Howard Hinnant's
/// `days_from_civil`).
fn days_from_civil(y: i64, m: i64, d: i64) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (m + 9) % 12;
    let doy = (153 * mp + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// "27 min 5 s", "1 h 02 min", "42 s".
fn duration(seconds: f64) -> String {
    let s = seconds.round() as i64;
    match s {
        ..60 => format!("{s} s"),
        60..3600 => format!("{} min {} s", s / 60, s % 60),
        _ => format!("{} h {:02} min", s / 3600, s % 3600 / 60),
    }
}

/// The version number in a tool's version line ("nginx version: nginx/1.22.1"
/// → "1.22.1"): the first word that starts with a digit and has a dot; the whole
/// line if there is none.
fn version(line: &str) -> String {
    line.split(|c: char| c.is_whitespace() || c == '/' || c == ',')
        .map(|w| w.trim_start_matches('v'))
        .find(|w| w.starts_with(|c: char| c.is_ascii_digit()) && w.contains('.'))
        .map_or_else(|| line.trim().to_string(), str::to_string)
}

pub fn section(meta: Option<&Meta>) -> String {
    let Some(m) = meta else {
        return "*The results have no `meta.json`: when, where and on which commit they were \
                measured is not recorded.*\n"
            .into();
    };
    let mut out = String::new();
    if m.quick {
        out.push_str(
            "> **Quick run.** These results come from a shortened smoke run of `./run bench`: \
             it shows that every benchmark works, but its numbers are not measurements to \
             quote or compare.\n\n",
        );
    }
    let took = match (parse_rfc3339(&m.started), parse_rfc3339(&m.finished)) {
        (Some(a), Some(b)) if b >= a => format!(" ({})", duration(b - a)),
        _ => String::new(),
    };
    // The runner writes "" for a tool it could not find.
    let given = |v: &Option<String>| v.clone().filter(|s| !s.trim().is_empty());
    let or_none =
        |v: &Option<String>| given(v).map_or_else(|| "not installed".into(), |s| version(&s));
    let rows = [
        ("measured", format!("{} to {}{took}", m.started, m.finished)),
        (
            "commit",
            format!(
                "`{}`{}",
                m.commit,
                if m.dirty {
                    " with uncommitted changes"
                } else {
                    ""
                }
            ),
        ),
        (
            "machine",
            format!(
                "{}, {} cores, {} GiB memory",
                m.cpu,
                m.cores,
                crate::stats::num(m.memory_gib)
            ),
        ),
        ("OS", m.os.clone()),
        ("Rust", m.rustc.clone()),
        (
            "peers",
            format!(
                "GDAL {}, nginx {}, wrk {}, oha {}",
                or_none(&m.gdal),
                or_none(&m.nginx),
                or_none(&m.wrk),
                or_none(&m.oha)
            ),
        ),
        (
            "renderer",
            given(&m.renderer).unwrap_or_else(|| "not recorded".into()),
        ),
        ("runs per measurement", m.runs.to_string()),
    ];
    out.push_str("| | |\n|---|---|\n");
    for (k, v) in rows {
        let _ = writeln!(out, "| {k} | {} |", v.replace('|', "\\|"));
    }
    if m.runs < 3 {
        let _ = writeln!(
            out,
            "\n*{} run(s) per measurement: fewer than the 3 the medians are meant to be taken over.*",
            m.runs
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta(quick: bool, runs: u32) -> Meta {
        Meta {
            started: "2026-11-23T10:00:00Z".into(),
            finished: "2026-11-23T11:27:05+01:00".into(),
            commit: "abc1234".into(),
            dirty: true,
            cpu: "AMD EPYC".into(),
            cores: 2,
            memory_gib: 24.0,
            os: "Debian 12".into(),
            rustc: "rustc 1.95.0".into(),
            gdal: Some("GDAL 3.6.2, released 2023/01/02".into()),
            nginx: Some(String::new()),
            wrk: Some("wrk 4.1.0 [epoll] Copyright (C) 2012 Will Glozer".into()),
            oha: None,
            renderer: Some("llvmpipe (LLVM 15.0.6, 256 bits)".into()),
            runs,
            quick,
        }
    }

    #[test]
    fn rfc3339_times() {
        assert_eq!(parse_rfc3339("1970-01-01T00:00:00Z"), Some(0.0));
        assert_eq!(parse_rfc3339("1970-01-02T00:00:01.5Z"), Some(86_401.5));
        assert_eq!(parse_rfc3339("2000-03-01T00:00:00Z"), Some(951_868_800.0));
        assert_eq!(
            parse_rfc3339("2026-11-23T11:00:00+01:00"),
            parse_rfc3339("2026-11-23 10:00:00Z")
        );
        assert_eq!(parse_rfc3339("2026-11-23"), None);
        assert_eq!(parse_rfc3339("2026-13-23T10:00:00Z"), None);
        assert_eq!(parse_rfc3339("2026-11-23T10:00:00"), None);
    }

    #[test]
    fn quick_runs_are_flagged_first_and_the_rest_is_tabled() {
        let s = section(Some(&meta(true, 1)));
        assert!(s.starts_with("> **Quick run.**"), "{s}");
        assert!(s.contains("(27 min 5 s)"), "{s}");
        assert!(s.contains("`abc1234` with uncommitted changes"));
        assert!(
            s.contains("GDAL 3.6.2, nginx not installed, wrk 4.1.0"),
            "{s}"
        );
        assert_eq!(version("nginx version: nginx/1.22.1"), "1.22.1");
        assert_eq!(version("custom build"), "custom build");
        assert!(s.contains("fewer than the 3"));
        let s = section(Some(&meta(false, 3)));
        assert!(!s.contains("Quick run") && !s.contains("fewer than"), "{s}");
        assert!(section(None).contains("no `meta.json`"));
    }
}
