//! `{{select}}`: time per frame of view-dependent selection alone
//! (`tessera bench-select`, every error table resident) on the moon and on the
//! largest synthetic terrain, against the seeds' figures (Kang 3.0–6.1 ms, Yang
//! < 1.6 ms; other machines, so the ratios are indicative only).
//!
//! Aim: ≤ 0.5 ms per frame (median) on `synthetic:65537` at τ = 1, on every path.

use super::{Aim, Ctx, Section, Table, Verdict, distinct, tau};
use crate::chart::{BarChart, BarSeries, HEIGHT, Reference, WIDTH};
use crate::results::Select;
use crate::stats::{Spread, num, ratio};

pub const ANCHOR: &str = "selection-time";
const NAME: &str = "Selection time";
const AIM_DATASET: &str = "synthetic:65537";
const AIM_US: f64 = 500.0;
const KANG_US: (f64, f64) = (3000.0, 6100.0);
const YANG_US: f64 = 1600.0;

fn aim(measured: String, verdict: Verdict) -> Aim {
    Aim {
        anchor: ANCHOR,
        section: NAME,
        goal: format!("selection ≤ 0.5 ms per frame on `{AIM_DATASET}` (τ = 1)"),
        measured,
        verdict,
    }
}

/// One (dataset, path, τ, viewport) over its runs.
struct Row<'a> {
    dataset: &'a str,
    path: &'a str,
    tau: f64,
    viewport: (u32, u32),
    runs: usize,
    median_us: Spread,
    p90_us: Spread,
    max_us: f64,
    triangles: Spread,
    worst_deficit: f64,
}

