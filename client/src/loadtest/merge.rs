//! `tessera load merge`: the reports of many load processes (`--shard K/N`) added
//! into one. Counts and errors add, latency histograms add exactly (so merged
//! percentiles are those of all the requests), and every report is checked first, so
//! that implausible or repeated shards are refused with the file and field named.

use super::check::ErrorKind;
use super::latency::HistogramError;
use super::replay_report::{Histograms, Latency, REPORT_VERSION, ReplayReport, Second};
use super::replay_report_file::{Implausible, ReportError};

/// Why reports could not be merged: each names the report (by its place, or its
/// file with [`merge_files`]) and what was wrong.
#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    #[error("{label}: {field} {value}: the sum over the reports does not fit ({before} before it)")]
    Overflow {
        label: String,
        field: String,
        value: String,
        before: String,
    },
    #[error("{label}: cannot open")]
    Open {
        label: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{label} is {first} again: the same shard twice would count its requests twice")]
    SamePath { label: String, first: String },
    #[error("{label}: cannot read")]
    Read {
        label: String,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "{label} has the same content as {first}: the same shard twice would count its requests twice"
    )]
    SameContent { label: String, first: String },
    #[error("{label}: not UTF-8 text")]
    NotUtf8 {
        label: String,
        #[source]
        source: std::string::FromUtf8Error,
    },
    #[error("{label}")]
    Report {
        label: String,
        #[source]
        source: ReportError,
    },
    #[error("nothing to merge: no reports")]
    Nothing,
    #[error("{label}: version {version} (this build merges version {REPORT_VERSION})")]
    Version { label: String, version: u32 },
    #[error(
        "{label}: mode {mode} but {first_label}'s is {first_mode}; merge the shards of one run"
    )]
    Mode {
        label: String,
        mode: &'static str,
        first_label: String,
        first_mode: &'static str,
    },
    #[error("{label}: HTTP/{http} but {first_label} spoke HTTP/{first_http}")]
    Http {
        label: String,
        http: &'static str,
        first_label: String,
        first_http: &'static str,
    },
    #[error("{label}")]
    Implausible {
        label: String,
        #[source]
        source: Implausible,
    },
    #[error(
        "{label}: shard {shard} is in {other} too: the same shard twice would count its requests twice"
    )]
    SameShard {
        label: String,
        shard: String,
        other: String,
    },
    #[error("{label}")]
    Histogram {
        label: String,
        #[source]
        source: HistogramError,
    },
    #[error("{label}, second {second}")]
    SecondHistogram {
        label: String,
        second: u64,
        #[source]
        source: HistogramError,
    },
}

/// `a + b`, or an error naming the field and the report that overflowed it.
fn sum<T: Copy + std::fmt::Display>(
    a: T,
    b: T,
    add: fn(T, T) -> Option<T>,
    label: &str,
    field: &str,
) -> Result<T, MergeError> {
    add(a, b).ok_or_else(|| MergeError::Overflow {
        label: label.into(),
        field: field.into(),
        value: b.to_string(),
        before: a.to_string(),
    })
}

/// Adds the reports of the shards of one run: counts and errors add, histograms add
/// exactly (percentiles are recomputed from the sums), seconds align by index and add
/// the same way; `seconds` is the longest shard's and the rates are totals over it;
/// `target_rate`, `connections` and `shards` add; `rate_held` is whether every shard
/// held its share (null if any is null). The reports must agree on mode and HTTP
/// version, name no shard twice, and each pass [`ReplayReport::validate`]; errors
/// name a report by its place (`report 2`): [`merge_files`] names the files.
pub fn merge(reports: &[ReplayReport]) -> Result<ReplayReport, MergeError> {
    let labelled: Vec<(String, &ReplayReport)> = reports
        .iter()
        .enumerate()
        .map(|(i, r)| (format!("report {}", i + 1), r))
        .collect();
    merge_labelled(&labelled)
}

