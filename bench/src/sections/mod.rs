//! One module per section of BENCHMARKS.md. Each turns its records into the
//! Markdown for its placeholder (tables, verdict bullets, chart links), the charts
//! themselves, and its aims with a verdict computed from the numbers, which
//! [`aims`] collects into the summary table at the top.
//!
//! A section whose results file is missing still returns its aims, "not
//! measured", so the summary never silently drops one.

pub mod aims;
pub mod build;
pub mod gonzalez;
pub mod gpu;
pub mod ingest;
pub mod load;
pub mod loadreplay;
pub mod meta;
pub mod policy;
pub mod select;
pub mod serve;
pub mod stream;
pub mod terrain;
pub mod webtiles;

use crate::chart::Image;
use std::fmt;
use std::fmt::Write as _;

/// Where the report's charts are, as a link from BENCHMARKS.md ("bench/plots").
#[derive(Clone, Debug)]
pub struct Ctx {
    pub plots: String,
}

impl Ctx {
    /// Adds `image` to `section` as `file` and links it in its Markdown.
    pub fn chart(&self, section: &mut Section, file: &str, alt: &str, image: Image) {
        let link = if self.plots.is_empty() {
            file.to_string()
        } else {
            format!("{}/{file}", self.plots.trim_end_matches('/'))
        };
        let _ = writeln!(section.markdown, "\n![{alt}]({link})");
        section.charts.push(Chart {
            file: file.to_string(),
            image,
        });
    }
}

/// A chart to write into the plots directory.
#[derive(Clone, Debug)]
pub struct Chart {
    pub file: String,
    pub image: Image,
}

/// What one section contributes to the report.
#[derive(Clone, Debug, Default)]
pub struct Section {
    pub markdown: String,
    pub aims: Vec<Aim>,
    pub charts: Vec<Chart>,
}

impl Section {
    /// A section whose results file is absent: says so, and its aims are not measured.
    pub fn not_run(file: &str, aims: Vec<Aim>) -> Self {
        Self {
            markdown: format!("*Not run: the results have no `{file}`.*\n"),
            aims,
            charts: Vec::new(),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    Met,
    NotMet,
    NotMeasured,
}

impl Verdict {
    /// Of an aim with several parts (paths, connection counts): not met if any
    /// part is not met, else not measured if any part (or every part, there being
    /// none) is not measured, else met.
    pub fn all(parts: impl IntoIterator<Item = Verdict>) -> Verdict {
        let mut out = None;
        for p in parts {
            out = Some(match (out, p) {
                (_, Verdict::NotMet) | (Some(Verdict::NotMet), _) => Verdict::NotMet,
                (_, Verdict::NotMeasured) | (Some(Verdict::NotMeasured), _) => Verdict::NotMeasured,
                _ => Verdict::Met,
            });
        }
        out.unwrap_or(Verdict::NotMeasured)
    }

    pub fn from_bool(met: bool) -> Verdict {
        if met { Verdict::Met } else { Verdict::NotMet }
    }
}

impl fmt::Display for Verdict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Verdict::Met => "**met**",
            Verdict::NotMet => "**not met**",
            Verdict::NotMeasured => "not measured",
        })
    }
}

/// One of the benchmarks' aims with what was measured against it.
#[derive(Clone, Debug)]
pub struct Aim {
    /// The heading's anchor in BENCHMARKS.md ("build" for `## Build`).
    pub anchor: &'static str,
    /// The section's name, for the link.
    pub section: &'static str,
    pub goal: String,
    pub measured: String,
    pub verdict: Verdict,
}

impl Aim {
    /// The bullet a section writes under its tables: "- Aim: …: **met** — measured."
    pub fn bullet(&self) -> String {
        format!(
            "- Aim: {}: {} — {}.\n",
            self.goal, self.verdict, self.measured
        )
    }
}

/// A Markdown table built row by row.
#[derive(Clone, Debug)]
pub struct Table {
    header: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl Table {
    pub fn new(header: &[&str]) -> Self {
        Self {
            header: header.iter().map(|h| (*h).to_string()).collect(),
            rows: Vec::new(),
        }
    }

    pub fn row(&mut self, cells: Vec<String>) {
        debug_assert_eq!(cells.len(), self.header.len(), "{cells:?}");
        self.rows.push(cells);
    }

    pub fn render(&self) -> String {
        let line = |cells: &[String]| format!("| {} |\n", cells.join(" | "));
        let mut out = line(&self.header);
        let _ = writeln!(out, "|{}", "---|".repeat(self.header.len()));
        for r in &self.rows {
            out.push_str(&line(
                &r.iter().map(|c| c.replace('|', "\\|")).collect::<Vec<_>>(),
            ));
        }
        out
    }
}

/// `values` in order of first appearance, without repeats.
pub fn distinct<K: PartialEq>(values: impl IntoIterator<Item = K>) -> Vec<K> {
    let mut out = Vec::new();
    for v in values {
        if !out.contains(&v) {
            out.push(v);
        }
    }
    out
}

/// τ as written in tables: "1", "0.5".
pub fn tau(t: f64) -> String {
    format!("{t}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn verdicts_combine_pessimistically() {
        use Verdict::{Met, NotMeasured, NotMet};
        assert_eq!(Verdict::all([Met, Met]), Met);
        assert_eq!(Verdict::all([Met, NotMet]), NotMet);
        assert_eq!(Verdict::all([NotMet, NotMeasured, Met]), NotMet);
        assert_eq!(Verdict::all([Met, NotMeasured]), NotMeasured);
        assert_eq!(Verdict::all([]), NotMeasured);
    }

    #[test]
    fn tables_render_as_markdown() {
        let mut t = Table::new(&["a", "b"]);
        t.row(vec!["1".into(), "x|y".into()]);
        assert_eq!(t.render(), "| a | b |\n|---|---|\n| 1 | x\\|y |\n");
    }

    #[test]
    fn distinct_keeps_first_appearance_order() {
        assert_eq!(distinct([2, 2, 1, 3, 2]), vec![2, 1, 3]);
    }
}
