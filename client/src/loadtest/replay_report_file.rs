//! A replay's report as a file: `load.json` read back (its version and JSON checked,
//! then whether a run of this program could have written it: [`MAX_SECONDS`],
//! [`ReplayReport::validate`]) and written through a temporary file, and the
//! `--out DIR` directory with `latency.png` beside it.

use super::check::ErrorKind;
use super::latency::HistogramError;
use super::latency_plot;
use super::pacing::{MAX_RUN, MAX_TIMEOUT};
use super::replay_report::{REPORT_VERSION, ReplayReport};
use crate::errors::PngError;
use std::path::{Path, PathBuf};

/// A report that could not be read or written; [`Implausible`] when it reads but
/// no run of this program could have written it.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("report {}: cannot read", path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// What was wrong in the report at `path`.
    #[error("report {}", path.display())]
    File {
        path: PathBuf,
        #[source]
        source: Box<ReportError>,
    },
    #[error("not JSON")]
    NotJson(#[source] serde_json::Error),
    #[error("not a tessera load report (no \"tessera_load\" key)")]
    NoVersion,
    #[error("report version {version} (this build reads version {REPORT_VERSION})")]
    Version { version: serde_json::Value },
    #[error("not a tessera load report")]
    NotReport(#[source] serde_json::Error),
    #[error(transparent)]
    Histogram(#[from] HistogramError),
    #[error(transparent)]
    Implausible(#[from] Implausible),
    #[error("{}: cannot create the directory", dir.display())]
    CreateDir {
        dir: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: cannot write", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: PngError,
    },
    #[error(transparent)]
    Png(#[from] PngError),
}

/// A report no run of this program could have written ([`ReplayReport::validate`]):
/// each names the field.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Implausible {
    #[error("seconds {seconds:?}: not the length of a run (0 to {MAX_SECONDS} s)")]
    Seconds { seconds: f64 },
    #[error("target_rate {rate:?}: not a number of requests per second")]
    TargetRate { rate: f64 },
    #[error("sent {sent} is more than scheduled ({scheduled})")]
    Sent { sent: u64, scheduled: u64 },
    #[error("completed {completed} is more than sent ({sent})")]
    Completed { completed: u64, sent: u64 },
    #[error("backlog {backlog} is more than scheduled ({scheduled})")]
    Backlog { backlog: u64, scheduled: u64 },
    #[error("unsent {unsent} is more than scheduled less sent ({room})")]
    Unsent { unsent: u64, room: u64 },
    #[error("errors.{kind} {n}: more errors than requests sent ({sent})")]
    Errors { kind: ErrorKind, n: u64, sent: u64 },
    #[error("http_statuses.{status} {n}: more than the http_status errors ({errors})")]
    Statuses { status: u16, n: u64, errors: u64 },
    #[error("timeline[{index}].second {second} is past the end of the run ({seconds} s)")]
    PastEnd {
        index: usize,
        second: u64,
        seconds: f64,
    },
    #[error(
        "timeline[{index}].second {second} does not follow timeline[{previous_index}].second {previous}"
    )]
    OutOfOrder {
        index: usize,
        second: u64,
        previous_index: usize,
        previous: u64,
    },
}

impl ReplayReport {
    /// Reads a report, naming the file and what is wrong with it.
    pub fn read(path: &Path) -> Result<Self, ReportError> {
        let text = std::fs::read_to_string(path).map_err(|source| ReportError::Read {
            path: path.into(),
            source,
        })?;
        Self::from_json(&text).map_err(|e| ReportError::File {
            path: path.into(),
            source: Box::new(e),
        })
    }

    /// Parses a report: a JSON object with `"tessera_load": 1`.
    pub fn from_json(text: &str) -> Result<Self, ReportError> {
        let v: serde_json::Value = serde_json::from_str(text).map_err(ReportError::NotJson)?;
        let Some(version) = v.get("tessera_load") else {
            return Err(ReportError::NoVersion);
        };
        if version.as_u64() != Some(u64::from(REPORT_VERSION)) {
            return Err(ReportError::Version {
                version: version.clone(),
            });
        }
        let r: Self = serde_json::from_value(v).map_err(ReportError::NotReport)?;
        r.histograms.decode()?;
        r.validate()?;
        Ok(r)
    }

    /// Writes `dir/load.json` and `dir/latency.png` (each through a temporary file
    /// renamed into place), creating `dir`.
    pub fn write_dir(&self, dir: &Path) -> Result<(), ReportError> {
        self.write_json(dir)?;
        Ok(latency_plot::write(self, &dir.join("latency.png"))?)
    }

    /// Writes `dir/load.json` (temp and rename), creating `dir`.
    pub fn write_json(&self, dir: &Path) -> Result<(), ReportError> {
        std::fs::create_dir_all(dir).map_err(|source| ReportError::CreateDir {
            dir: dir.into(),
            source,
        })?;
        let path = dir.join("load.json");
        tessera_charts::png::write_atomically(&path, |w| {
            serde_json::to_writer_pretty(&mut *w, self)?;
            std::io::Write::write_all(w, b"\n")?;
            Ok(())
        })
        .map_err(|e| ReportError::Write {
            source: e.into(),
            path,
        })
    }
}

/// The longest run a report may describe, seconds: [`MAX_RUN`] of schedule, one
/// [`MAX_TIMEOUT`] to wait for the last answers, and a minute to close the run. A
/// larger `seconds` (or a timeline second past it) is not a run of this program,
/// and would have `merge` build a timeline of billions of seconds.
pub const MAX_SECONDS: f64 = (MAX_RUN.as_secs() + MAX_TIMEOUT.as_secs() + 60) as f64;

impl ReplayReport {
    /// Checks that the report describes a run this program could have made: a length
    /// within [`MAX_SECONDS`], a timeline of increasing seconds within it, and counts
    /// that fit one another (no more sent than scheduled, answered than sent, errors
    /// than requests sent). Each error names the field.
    pub fn validate(&self) -> Result<(), Implausible> {
        if !(self.seconds.is_finite() && (0.0..=MAX_SECONDS).contains(&self.seconds)) {
            return Err(Implausible::Seconds {
                seconds: self.seconds,
            });
        }
        if let Some(t) = self.target_rate
            && !(t.is_finite() && t >= 0.0)
        {
            return Err(Implausible::TargetRate { rate: t });
        }
        if self.sent > self.scheduled {
            return Err(Implausible::Sent {
                sent: self.sent,
                scheduled: self.scheduled,
            });
        }
        if self.completed > self.sent {
            return Err(Implausible::Completed {
                completed: self.completed,
                sent: self.sent,
            });
        }
        if self.backlog > self.scheduled {
            return Err(Implausible::Backlog {
                backlog: self.backlog,
                scheduled: self.scheduled,
            });
        }
        if self.unsent > self.scheduled - self.sent {
            return Err(Implausible::Unsent {
                unsent: self.unsent,
                room: self.scheduled - self.sent,
            });
        }
        // One error at most per request sent (those never sent are `unsent`).
        let mut errors = 0u64;
        for k in ErrorKind::ALL {
            errors = errors
                .checked_add(self.errors.get(k))
                .filter(|&e| e <= self.sent)
                .ok_or(Implausible::Errors {
                    kind: k,
                    n: self.errors.get(k),
                    sent: self.sent,
                })?;
        }
        let mut statuses = 0u64;
        for (&status, &n) in &self.http_statuses {
            statuses = statuses
                .checked_add(n)
                .filter(|&t| t <= self.errors.http_status)
                .ok_or(Implausible::Statuses {
                    status,
                    n,
                    errors: self.errors.http_status,
                })?;
        }
        // Second `s` covers [s, s + 1): none lies past the end of the run (one more
        // for the second in progress when it ended).
        let last = self.seconds.ceil() as u64 + 1;
        let mut previous: Option<u64> = None;
        for (i, s) in self.timeline.iter().enumerate() {
            if s.second > last {
                return Err(Implausible::PastEnd {
                    index: i,
                    second: s.second,
                    seconds: self.seconds,
                });
            }
            if let Some(p) = previous
                && s.second <= p
            {
                return Err(Implausible::OutOfOrder {
                    index: i,
                    second: s.second,
                    previous_index: i - 1,
                    previous: p,
                });
            }
            previous = Some(s.second);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::loadtest::replay_report::tests::report;

    #[test]
    fn a_report_round_trips_through_json() {
        let r = report("1/4", 7, 3000, 3);
        let text = serde_json::to_string_pretty(&r).unwrap();
        let back = ReplayReport::from_json(&text).unwrap();
        assert_eq!(back, r);
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(v["tessera_load"], 1);
        assert_eq!(v["mode"], "rate");
        assert_eq!(v["http"], "1.1");
        assert_eq!(v["errors"]["timeout"], 3);
        assert_eq!(v["errors"]["http_status"], 0);
        assert!(v["latency_ms"]["p999"].is_f64());
        let (c, _) = back.histograms.decode().unwrap();
        assert_eq!(c.count(), 3000);
        assert_eq!(c.percentiles(), r.latency_ms);
    }

    #[test]
    fn bad_reports_say_what_they_are_not() {
        let err =
            |s: &str| crate::errors::Chain(&ReplayReport::from_json(s).unwrap_err()).to_string();
        assert!(err("not json").contains("not JSON"));
        assert!(err("{\"tessera_trace\":1}").contains("not a tessera load report"));
        let text = serde_json::to_string(&report("0/1", 1, 100, 1)).unwrap();
        assert!(
            err(&text.replace("\"tessera_load\":1", "\"tessera_load\":2")).contains("version 2")
        );
        let broken = text.replacen("\"corrected\":\"", "\"corrected\":\"!!", 1);
        assert!(err(&broken).contains("corrected histogram"));
    }

    #[test]
    fn out_dir_gets_both_files_and_reads_back() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("shard-0");
        let r = report("0/1", 9, 600, 3);
        r.write_dir(&out).unwrap();
        // (Through JSON, as any reader sees it: serde_json's float parsing may differ
        // from the f64 written in the last bit.)
        let through_json =
            ReplayReport::from_json(&serde_json::to_string_pretty(&r).unwrap()).unwrap();
        assert_eq!(
            ReplayReport::read(&out.join("load.json")).unwrap(),
            through_json
        );
        assert!(out.join("latency.png").is_file());
        // Only the two files: no temporary left behind.
        assert_eq!(std::fs::read_dir(&out).unwrap().count(), 2);
        // A directory that cannot be made is an error naming it.
        let file = dir.path().join("a-file");
        std::fs::write(&file, b"x").unwrap();
        let e = crate::errors::Chain(&r.write_dir(&file).unwrap_err()).to_string();
        assert!(e.contains("a-file"), "{e}");
    }
}
