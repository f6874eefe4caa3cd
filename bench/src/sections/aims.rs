//! `{{aims}}`: every aim of the benchmarks in one table at the top — what was measured
//! and whether it is met — each linked to the section with the details. The links
//! point at headings of the template, so [`broken_links`] checks they still exist.

use super::{Aim, Verdict};
use std::fmt::Write as _;

pub fn section(aims: &[Aim]) -> String {
    let mut out = String::from("| aim | measured | verdict |\n|---|---|---|\n");
    for a in aims {
        let _ = writeln!(
            out,
            "| [{}](#{}): {} | {} | {} |",
            a.section,
            a.anchor,
            a.goal,
            a.measured.replace('|', "\\|"),
            a.verdict
        );
    }
    let count = |v: Verdict| aims.iter().filter(|a| a.verdict == v).count();
    let _ = writeln!(
        out,
        "\n{} of {} aims met, {} not met, {} not measured.",
        count(Verdict::Met),
        aims.len(),
        count(Verdict::NotMet),
        count(Verdict::NotMeasured)
    );
    out
}

/// GitHub's anchor for a heading: lower case, punctuation other than `-` and `_`
/// dropped, spaces turned into `-`.
pub fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

/// The `](#anchor)` links of `markdown` that match none of its headings.
pub fn broken_links(markdown: &str) -> Vec<String> {
    let headings: Vec<String> = markdown
        .lines()
        .filter_map(|l| {
            let t = l.trim_start();
            let hashes = t.chars().take_while(|&c| c == '#').count();
            (hashes > 0 && t[hashes..].starts_with(' ')).then(|| slug(&t[hashes..]))
        })
        .collect();
    let mut broken = Vec::new();
    for part in markdown.split("](#").skip(1) {
        let anchor = part.split(')').next().unwrap_or("");
        if !headings.iter().any(|h| h == anchor) && !broken.iter().any(|b| b == anchor) {
            broken.push(anchor.to_string());
        }
    }
    broken
}

#[cfg(test)]
mod tests {
    use super::*;

    fn aim(verdict: Verdict) -> Aim {
        Aim {
            anchor: "build",
            section: "Build",
            goal: "faster than GDAL".into(),
            measured: "0.60×".into(),
            verdict,
        }
    }

    #[test]
    fn table_links_each_aim_and_counts_verdicts() {
        let s = section(&[
            aim(Verdict::Met),
            aim(Verdict::NotMet),
            aim(Verdict::NotMeasured),
        ]);
        assert!(
            s.contains("| [Build](#build): faster than GDAL | 0.60× | **met** |"),
            "{s}"
        );
        assert!(s.contains("| **not met** |"));
        assert!(
            s.contains("1 of 3 aims met, 1 not met, 1 not measured."),
            "{s}"
        );
    }

    #[test]
    fn slugs_and_broken_links() {
        assert_eq!(
            slug("Parallax: the González table"),
            "parallax-the-gonzález-table"
        );
        assert_eq!(slug(" Streaming under latency "), "streaming-under-latency");
        let doc = "## Build\n[a](#build) [b](#serving)\n### Serving (wrk)\n";
        assert_eq!(broken_links(doc), vec!["serving".to_string()]);
        assert!(broken_links("## Serving\n[b](#serving)").is_empty());
    }
}
