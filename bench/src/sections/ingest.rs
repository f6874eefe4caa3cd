//! `{{ingest}}`: real datasets (DECISIONS.md "Mosaics", "Mixed-grid collections") —
//! one file against a 64-file mosaic of the same samples, reprojection (`build --to
//! EPSG:4326`) against `gdalwarp`, and a mosaic of 64 pieces in 3 CRSs against
//! `gdalwarp` to one file followed by the build of that file.
//!
//! Aims: the mosaic builds within 1.1× the one file's wall time with the same peak
//! RSS (within 10 %); reprojection at least as fast as `gdalwarp -r bilinear`; the
//! mixed-grid mosaic within 1.3× the wall time of gdalwarp + the single build, with
//! its peak RSS under its `--memory` budget. Ratios are paired by run (the commands
//! alternate within each run).

use super::{Aim, Section, Table, Verdict};
use crate::results::Ingest;
use crate::stats::{Spread, fmt_paired, num, paired_ratio};
use std::fmt::Write as _;

pub const ANCHOR: &str = "real-datasets";
const NAME: &str = "Real datasets";
const ONE: &str = "one file";
const MOSAIC: &str = "64-file mosaic";
const GDALWARP: &str = "gdalwarp -r bilinear";
const TO: &str = "tessera build --to";
const PLAIN: &str = "tessera build (no --to)";
const MIXED: &str = "64 pieces in 3 CRSs";
const MIXED_WARP: &str = "gdalwarp -r bilinear (64 pieces)";
const MIXED_SINGLE: &str = "tessera build (gdalwarp's output)";

fn aim(goal: &str, measured: String, verdict: Verdict) -> Aim {
    Aim {
        anchor: ANCHOR,
        section: NAME,
        goal: goal.into(),
        measured,
        verdict,
    }
}

const AIM_WALL: &str =
    "a 64-file mosaic builds within 1.1× the wall time of the same samples as one file";
const AIM_RSS: &str = "the mosaic's peak RSS the same as the one file's (within 10 %)";
const AIM_WARP: &str =
    "reprojection to EPSG:4326 at least as fast (M samples/s) as `gdalwarp -r bilinear`";
const AIM_MIXED_WALL: &str = "a mosaic of 64 pieces in 3 CRSs builds within 1.3× the wall time \
     of `gdalwarp` to one file followed by the build of that file";
const AIM_MIXED_RSS: &str = "the mixed-grid build's peak RSS under its `--memory` budget";

fn pairs(records: &[Ingest], case: &str, tool: &str, f: fn(&Ingest) -> f64) -> Vec<(u32, f64)> {
    records
        .iter()
        .filter(|r| r.case == case && r.tool == tool)
        .map(|r| (r.run, f(r)))
        .collect()
}