impl<'a> Row<'a> {
    fn of(runs: &[&'a Select]) -> Option<Row<'a>> {
        let first = runs.first()?;
        let s = |f: fn(&Select) -> f64| Spread::of(runs.iter().map(|r| f(r)));
        Some(Row {
            dataset: &first.dataset,
            path: &first.path,
            tau: first.tau,
            viewport: (first.width, first.height),
            runs: runs.len(),
            median_us: s(|r| r.median_us)?,
            p90_us: s(|r| r.p90_us)?,
            max_us: s(|r| r.max_us)?.max,
            triangles: s(|r| r.median_triangles)?,
            worst_deficit: s(|r| r.worst_deficit)?.max,
        })
    }

    fn chart_label(&self) -> String {
        let dataset = self.dataset.replace(':', " ");
        if self.tau == 1.0 {
            format!("{dataset} {}", self.path)
        } else {
            format!("{dataset} {} τ={}", self.path, tau(self.tau))
        }
    }
}

/// "16.5–33.5×": the seed's range over ours.
fn range_ratio((lo, hi): (f64, f64), ours: f64) -> String {
    format!(
        "{}–{}",
        ratio(lo / ours).trim_end_matches('×'),
        ratio(hi / ours)
    )
}

pub fn section(records: Option<&[Select]>, ctx: &Ctx) -> Section {
    let Some(records) = records.filter(|r| !r.is_empty()) else {
        return Section::not_run(
            "select.jsonl",
            vec![aim("not run".into(), Verdict::NotMeasured)],
        );
    };
    let mut keys = distinct(records.iter().map(|r| {
        (
            r.dataset.as_str(),
            r.path.as_str(),
            r.tau,
            r.width,
            r.height,
        )
    }));
    // Datasets and paths as they come, τ ascending within them.
    let order = distinct(keys.iter().map(|k| (k.0, k.1)));
    keys.sort_by(|a, b| {
        let pos = |k: &(&str, &str, f64, u32, u32)| order.iter().position(|o| *o == (k.0, k.1));
        pos(a).cmp(&pos(b)).then(a.2.total_cmp(&b.2))
    });
    let rows: Vec<Row> = keys
        .iter()
        .filter_map(|k| {
            let runs: Vec<&Select> = records
                .iter()
                .filter(|r| {
                    (
                        r.dataset.as_str(),
                        r.path.as_str(),
                        r.tau,
                        r.width,
                        r.height,
                    ) == *k
                })
                .collect();
            Row::of(&runs)
        })
        .collect();
    let mut table = Table::new(&[
        "dataset",
        "path",
        "τ",
        "viewport",
        "runs",
        "median µs (min–max of runs)",
        "p90 µs",
        "slowest frame µs",
        "median triangles",
        "worst deficit",
        "Kang 3.0–6.1 ms ÷ ours",
        "Yang 1.6 ms ÷ ours",
    ]);
    for r in &rows {
        table.row(vec![
            format!("`{}`", r.dataset),
            format!("`{}`", r.path),
            tau(r.tau),
            format!("{}×{}", r.viewport.0, r.viewport.1),
            r.runs.to_string(),
            r.median_us.fmt(),
            r.p90_us.fmt(),
            num(r.max_us),
            r.triangles.fmt(),
            num(r.worst_deficit),
            range_ratio(KANG_US, r.median_us.median),
            ratio(YANG_US / r.median_us.median),
        ]);
    }
    let at_aim: Vec<&Row> = rows
        .iter()
        .filter(|r| r.dataset == AIM_DATASET && r.tau == 1.0)
        .collect();
    let verdict = if at_aim.is_empty() {
        aim(
            format!("not run on `{AIM_DATASET}` at τ = 1"),
            Verdict::NotMeasured,
        )
    } else {
        let measured: Vec<String> = at_aim
            .iter()
            .map(|r| {
                let met = r.median_us.median <= AIM_US;
                format!(
                    "`{}` {} µs ({})",
                    r.path,
                    num(r.median_us.median),
                    if met { "meets it" } else { "over" }
                )
            })
            .collect();
        aim(
            measured.join(", "),
            Verdict::all(
                at_aim
                    .iter()
                    .map(|r| Verdict::from_bool(r.median_us.median <= AIM_US)),
            ),
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
    let chart = BarChart {
        title: "Selection time per frame (median of runs, log scale)".into(),
        y_label: "µs per frame".into(),
        categories: rows.iter().map(Row::chart_label).collect(),
        series: vec![
            BarSeries {
                name: "median".into(),
                values: rows.iter().map(|r| Some(r.median_us.median)).collect(),
            },
            BarSeries {
                name: "p90".into(),
                values: rows.iter().map(|r| Some(r.p90_us.median)).collect(),
            },
        ],
        references: vec![
            Reference {
                value: AIM_US,
                label: "aim 0.5 ms (65537)".into(),
            },
            Reference {
                value: YANG_US,
                label: "Yang 1.6 ms".into(),
            },
            Reference {
                value: KANG_US.0,
                label: "Kang 3.0 ms".into(),
            },
        ],
        log_y: true,
    };
    ctx.chart(
        &mut s,
        "select.png",
        "Selection time per frame against the aim and the seeds",
        chart.draw(WIDTH, HEIGHT),
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(dataset: &str, path: &str, run: u32, median_us: f64) -> Select {
        Select {
            dataset: dataset.into(),
            path: path.into(),
            run,
            width: 1920,
            height: 1080,
            tau: 1.0,
            median_us,
            p90_us: median_us * 1.5,
            max_us: median_us * 3.0 + f64::from(run),
            median_triangles: 25_916.0,
            worst_deficit: 1.0,
        }
    }

    fn records(canyon_us: f64) -> Vec<Select> {
        let mut r = Vec::new();
        for run in 1..=3 {
            r.push(rec("moon8192", "pass", run, 130.0 + f64::from(run) * 5.0));
            r.push(rec(AIM_DATASET, "pass", run, 11.0));
            r.push(rec(AIM_DATASET, "canyon", run, canyon_us));
        }
        r
    }

    fn ctx() -> Ctx {
        Ctx {
            plots: "plots".into(),
        }
    }

    #[test]
    fn every_path_under_half_a_millisecond_meets_the_aim() {
        let s = section(Some(&records(450.0)), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::Met, "{}", s.aims[0].measured);
        assert!(s.markdown.contains("| 140 (135–145) |"), "{}", s.markdown);
        // Kang and Yang over 140 µs.
        assert!(
            s.markdown.contains("| 21.4–43.6× | 11.4× |"),
            "{}",
            s.markdown
        );
        // The slowest frame over all runs: 3 × 145 + 3.
        assert!(s.markdown.contains("| 438 |"), "{}", s.markdown);
        assert_eq!(s.charts[0].file, "select.png");
    }

    #[test]
    fn one_slow_path_fails_it() {
        let s = section(Some(&records(595.0)), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::NotMet);
        assert!(
            s.aims[0].measured.contains("`canyon` 595 µs (over)"),
            "{}",
            s.aims[0].measured
        );
        assert!(
            s.aims[0].measured.contains("`pass` 11 µs (meets it)"),
            "{}",
            s.aims[0].measured
        );
        let r: Vec<Select> = records(1.0)
            .into_iter()
            .filter(|r| r.dataset != AIM_DATASET)
            .collect();
        assert_eq!(
            section(Some(&r), &ctx()).aims[0].verdict,
            Verdict::NotMeasured
        );
    }
}