/// Reads and merges the reports at `paths` (a directory stands for its
/// `load.json`), as [`merge`] does, refusing a file given twice or two files with
/// the same content: the same shard counted twice would double its requests. Errors
/// name the file.
pub fn merge_files(paths: &[std::path::PathBuf]) -> Result<ReplayReport, MergeError> {
    let mut seen_paths: Vec<(std::path::PathBuf, String)> = Vec::new();
    let mut seen_content: Vec<(u64, String)> = Vec::new();
    let mut reports = Vec::with_capacity(paths.len());
    for p in paths {
        let file = if p.is_dir() {
            p.join("load.json")
        } else {
            p.clone()
        };
        let label = format!("report {}", file.display());
        let canonical = std::fs::canonicalize(&file).map_err(|source| MergeError::Open {
            label: label.clone(),
            source,
        })?;
        if let Some((_, first)) = seen_paths.iter().find(|(c, _)| *c == canonical) {
            return Err(MergeError::SamePath {
                label,
                first: first.clone(),
            });
        }
        let bytes = std::fs::read(&file).map_err(|source| MergeError::Read {
            label: label.clone(),
            source,
        })?;
        let hash = xxhash_rust::xxh3::xxh3_64(&bytes);
        if let Some((_, first)) = seen_content.iter().find(|(h, _)| *h == hash) {
            return Err(MergeError::SameContent {
                label,
                first: first.clone(),
            });
        }
        let text = String::from_utf8(bytes).map_err(|source| MergeError::NotUtf8 {
            label: label.clone(),
            source,
        })?;
        let r = ReplayReport::from_json(&text).map_err(|source| MergeError::Report {
            label: label.clone(),
            source,
        })?;
        seen_paths.push((canonical, label.clone()));
        seen_content.push((hash, label.clone()));
        reports.push((label, r));
    }
    let labelled: Vec<(String, &ReplayReport)> =
        reports.iter().map(|(l, r)| (l.clone(), r)).collect();
    merge_labelled(&labelled)
}

fn merge_labelled(reports: &[(String, &ReplayReport)]) -> Result<ReplayReport, MergeError> {
    let Some(&(ref first_label, first)) = reports.first() else {
        return Err(MergeError::Nothing);
    };
    let mut corrected = Latency::new();
    let mut uncorrected = Latency::new();
    let mut out = ReplayReport {
        target_rate: Some(0.0),
        shards: 0,
        rate_held: Some(true),
        ..ReplayReport::empty(first.mode, first.http, first.latency_from)
    };
    let mut shards: Vec<(&str, &str)> = Vec::new();
    for (label, r) in reports {
        let label = label.as_str();
        if r.tessera_load != REPORT_VERSION {
            return Err(MergeError::Version {
                label: label.into(),
                version: r.tessera_load,
            });
        }
        if r.mode != first.mode {
            return Err(MergeError::Mode {
                label: label.into(),
                mode: r.mode.name(),
                first_label: first_label.clone(),
                first_mode: first.mode.name(),
            });
        }
        if r.http != first.http {
            return Err(MergeError::Http {
                label: label.into(),
                http: r.http.name(),
                first_label: first_label.clone(),
                first_http: first.http.name(),
            });
        }
        r.validate().map_err(|source| MergeError::Implausible {
            label: label.into(),
            source,
        })?;
        for shard in r.shard.split(',').map(str::trim) {
            if let Some((_, other)) = shards.iter().find(|(s, _)| *s == shard) {
                return Err(MergeError::SameShard {
                    label: label.into(),
                    shard: shard.into(),
                    other: (*other).into(),
                });
            }
            shards.push((shard, label));
        }
        let (c, u) = r
            .histograms
            .decode()
            .map_err(|source| MergeError::Histogram {
                label: label.into(),
                source,
            })?;
        corrected.add(&c);
        uncorrected.add(&u);
        let add64 = |a: u64, b: u64, field: &str| sum(a, b, u64::checked_add, label, field);
        let add32 = |a: u32, b: u32, field: &str| sum(a, b, u32::checked_add, label, field);
        out.shards = add32(out.shards, r.shards, "shards")?;
        out.connections = add32(out.connections, r.connections, "connections")?;
        out.seconds = out.seconds.max(r.seconds);
        out.scheduled = add64(out.scheduled, r.scheduled, "scheduled")?;
        out.sent = add64(out.sent, r.sent, "sent")?;
        out.completed = add64(out.completed, r.completed, "completed")?;
        out.tiles = add64(out.tiles, r.tiles, "tiles")?;
        out.bytes = add64(out.bytes, r.bytes, "bytes")?;
        out.backlog = add64(out.backlog, r.backlog, "backlog")?;
        out.unsent = add64(out.unsent, r.unsent, "unsent")?;
        for k in ErrorKind::ALL {
            let total = add64(out.errors.get(k), r.errors.get(k), &format!("errors.{k}"))?;
            out.errors.set(k, total);
        }
        for (&status, &n) in &r.http_statuses {
            let total = out.http_statuses.entry(status).or_insert(0);
            *total = add64(*total, n, &format!("http_statuses.{status}"))?;
        }
        out.target_rate = out.target_rate.zip(r.target_rate).map(|(a, b)| a + b);
        out.rate_held = out.rate_held.zip(r.rate_held).map(|(a, b)| a && b);
    }
    out.shard = shards.iter().map(|(s, _)| *s).collect::<Vec<_>>().join(",");
    out.latency_ms = corrected.percentiles();
    out.uncorrected_latency_ms = uncorrected.percentiles();
    out.histograms = Histograms::of(&corrected, &uncorrected);
    out.timeline = merge_timelines(reports)?;
    out.set_rates();
    Ok(out)
}