pub fn section(records: Option<&[Ingest]>) -> Section {
    let not_measured = || {
        vec![
            aim(AIM_WALL, "not run".into(), Verdict::NotMeasured),
            aim(AIM_RSS, "not run".into(), Verdict::NotMeasured),
            aim(AIM_WARP, "not run".into(), Verdict::NotMeasured),
            aim(AIM_MIXED_WALL, "not run".into(), Verdict::NotMeasured),
            aim(AIM_MIXED_RSS, "not run".into(), Verdict::NotMeasured),
        ]
    };
    let Some(records) = records.filter(|r| !r.is_empty()) else {
        return Section::not_run("ingest.jsonl", not_measured());
    };
    let mut table = Table::new(&[
        "case",
        "command",
        "runs",
        "wall s, median (min–max)",
        "CPU s",
        "peak RSS MiB",
        "M input samples/s",
    ]);
    for (case, tool) in [
        ("mosaic", ONE),
        ("mosaic", MOSAIC),
        ("reproject", GDALWARP),
        ("reproject", TO),
        ("reproject", PLAIN),
        ("mixed", MIXED),
        ("mixed", MIXED_WARP),
        ("mixed", MIXED_SINGLE),
    ] {
        let runs: Vec<&Ingest> = records
            .iter()
            .filter(|r| r.case == case && r.tool == tool)
            .collect();
        let s = |f: fn(&Ingest) -> f64| Spread::of(runs.iter().map(|r| f(r)));
        let (Some(wall), Some(cpu), Some(rss), Some(rate)) = (
            s(|r| r.wall_s),
            s(|r| r.cpu_s),
            s(|r| r.rss_mib),
            s(|r| r.samples / r.wall_s / 1e6),
        ) else {
            continue;
        };
        table.row(vec![
            case.into(),
            format!("`{tool}`"),
            runs.len().to_string(),
            wall.fmt(),
            num(cpu.median),
            num(rss.median),
            rate.fmt(),
        ]);
    }
    let mut md = table.render();
    let mut aims = Vec::new();

    let wall = paired_ratio(
        &pairs(records, "mosaic", MOSAIC, |r| r.wall_s),
        &pairs(records, "mosaic", ONE, |r| r.wall_s),
    );
    let rss = paired_ratio(
        &pairs(records, "mosaic", MOSAIC, |r| r.rss_mib),
        &pairs(records, "mosaic", ONE, |r| r.rss_mib),
    );
    aims.push(match &wall {
        Some((r, per)) => aim(
            AIM_WALL,
            format!(
                "{} of the one file's wall time",
                fmt_paired(*r, per.as_ref())
            ),
            Verdict::from_bool(*r <= 1.1),
        ),
        None => aim(AIM_WALL, "not measured".into(), Verdict::NotMeasured),
    });
    aims.push(match &rss {
        Some((r, per)) => aim(
            AIM_RSS,
            format!(
                "{} of the one file's peak RSS",
                fmt_paired(*r, per.as_ref())
            ),
            Verdict::from_bool((r - 1.0).abs() <= 0.10),
        ),
        None => aim(AIM_RSS, "not measured".into(), Verdict::NotMeasured),
    });

    // The reprojection's own time: the build with --to minus the build of a
    // same-sized input without it, run by run.
    let to = pairs(records, "reproject", TO, |r| r.wall_s);
    let plain = pairs(records, "reproject", PLAIN, |r| r.wall_s);
    let warp = pairs(records, "reproject", GDALWARP, |r| r.wall_s);
    let samples = records
        .iter()
        .find(|r| r.case == "reproject")
        .map_or(0.0, |r| r.samples);
    let own: Vec<(u32, f64)> = to
        .iter()
        .filter_map(|(run, t)| {
            let p = plain.iter().find(|(r2, _)| r2 == run)?.1;
            Some((*run, (t - p).max(1e-3)))
        })
        .collect();
    // Throughput ratio = gdalwarp's time / our reprojection's time.
    aims.push(match paired_ratio(&warp, &own) {
        Some((r, per)) => {
            let ours = Spread::of(own.iter().map(|(_, t)| samples / t / 1e6));
            let _ = writeln!(
                md,
                "\nReprojection alone (`build --to` minus the build without it, run by run): \
                 {} M input samples/s.",
                ours.map_or_else(|| "—".into(), |s| s.fmt())
            );
            aim(
                AIM_WARP,
                format!("{} gdalwarp's throughput", fmt_paired(r, per.as_ref())),
                Verdict::from_bool(r >= 1.0),
            )
        }
        None => aim(AIM_WARP, "not measured".into(), Verdict::NotMeasured),
    });
    mixed(records, &mut md, &mut aims);
    for a in &aims {
        md.push_str(&a.bullet());
    }
    Section {
        markdown: md,
        aims,
        charts: Vec::new(),
    }
}

