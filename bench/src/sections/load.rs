//! `{{load}}`: the `tessera load` replay, many real fly-through clients against
//! one server, with Morton-range batches and with one tile per request. There is
//! no aim; the ratio ranges ÷ single tiles/s shows what batching buys under a
//! real request pattern rather than wrk's uniform one.

use super::{Ctx, Section, Table, distinct};
use crate::chart::{BarChart, BarSeries, HEIGHT, WIDTH};
use crate::results::Load;
use crate::stats::{Spread, fmt_paired, paired_ratio, pct_spread};
use std::fmt::Write as _;

fn mode_label(mode: &str) -> String {
    match mode {
        "ranges" => "ranges (Morton batches)".into(),
        "single" => "single (one tile per request)".into(),
        m => m.into(),
    }
}

pub fn section(records: Option<&[Load]>, ctx: &Ctx) -> Section {
    let Some(records) = records.filter(|r| !r.is_empty()) else {
        return Section::not_run("load.jsonl", Vec::new());
    };
    let mut modes = distinct(records.iter().map(|r| r.mode.as_str()));
    modes.sort_by_key(|m| (*m != "ranges", *m != "single"));
    let mut table = Table::new(&[
        "mode",
        "clients",
        "runs",
        "requests/s",
        "tiles/s",
        "MB/s",
        "p50 ms",
        "p90 ms",
        "p99 ms",
        "max ms",
        "errors",
        "frames within 2τ",
    ]);
    let mut latencies: Vec<(String, [f64; 4])> = Vec::new();
    for mode in &modes {
        let runs: Vec<&Load> = records.iter().filter(|r| r.mode == *mode).collect();
        let s = |f: fn(&Load) -> f64| Spread::of(runs.iter().map(|r| f(r)));
        let (Some(rps), Some(tps), Some(mb), Some(p50), Some(p90), Some(p99), Some(max)) = (
            s(|r| r.requests_per_s),
            s(|r| r.tiles_per_s),
            s(|r| r.mb_per_s),
            s(|r| r.latency_ms_p50),
            s(|r| r.latency_ms_p90),
            s(|r| r.latency_ms_p99),
            s(|r| r.latency_ms_max),
        ) else {
            continue;
        };
        let (Some(err), Some(within)) = (s(|r| r.errors), s(|r| r.frames_within_2tau)) else {
            continue;
        };
        let clients = distinct(runs.iter().map(|r| r.clients.to_string()));
        latencies.push((
            (*mode).to_string(),
            [p50.median, p90.median, p99.median, max.median],
        ));
        table.row(vec![
            mode_label(mode),
            clients.join(", "),
            runs.len().to_string(),
            rps.fmt(),
            tps.fmt(),
            mb.fmt(),
            p50.fmt(),
            p90.fmt(),
            p99.fmt(),
            max.fmt(),
            if err.max == 0.0 {
                "none".into()
            } else {
                err.fmt()
            },
            pct_spread(&within),
        ]);
    }
    let mut s = Section {
        markdown: table.render(),
        ..Section::default()
    };
    let tiles = |mode: &str| -> Vec<(u32, f64)> {
        records
            .iter()
            .filter(|r| r.mode == mode)
            .map(|r| (r.run, r.tiles_per_s))
            .collect()
    };
    s.markdown.push('\n');
    match paired_ratio(&tiles("ranges"), &tiles("single")) {
        Some((r, spread)) => {
            let _ = writeln!(
                s.markdown,
                "- Ranges ÷ single, tiles/s: {} (ratio of the medians; run-by-run range in brackets).",
                fmt_paired(r, spread.as_ref())
            );
        }
        None => s
            .markdown
            .push_str("- Ranges ÷ single, tiles/s: not measured (one of the modes is missing).\n"),
    }
    let chart = BarChart {
        title: "Request latency of the load replay (median of runs)".into(),
        y_label: "ms".into(),
        categories: ["p50", "p90", "p99", "max"].map(String::from).to_vec(),
        series: latencies
            .iter()
            .map(|(mode, v)| BarSeries {
                name: mode.clone(),
                values: v.iter().map(|&x| Some(x)).collect(),
            })
            .collect(),
        references: Vec::new(),
        log_y: false,
    };
    ctx.chart(
        &mut s,
        "load.png",
        "Latency percentiles of the load replay by mode",
        chart.draw(WIDTH, HEIGHT),
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(mode: &str, run: u32, tiles_per_s: f64) -> Load {
        Load {
            mode: mode.into(),
            run,
            clients: 64,
            requests_per_s: tiles_per_s / 10.0,
            tiles_per_s,
            mb_per_s: tiles_per_s * 0.06,
            latency_ms_p50: 20.0,
            latency_ms_p90: 900.0,
            latency_ms_p99: 1100.0,
            latency_ms_max: 1200.0,
            errors: 0.0,
            frames_within_2tau: 0.622,
        }
    }

    #[test]
    fn modes_are_tabled_and_compared_run_by_run() {
        let r = vec![
            rec("single", 1, 100.0),
            rec("ranges", 1, 330.0),
            rec("single", 2, 110.0),
            rec("ranges", 2, 350.0),
        ];
        let s = section(Some(&r), &Ctx { plots: "p".into() });
        // Ranges first whatever the file's order.
        assert!(
            s.markdown.find("| ranges").expect("ranges")
                < s.markdown.find("| single").expect("single")
        );
        assert!(s.markdown.contains("| 340 (330–350) |"), "{}", s.markdown);
        assert!(
            s.markdown.contains("| 62.2% (62.2–62.2%) |"),
            "{}",
            s.markdown
        );
        // Medians 340 / 105; runs 3.30 and 3.18.
        assert!(s.markdown.contains("3.24× (3.18–3.30×)"), "{}", s.markdown);
        assert_eq!(s.charts.len(), 1);
        assert!(s.aims.is_empty());
    }
}