/// The shards' timelines added second by second. Each is in increasing order
/// (`validate`), so one pass with a cursor per report does it, holding one second's
/// histograms at a time: keeping every second's (two 188 KB histograms each) was
/// 1.4 TB for a timeline claiming second 4·10⁹.
fn merge_timelines(reports: &[(String, &ReplayReport)]) -> Result<Vec<Second>, MergeError> {
    let Some(end) = reports
        .iter()
        .filter_map(|(_, r)| r.timeline.last().map(|s| s.second))
        .max()
    else {
        return Ok(Vec::new());
    };
    let empty = Latency::new().to_base64();
    let mut cursors = vec![0usize; reports.len()];
    let (mut c, mut u) = (Latency::new(), Latency::new());
    let mut timeline = Vec::new();
    for second in 0..=end {
        if !c.is_empty() || !u.is_empty() {
            c.clear();
            u.clear();
        }
        let mut acc = Second::default();
        for ((label, r), cursor) in reports.iter().zip(&mut cursors) {
            let Some(s) = r.timeline.get(*cursor).filter(|s| s.second == second) else {
                continue;
            };
            *cursor += 1;
            let what = |field: &str| format!("timeline second {second} {field}");
            // Most seconds of a long run that did little have nothing to add.
            if s.histograms.corrected != empty || s.histograms.uncorrected != empty {
                let (sc, su) =
                    s.histograms
                        .decode()
                        .map_err(|source| MergeError::SecondHistogram {
                            label: label.clone(),
                            second,
                            source,
                        })?;
                c.add(&sc);
                u.add(&su);
            }
            let add =
                |a: u64, b: u64, field: &str| sum(a, b, u64::checked_add, label, &what(field));
            acc.scheduled = add(acc.scheduled, s.scheduled, "scheduled")?;
            acc.sent = add(acc.sent, s.sent, "sent")?;
            acc.completed = add(acc.completed, s.completed, "completed")?;
            acc.tiles = add(acc.tiles, s.tiles, "tiles")?;
            acc.errors = add(acc.errors, s.errors, "errors")?;
        }
        timeline.push(Second {
            scheduled: acc.scheduled,
            sent: acc.sent,
            completed: acc.completed,
            tiles: acc.tiles,
            errors: acc.errors,
            ..Second::new(second, &c, &u)
        });
    }
    Ok(timeline)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::loadtest::replay_report::tests::{latency, report, values};
    use crate::loadtest::replay_report::{Http, Mode};
    use crate::loadtest::replay_report_file::MAX_SECONDS;

    #[test]
    fn merged_histograms_equal_one_fed_every_value() {
        let (a, b) = (values(1, 5000), values(2, 7000));
        let mut merged = latency(&a);
        merged.add(&latency(&b));
        let all = latency(&[a.clone(), b.clone()].concat());
        assert_eq!(merged.count(), 12_000);
        for q in [0.0, 0.1, 0.5, 0.9, 0.99, 0.999, 0.9999, 1.0] {
            assert_eq!(merged.quantile_ms(q), all.quantile_ms(q), "quantile {q}");
        }
        assert_eq!(merged.max_ms(), all.max_ms());
        // And through the base64 V2 encoding.
        let through = Latency::from_base64(&merged.to_base64()).unwrap();
        assert_eq!(through, all);
    }

    #[test]
    fn merged_reports_add_up() {
        let a = report("0/2", 3, 4000, 4);
        let b = report("1/2", 4, 2000, 2);
        let m = merge(&[a.clone(), b.clone()]).unwrap();
        assert_eq!(m.shard, "0/2,1/2");
        assert_eq!(m.shards, 2);
        assert_eq!(m.connections, 16);
        assert_eq!(m.scheduled, 6000);
        assert_eq!(m.completed, a.completed + b.completed);
        assert_eq!(m.tiles, a.tiles + b.tiles);
        assert_eq!(m.backlog, 2);
        assert_eq!(m.errors.timeout, 6);
        assert_eq!(m.errors.corrupt, 7);
        assert_eq!(m.seconds, 4.0);
        assert_eq!(m.target_rate, Some(2000.0));
        assert!((m.requests_per_s - m.completed as f64 / 4.0).abs() < 1e-9);
        assert_eq!(m.rate_held, Some(true));
        // Percentiles are those of all values, not a mix of the shards' percentiles.
        let all = latency(&[values(3, 4000), values(4, 2000)].concat());
        assert_eq!(m.latency_ms, all.percentiles());
        // Seconds align: 0 and 1 have both shards, 2 and 3 only the first.
        assert_eq!(m.timeline.len(), 4);
        assert_eq!(m.timeline[1].completed, 1000 + 1000);
        assert_eq!(m.timeline[1].errors, 2);
        assert_eq!(m.timeline[3].completed, 1000);
        let second1 =
            latency(&[&values(3, 4000)[1000..2000], &values(4, 2000)[1000..2000]].concat());
        assert_eq!(
            m.timeline[1].corrected_p99_ms,
            Some(second1.quantile_ms(0.99))
        );
        // A shard that missed its rate makes the run miss it; saturation has none.
        let mut late = b.clone();
        late.rate_held = Some(false);
        assert_eq!(merge(&[a.clone(), late]).unwrap().rate_held, Some(false));
        // Merging is associative in its totals.
        let one = merge(&[merge(std::slice::from_ref(&a)).unwrap(), b.clone()]).unwrap();
        assert_eq!(one.histograms, m.histograms);
    }

    #[test]
    fn merge_refuses_reports_of_different_runs() {
        let a = report("0/2", 3, 100, 1);
        let mut b = report("1/2", 4, 100, 1);
        b.mode = Mode::Saturation;
        assert!(
            crate::errors::Chain(&merge(&[a.clone(), b]).unwrap_err())
                .to_string()
                .contains("mode saturation")
        );
        let mut c = report("1/2", 4, 100, 1);
        c.http = Http::Http2;
        assert!(
            crate::errors::Chain(&merge(&[a, c]).unwrap_err())
                .to_string()
                .contains("HTTP/2")
        );
        assert!(merge(&[]).is_err());
    }

    fn merge_err(reports: &[ReplayReport]) -> String {
        crate::errors::Chain(&merge(reports).unwrap_err()).to_string()
    }

    #[test]
    fn merge_refuses_seconds_past_the_run_without_allocating_them() {
        let a = report("0/2", 3, 400, 4);
        // A timeline second of 4·10⁹ was a 1.4 TB allocation, u64::MAX an index out
        // of bounds (a panic).
        for second in [4_000_000_000, u64::MAX, 6] {
            let mut b = report("1/2", 4, 400, 4);
            b.timeline[3].second = second;
            let e = merge_err(&[a.clone(), b]);
            assert!(
                e.contains("report 2") && e.contains(&format!("timeline[3].second {second}")),
                "{e}"
            );
        }
        // Out of order, or twice the same second.
        let mut b = report("1/2", 4, 400, 4);
        b.timeline[2].second = 1;
        let e = merge_err(&[a.clone(), b]);
        assert!(e.contains("timeline[2].second 1 does not follow"), "{e}");
        // A run's length that no run has.
        for seconds in [1e300, -1.0, f64::NAN, f64::INFINITY, MAX_SECONDS + 1.0] {
            let mut b = report("1/2", 4, 400, 4);
            b.seconds = seconds;
            let e = merge_err(&[a.clone(), b]);
            assert!(e.contains("report 2: seconds"), "{seconds}: {e}");
        }
        // The longest run there can be still merges.
        let mut b = report("1/2", 4, 400, 4);
        b.seconds = MAX_SECONDS;
        assert_eq!(merge(&[a, b]).unwrap().seconds, MAX_SECONDS);
    }

    #[test]
    fn merge_refuses_counts_that_do_not_fit_instead_of_wrapping() {
        let a = report("0/2", 3, 400, 4);
        // completed u64::MAX used to wrap the sum silently.
        let mut b = report("1/2", 4, 400, 4);
        b.completed = u64::MAX;
        let e = merge_err(&[a.clone(), b]);
        assert!(
            e.contains("report 2: completed 18446744073709551615 is more than sent"),
            "{e}"
        );
        // Plausible alone, too large together: the field and the report that overflowed.
        let huge = |shard: &str| {
            let mut r = report(shard, 4, 400, 4);
            r.scheduled = u64::MAX / 2 + 1;
            r.sent = r.scheduled;
            r
        };
        let e = merge_err(&[huge("0/2"), huge("1/2")]);
        assert!(
            e.contains("report 2: scheduled") && e.contains("does not fit"),
            "{e}"
        );
        let mut b = report("1/2", 4, 400, 4);
        b.tiles = u64::MAX;
        let mut c = report("2/3", 5, 400, 4);
        c.tiles = 1;
        let e = merge_err(&[b, c]);
        assert!(e.contains("report 2: tiles 1"), "{e}");
        // A second's counts too.
        let mut b = report("0/2", 3, 400, 4);
        b.timeline[1].tiles = u64::MAX;
        let e = merge_err(&[b, report("1/2", 4, 400, 4)]);
        assert!(e.contains("report 2: timeline second 1 tiles"), "{e}");
        // Errors beyond the requests sent; more connections than a u32 holds.
        let mut b = report("1/2", 4, 400, 4);
        b.errors.mismatch = u64::MAX;
        assert!(merge_err(&[a.clone(), b]).contains("errors.mismatch"));
        let mut b = report("1/2", 4, 400, 4);
        b.connections = u32::MAX;
        assert!(merge_err(&[a, b]).contains("report 2: connections"));
    }

    #[test]
    fn merge_refuses_a_shard_given_twice() {
        let a = report("0/2", 3, 400, 4);
        let e = merge_err(&[a.clone(), report("1/2", 4, 400, 4), a.clone()]);
        assert!(e.contains("report 3: shard 0/2 is in report 1 too"), "{e}");
        // Inside a merged report too.
        let m = merge(&[a.clone(), report("1/2", 4, 400, 4)]).unwrap();
        assert!(merge_err(&[m, report("1/2", 5, 400, 4)]).contains("shard 1/2"));
    }

    #[test]
    fn merge_files_refuses_the_same_file_or_content_twice_and_names_it() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a"), dir.path().join("b"));
        report("0/2", 3, 400, 4).write_json(&a).unwrap();
        report("1/2", 4, 400, 4).write_json(&b).unwrap();
        let merged = merge_files(&[a.clone(), b.join("load.json")]).unwrap();
        assert_eq!(merged.shards, 2);
        // The same file, as a directory and as its load.json.
        let e = format!(
            "{}",
            crate::errors::Chain(
                &merge_files(&[a.clone(), b.clone(), a.join("load.json")]).unwrap_err()
            )
        );
        assert!(
            e.contains("a/load.json is report") && e.contains("again"),
            "{e}"
        );
        // A copy of it.
        let copy = dir.path().join("copy.json");
        std::fs::copy(a.join("load.json"), &copy).unwrap();
        let e = crate::errors::Chain(&merge_files(&[a.clone(), copy]).unwrap_err()).to_string();
        assert!(e.contains("copy.json has the same content as"), "{e}");
        // A file's implausible field is named with the file.
        let mut bad = report("1/2", 4, 400, 4);
        bad.completed = u64::MAX;
        let c = dir.path().join("c");
        bad.write_json(&c).unwrap();
        let e = crate::errors::Chain(&merge_files(&[a, c]).unwrap_err()).to_string();
        assert!(e.contains("c/load.json") && e.contains("completed"), "{e}");
        let e =
            crate::errors::Chain(&merge_files(&[dir.path().join("none")]).unwrap_err()).to_string();
        assert!(e.contains("none") && e.contains("cannot open"), "{e}");
    }

    #[test]
    fn timelines_with_gaps_merge_second_by_second() {
        let mut a = report("0/2", 3, 400, 4);
        a.timeline.remove(1);
        let mut b = report("1/2", 4, 400, 4);
        b.timeline.retain(|s| s.second == 1);
        let m = merge(&[a.clone(), b.clone()]).unwrap();
        assert_eq!(
            m.timeline.iter().map(|s| s.second).collect::<Vec<_>>(),
            [0, 1, 2, 3]
        );
        assert_eq!(m.timeline[0], a.timeline[0]);
        assert_eq!(m.timeline[1], b.timeline[0]);
        assert_eq!(m.timeline[3], a.timeline[2]);
    }
}