/// The mixed-grid aims: the build against gdalwarp + the single build, run by run, and
/// the build's largest peak RSS against its budget.
fn mixed(records: &[Ingest], md: &mut String, aims: &mut Vec<Aim>) {
    let build = pairs(records, "mixed", MIXED, |r| r.wall_s);
    let warp = pairs(records, "mixed", MIXED_WARP, |r| r.wall_s);
    let single = pairs(records, "mixed", MIXED_SINGLE, |r| r.wall_s);
    let both: Vec<(u32, f64)> = warp
        .iter()
        .filter_map(|(run, w)| {
            let s = single.iter().find(|(r2, _)| r2 == run)?.1;
            Some((*run, w + s))
        })
        .collect();
    aims.push(match paired_ratio(&build, &both) {
        Some((r, per)) => {
            let _ = writeln!(
                md,
                "\nMixed grids: `gdalwarp` + the build of its output, run by run: {} s; \
                 the mixed-grid build: {} s.",
                Spread::of(both.iter().map(|(_, t)| *t)).map_or_else(|| "—".into(), |s| s.fmt()),
                Spread::of(build.iter().map(|(_, t)| *t)).map_or_else(|| "—".into(), |s| s.fmt())
            );
            aim(
                AIM_MIXED_WALL,
                format!(
                    "{} of gdalwarp + the single build's wall time",
                    fmt_paired(r, per.as_ref())
                ),
                Verdict::from_bool(r <= 1.3),
            )
        }
        None => aim(AIM_MIXED_WALL, "not measured".into(), Verdict::NotMeasured),
    });
    let runs: Vec<&Ingest> = records
        .iter()
        .filter(|r| r.case == "mixed" && r.tool == MIXED)
        .collect();
    let peak = runs
        .iter()
        .map(|r| r.rss_mib)
        .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v))));
    // The smallest budget any run had (they all have the script's one).
    let budget = runs
        .iter()
        .filter_map(|r| r.memory_mib)
        .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.min(v))));
    aims.push(match (peak, budget) {
        (Some(peak), Some(budget)) => aim(
            AIM_MIXED_RSS,
            format!(
                "{} MiB at most in {} run{}, budget {} MiB",
                num(peak),
                runs.len(),
                if runs.len() == 1 { "" } else { "s" },
                num(budget)
            ),
            Verdict::from_bool(peak < budget),
        ),
        _ => aim(AIM_MIXED_RSS, "not measured".into(), Verdict::NotMeasured),
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(case: &str, tool: &str, run: u32, wall_s: f64, rss_mib: f64) -> Ingest {
        Ingest {
            case: case.into(),
            tool: tool.into(),
            run,
            samples: 12e6,
            wall_s,
            cpu_s: wall_s,
            rss_mib,
            memory_mib: (case == "mixed").then_some(256.0),
        }
    }

    #[test]
    fn verdicts_follow_the_paired_ratios() {
        let r = vec![
            rec("mosaic", ONE, 1, 10.0, 100.0),
            rec("mosaic", MOSAIC, 1, 10.5, 104.0),
            rec("reproject", GDALWARP, 1, 4.0, 50.0),
            rec("reproject", TO, 1, 9.0, 60.0),
            rec("reproject", PLAIN, 1, 6.0, 60.0),
            rec("mixed", MIXED, 1, 1.2, 50.0),
            rec("mixed", MIXED_WARP, 1, 0.8, 60.0),
            rec("mixed", MIXED_SINGLE, 1, 0.2, 40.0),
        ];
        let s = section(Some(&r));
        let v: Vec<Verdict> = s.aims.iter().map(|a| a.verdict).collect();
        // 1.05× wall, 1.04× RSS; our reprojection 3 s against gdalwarp's 4 s; the
        // mixed build 1.2 s against 0.8 + 0.2 s (1.2×), 50 MiB of 256.
        assert_eq!(
            v,
            [
                Verdict::Met,
                Verdict::Met,
                Verdict::Met,
                Verdict::Met,
                Verdict::Met
            ],
            "{}",
            s.markdown
        );
        assert!(
            s.markdown
                .contains("run by run: 1 s; the mixed-grid build: 1.2 s."),
            "{}",
            s.markdown
        );
        assert!(
            s.markdown
                .contains("50 MiB at most in 1 run, budget 256 MiB"),
            "{}",
            s.markdown
        );
        assert!(s.markdown.contains("4 M input samples/s"), "{}", s.markdown);
        let slow = vec![
            rec("mosaic", ONE, 1, 10.0, 100.0),
            rec("mosaic", MOSAIC, 1, 12.0, 150.0),
            rec("reproject", GDALWARP, 1, 2.0, 50.0),
            rec("reproject", TO, 1, 9.0, 60.0),
            rec("reproject", PLAIN, 1, 6.0, 60.0),
            rec("mixed", MIXED, 1, 1.4, 300.0),
            rec("mixed", MIXED_WARP, 1, 0.8, 60.0),
            rec("mixed", MIXED_SINGLE, 1, 0.2, 40.0),
        ];
        let v: Vec<Verdict> = section(Some(&slow))
            .aims
            .iter()
            .map(|a| a.verdict)
            .collect();
        assert_eq!(v, [Verdict::NotMet; 5]);
        let none = section(None);
        assert!(none.aims.iter().all(|a| a.verdict == Verdict::NotMeasured));
    }
}
