//! `{{gonzalez}}`: González et al.'s table — image error against the
//! full-resolution reference and frame time for each parallax mode (none, offset,
//! iterative, binary search) at τ = 1, 2, 4 — and the ratio of each mode's MSE to
//! tessellation alone at the same τ, as in their Fig. 11b.
//!
//! Aim: binary-search parallax brings the MSE to ≤ 1/5 of tessellation alone at
//! τ = 4.

use super::{Aim, Ctx, Section, Table, Verdict, distinct, tau};
use crate::chart::{BarChart, BarSeries, HEIGHT, Reference, WIDTH};
use crate::results::{Frame, Gonzalez};
use crate::stats::{Spread, median, num, ratio};

pub const ANCHOR: &str = "parallax-the-gonzález-table";
const NAME: &str = "Parallax";
const NONE: &str = "none";
const BINARY: &str = "binary";
const AIM_TAU: f64 = 4.0;
const AIM_RATIO: f64 = 0.2;
const MODES: [&str; 4] = ["none", "offset", "iterative", "binary"];

fn aim(measured: String, verdict: Verdict) -> Aim {
    Aim {
        anchor: ANCHOR,
        section: NAME,
        goal: "binary-search parallax MSE ≤ 1/5 of tessellation alone at τ = 4".into(),
        measured,
        verdict,
    }
}

/// One (flight, τ, mode) over its runs.
struct Row {
    flight: String,
    tau: f64,
    mode: String,
    runs: usize,
    measured: usize,
    /// Over the measured frames of every run.
    mse: Option<Spread>,
    psnr: Option<f64>,
    /// Per-run medians of render time over drawn frames.
    frame_ms: Option<Spread>,
}

impl Row {
    fn of(flight: String, runs: &[&Gonzalez]) -> Row {
        let measured: Vec<&Frame> = runs
            .iter()
            .flat_map(|r| r.frames.iter())
            .filter(|f| f.measured() && f.mse.is_some())
            .collect();
        Row {
            flight,
            tau: runs[0].tau,
            mode: runs[0].parallax.clone(),
            runs: runs.len(),
            measured: measured.len(),
            mse: Spread::of(measured.iter().filter_map(|f| f.mse)),
            psnr: median(&measured.iter().filter_map(|f| f.psnr).collect::<Vec<_>>()),
            frame_ms: Spread::of(runs.iter().filter_map(|r| {
                let t: Vec<f64> = r
                    .frames
                    .iter()
                    .filter(|f| f.drawn())
                    .map(|f| f.render_ms)
                    .collect();
                median(&t)
            })),
        }
    }
}

fn mode_rank(m: &str) -> usize {
    MODES.iter().position(|x| *x == m).unwrap_or(MODES.len())
}

