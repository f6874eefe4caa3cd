//! JSON Lines files of records: one record per line, each checked, with errors that
//! name the file and line.

use anyhow::{Context, bail};
use serde::de::DeserializeOwned;
use std::collections::HashMap;
use std::path::Path;

/// A record of a `.jsonl` file: its run and what it measured, for the checks.
pub trait Record: DeserializeOwned {
    const FILE: &'static str;
    fn run(&self) -> u32;
    /// What was measured, without the run ("tessera synthetic:16385").
    fn key(&self) -> String;
    /// Values the report cannot use (a zero duration).
    fn check(&self) -> Result<(), RecordError> {
        Ok(())
    }
}

/// A record whose values the report cannot use.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum RecordError {
    /// A duration, count or size that must be above zero is zero, negative or NaN.
    #[error("`{field}` must be positive, not {value}")]
    NotPositive { field: &'static str, value: f64 },
}

/// The first of `fields` (name, value) that is not above zero, as an error.
pub(super) fn positive(fields: &[(&'static str, f64)]) -> Result<(), RecordError> {
    match fields.iter().find(|(_, v)| v.is_nan() || *v <= 0.0) {
        Some(&(field, value)) => Err(RecordError::NotPositive { field, value }),
        None => Ok(()),
    }
}

/// Reads `dir/T::FILE`: `None` if it does not exist, else one record per
/// non-blank line, checked.
pub fn load_jsonl<T: Record>(dir: &Path) -> anyhow::Result<Option<Vec<T>>> {
    let path = dir.join(T::FILE);
    let text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e).with_context(|| format!("{}: cannot read", path.display())),
    };
    parse_jsonl(&text)
        .map(Some)
        .with_context(|| path.display().to_string())
}

/// The records of a JSON Lines text; errors name the line.
pub fn parse_jsonl<T: Record>(text: &str) -> anyhow::Result<Vec<T>> {
    let mut records = Vec::new();
    let mut seen: HashMap<(String, u32), usize> = HashMap::new();
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        if line.trim().is_empty() {
            continue;
        }
        let r: T = serde_json::from_str(line).with_context(|| format!("line {n}"))?;
        if r.run() == 0 {
            bail!("line {n}: `run` counts from 1");
        }
        r.check().map_err(|e| anyhow::anyhow!("line {n}: {e}"))?;
        if let Some(first) = seen.insert((r.key(), r.run()), n) {
            bail!(
                "line {n}: run {} of {} again (first on line {first})",
                r.run(),
                r.key()
            );
        }
        records.push(r);
    }
    Ok(records)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::results::{Build, Serve};

    const BUILD: &str = r#"{"tool":"tessera","input":"synthetic:16385","run":1,"wall_s":4.8,"cpu_s":8.9,"rss_mib":72,"bytes":367000000,"samples":268468225,"extra":"ignored"}"#;

    #[test]
    fn parses_records_and_ignores_extra_fields_and_blank_lines() {
        let text = format!("{BUILD}\n\n{}\n", BUILD.replace("\"run\":1", "\"run\":2"));
        let r: Vec<Build> = parse_jsonl(&text).expect("valid");
        assert_eq!(r.len(), 2);
        assert_eq!(r[1].run, 2);
        assert_eq!(r[0].rss_mib, 72.0);
    }

    #[test]
    fn errors_name_the_line_and_the_problem() {
        let missing = BUILD.replace("\"wall_s\":4.8,", "");
        let e = parse_jsonl::<Build>(&format!("{BUILD}\n{missing}")).expect_err("no wall_s");
        let msg = format!("{e:#}");
        assert!(msg.contains("line 2") && msg.contains("wall_s"), "{msg}");

        let e = parse_jsonl::<Build>(&format!("{BUILD}\n{BUILD}")).expect_err("duplicate");
        let msg = format!("{e:#}");
        assert!(
            msg.contains("line 2") && msg.contains("first on line 1"),
            "{msg}"
        );

        let zero = BUILD.replace("\"run\":1", "\"run\":0");
        assert!(parse_jsonl::<Build>(&zero).is_err());
        let no_time = BUILD.replace("\"wall_s\":4.8", "\"wall_s\":0");
        let e = parse_jsonl::<Build>(&no_time).expect_err("zero wall time");
        assert!(format!("{e:#}").contains("wall_s"));
    }

    #[test]
    fn a_value_that_must_be_positive_names_its_field() {
        let e = positive(&[("seconds", 3.0), ("wall_s", 0.0)]).expect_err("zero");
        assert_eq!(
            e,
            RecordError::NotPositive {
                field: "wall_s",
                value: 0.0
            }
        );
        assert_eq!(e.to_string(), "`wall_s` must be positive, not 0");
        assert!(positive(&[("samples", f64::NAN)]).is_err());
        assert_eq!(positive(&[("seconds", 1e-9)]), Ok(()));
    }

    #[test]
    fn a_missing_file_is_not_run_but_a_bad_one_is_an_error() {
        let dir = tempfile::tempdir().expect("tempdir");
        assert!(load_jsonl::<Serve>(dir.path()).expect("absent").is_none());
        std::fs::write(dir.path().join("serve.jsonl"), "{not json\n").expect("write");
        let e = load_jsonl::<Serve>(dir.path()).expect_err("bad json");
        let msg = format!("{e:#}");
        assert!(
            msg.contains("serve.jsonl") && msg.contains("line 1"),
            "{msg}"
        );
    }
}