pub fn section(records: Option<&[Gonzalez]>, ctx: &Ctx) -> Section {
    let Some(records) = records.filter(|r| !r.is_empty()) else {
        return Section::not_run(
            "gonzalez.jsonl",
            vec![aim("not run".into(), Verdict::NotMeasured)],
        );
    };
    let flights = distinct(
        records
            .iter()
            .map(|r| (r.dataset.as_str(), r.path.as_str())),
    );
    let mut modes = distinct(records.iter().map(|r| r.parallax.as_str()));
    modes.sort_by_key(|m| mode_rank(m));
    let mut rows = Vec::new();
    for &(dataset, path) in &flights {
        let mut taus = distinct(
            records
                .iter()
                .filter(|r| r.dataset == dataset && r.path == path)
                .map(|r| r.tau),
        );
        taus.sort_by(f64::total_cmp);
        for t in taus {
            for &mode in &modes {
                let runs: Vec<&Gonzalez> = records
                    .iter()
                    .filter(|r| {
                        r.dataset == dataset && r.path == path && r.tau == t && r.parallax == mode
                    })
                    .collect();
                if !runs.is_empty() {
                    rows.push(Row::of(format!("{dataset} `{path}`"), &runs));
                }
            }
        }
    }
    let to_none = |r: &Row| -> Option<f64> {
        let none = rows
            .iter()
            .find(|n| n.flight == r.flight && n.tau == r.tau && n.mode == NONE)?;
        let (m, n) = (r.mse?.median, none.mse?.median);
        (n > 0.0).then(|| m / n)
    };
    let mut table = Table::new(&[
        "flight",
        "τ",
        "parallax",
        "runs",
        "measured frames",
        "MSE, median (min–max of frames)",
        "MSE ÷ none",
        "median PSNR dB",
        "frame ms, median (min–max of runs)",
    ]);
    for r in &rows {
        table.row(vec![
            r.flight.clone(),
            tau(r.tau),
            r.mode.clone(),
            r.runs.to_string(),
            r.measured.to_string(),
            r.mse.map_or_else(|| "—".into(), |m| m.fmt()),
            to_none(r).map_or_else(|| "—".into(), ratio),
            r.psnr.map_or_else(|| "—".into(), num),
            r.frame_ms.map_or_else(|| "—".into(), |t| t.fmt()),
        ]);
    }
    let at_aim: Vec<(&Row, Option<f64>)> = rows
        .iter()
        .filter(|r| r.tau == AIM_TAU && r.mode == BINARY)
        .map(|r| (r, to_none(r)))
        .collect();
    let verdict = if at_aim.is_empty() {
        aim(
            "binary parallax not run at τ = 4".into(),
            Verdict::NotMeasured,
        )
    } else {
        let measured: Vec<String> = at_aim
            .iter()
            .map(|(r, q)| match q {
                Some(q) => format!("{}: {} of none's MSE", r.flight, ratio(*q)),
                None => format!("{}: no MSE for none or binary", r.flight),
            })
            .collect();
        aim(
            measured.join("; "),
            Verdict::all(at_aim.iter().map(|(_, q)| match q {
                Some(q) => Verdict::from_bool(*q <= AIM_RATIO),
                None => Verdict::NotMeasured,
            })),
        )
    };
    let mut s = Section {
        markdown: table.render(),
        aims: vec![verdict],
        charts: Vec::new(),
    };
    s.markdown.push('\n');
    for a in &s.aims {
        s.markdown.push_str(&a.bullet());
    }
    // The chart: the first flight (the benchmark runs one).
    if let Some(&(dataset, path)) = flights.first() {
        let flight = format!("{dataset} `{path}`");
        let taus = distinct(rows.iter().filter(|r| r.flight == flight).map(|r| r.tau));
        let chart = BarChart {
            title: format!("MSE relative to no parallax ({dataset}, {path})"),
            y_label: "MSE / MSE without parallax".into(),
            categories: taus.iter().map(|t| format!("τ = {}", tau(*t))).collect(),
            series: modes
                .iter()
                .map(|&mode| BarSeries {
                    name: mode.to_string(),
                    values: taus
                        .iter()
                        .map(|&t| {
                            rows.iter()
                                .find(|r| r.flight == flight && r.tau == t && r.mode == mode)
                                .and_then(to_none)
                        })
                        .collect(),
                })
                .collect(),
            references: vec![Reference {
                value: AIM_RATIO,
                label: "aim 0.2 for binary at τ = 4".into(),
            }],
            log_y: false,
        };
        ctx.chart(
            &mut s,
            "gonzalez.png",
            "MSE of each parallax mode relative to tessellation alone, by τ",
            chart.draw(WIDTH, HEIGHT),
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(mse: Option<f64>, render_ms: f64) -> Frame {
        Frame {
            triangles: 1000,
            draw_calls: 4,
            render_ms,
            converged: Some(true),
            psnr: mse.map(|m| 10.0 * (255.0 * 255.0 / m).log10()),
            mse,
        }
    }

    fn rec(tau: f64, parallax: &str, run: u32, mse: f64, ms: f64) -> Gonzalez {
        Gonzalez {
            dataset: "moon4096".into(),
            path: "pass".into(),
            tau,
            parallax: parallax.into(),
            run,
            frames: vec![
                frame(None, ms),
                frame(Some(mse), ms + 1.0),
                frame(Some(mse), ms),
            ],
        }
    }

    fn records(binary_mse: f64) -> Vec<Gonzalez> {
        let mut r = Vec::new();
        for run in 1..=3 {
            for t in [4.0, 1.0] {
                r.push(rec(t, BINARY, run, binary_mse * t, 20.0 + f64::from(run)));
                r.push(rec(t, NONE, run, 10.0 * t, 15.0));
                r.push(rec(t, "offset", run, 8.0 * t, 16.0));
            }
        }
        r
    }

    fn ctx() -> Ctx {
        Ctx {
            plots: "plots".into(),
        }
    }

    #[test]
    fn binary_at_a_fifth_of_none_meets_the_aim() {
        let s = section(Some(&records(1.5)), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::Met, "{}", s.aims[0].measured);
        assert!(
            s.aims[0].measured.contains("0.15×"),
            "{}",
            s.aims[0].measured
        );
        // Rows by τ, modes in the fixed order.
        let one = s.markdown.find("| 1 | none").expect("τ 1 none");
        let four = s.markdown.find("| 4 | none").expect("τ 4 none");
        let one_binary = s.markdown.find("| 1 | binary").expect("τ 1 binary");
        assert!(one < one_binary && one_binary < four);
        // Frame time: per-run medians 21, 22, 23 (over frames of 21, 22 and 21 ms in run 1).
        assert!(s.markdown.contains("| 22 (21–23) |"), "{}", s.markdown);
        assert_eq!(s.charts[0].file, "gonzalez.png");
    }

    #[test]
    fn binary_above_a_fifth_does_not_meet_it() {
        let s = section(Some(&records(2.5)), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::NotMet);
        assert!(
            s.aims[0].measured.contains("0.25×"),
            "{}",
            s.aims[0].measured
        );
        let r: Vec<Gonzalez> = records(1.0).into_iter().filter(|r| r.tau != 4.0).collect();
        assert_eq!(
            section(Some(&r), &ctx()).aims[0].verdict,
            Verdict::NotMeasured
        );
    }
}
