//! `{{stream}}`: flights through the delaying proxy at several added round-trip
//! latencies, with prefetch on and off: how many frames meet τ and 2τ, how long
//! start-up takes, the streaming work per frame and the traffic.
//!
//! Aim: with prefetch, ≥ 99% of frames within 2τ at 150 ms added latency, on every
//! path (over the whole flight, warm-up included; the after-warm-up figure is
//! reported beside it).

use super::{Aim, Ctx, Section, Table, Verdict, distinct};
use crate::chart::{BarChart, BarSeries, HEIGHT, Reference, WIDTH};
use crate::results::Stream;
use crate::stats::{Spread, num, pct, pct_spread};

pub const ANCHOR: &str = "streaming-under-latency";
const NAME: &str = "Streaming under latency";
const AIM_LATENCY_MS: f64 = 150.0;
const AIM_WITHIN_2TAU: f64 = 0.99;

fn aim(measured: String, verdict: Verdict) -> Aim {
    Aim {
        anchor: ANCHOR,
        section: NAME,
        goal: "≥ 99% of frames within 2τ at 150 ms added latency, with prefetch".into(),
        measured,
        verdict,
    }
}

/// One (dataset, path, latency, prefetch) over its runs.
struct Row<'a> {
    flight: (&'a str, &'a str),
    latency_ms: f64,
    prefetch: bool,
    runs: usize,
    within_tau: Spread,
    within_2tau: Spread,
    warmup: Spread,
    steady_2tau: Spread,
    p99_ms: Spread,
    mb: Spread,
    requests: Spread,
}

impl<'a> Row<'a> {
    fn of(runs: &[&'a Stream]) -> Option<Row<'a>> {
        let s = |f: fn(&Stream) -> f64| Spread::of(runs.iter().map(|r| f(r)));
        let first = runs.first()?;
        Some(Row {
            flight: (&first.dataset, &first.path),
            latency_ms: first.latency_ms,
            prefetch: first.prefetch,
            runs: runs.len(),
            within_tau: s(|r| r.summary.within_tau)?,
            within_2tau: s(|r| r.summary.within_2tau)?,
            warmup: s(|r| f64::from(r.summary.warmup_frames))?,
            steady_2tau: s(|r| r.summary.steady_within_2tau)?,
            p99_ms: s(|r| r.summary.p99_stream_us / 1e3)?,
            mb: s(|r| r.summary.stream.bytes / 1e6)?,
            requests: s(|r| r.summary.stream.requests)?,
        })
    }
}

fn on_off(prefetch: bool) -> &'static str {
    if prefetch { "on" } else { "off" }
}

pub fn section(records: Option<&[Stream]>, ctx: &Ctx) -> Section {
    let Some(records) = records.filter(|r| !r.is_empty()) else {
        return Section::not_run(
            "stream.jsonl",
            vec![aim("not run".into(), Verdict::NotMeasured)],
        );
    };
    let flights = distinct(
        records
            .iter()
            .map(|r| (r.dataset.as_str(), r.path.as_str())),
    );
    let many_datasets = distinct(flights.iter().map(|f| f.0)).len() > 1;
    let flight_name = |(dataset, path): (&str, &str)| {
        if many_datasets {
            format!("{dataset} {path}")
        } else {
            path.to_string()
        }
    };
    let mut rows = Vec::new();
    for &flight in &flights {
        let of_flight: Vec<&Stream> = records
            .iter()
            .filter(|r| (r.dataset.as_str(), r.path.as_str()) == flight)
            .collect();
        let mut latencies = distinct(of_flight.iter().map(|r| r.latency_ms));
        latencies.sort_by(f64::total_cmp);
        for l in latencies {
            for prefetch in [true, false] {
                let runs: Vec<&Stream> = of_flight
                    .iter()
                    .copied()
                    .filter(|r| r.latency_ms == l && r.prefetch == prefetch)
                    .collect();
                if let Some(row) = Row::of(&runs) {
                    rows.push(row);
                }
            }
        }
    }
    let mut table = Table::new(&[
        "path",
        "added latency",
        "prefetch",
        "runs",
        "frames ≤ τ",
        "frames ≤ 2τ",
        "warm-up frames",
        "after warm-up ≤ 2τ",
        "p99 streaming work ms",
        "MB fetched",
        "requests",
    ]);
    for r in &rows {
        table.row(vec![
            format!("`{}`", flight_name(r.flight)),
            format!("{} ms", num(r.latency_ms)),
            on_off(r.prefetch).into(),
            r.runs.to_string(),
            pct_spread(&r.within_tau),
            pct_spread(&r.within_2tau),
            r.warmup.fmt(),
            pct_spread(&r.steady_2tau),
            r.p99_ms.fmt(),
            r.mb.fmt(),
            r.requests.fmt(),
        ]);
    }
    let mut verdicts = Vec::new();
    let mut measured = Vec::new();
    for &flight in &flights {
        let name = flight_name(flight);
        if let Some(r) = rows
            .iter()
            .find(|r| r.flight == flight && r.latency_ms == AIM_LATENCY_MS && r.prefetch)
        {
            verdicts.push(Verdict::from_bool(r.within_2tau.median >= AIM_WITHIN_2TAU));
            measured.push(format!(
                "`{name}`: {} (after warm-up {})",
                pct(r.within_2tau.median),
                pct(r.steady_2tau.median)
            ));
        } else {
            verdicts.push(Verdict::NotMeasured);
            measured.push(format!("`{name}`: not run at 150 ms with prefetch"));
        }
    }
    let mut s = Section {
        markdown: table.render(),
        aims: vec![aim(measured.join("; "), Verdict::all(verdicts))],
        charts: Vec::new(),
    };
    s.markdown.push('\n');
    for a in &s.aims {
        s.markdown.push_str(&a.bullet());
    }
    let cats: Vec<((&str, &str), f64)> = distinct(rows.iter().map(|r| (r.flight, r.latency_ms)));
    let chart = BarChart {
        title: "Frames within 2τ (median of runs)".into(),
        y_label: "% of frames".into(),
        categories: cats
            .iter()
            .map(|(f, l)| format!("{} {} ms", flight_name(*f), num(*l)))
            .collect(),
        series: [true, false]
            .into_iter()
            .map(|prefetch| BarSeries {
                name: format!("prefetch {}", on_off(prefetch)),
                values: cats
                    .iter()
                    .map(|(f, l)| {
                        rows.iter()
                            .find(|r| {
                                r.flight == *f && r.latency_ms == *l && r.prefetch == prefetch
                            })
                            .map(|r| r.within_2tau.median * 100.0)
                    })
                    .collect(),
            })
            .collect(),
        references: vec![Reference {
            value: AIM_WITHIN_2TAU * 100.0,
            label: "aim 99% (150 ms, prefetch)".into(),
        }],
        log_y: false,
    };
    ctx.chart(
        &mut s,
        "stream.png",
        "Percentage of frames within 2τ by path and added latency, prefetch on and off",
        chart.draw(WIDTH, HEIGHT),
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::results::flights::{FlySummary, StreamTotals};

    fn rec(path: &str, latency_ms: f64, prefetch: bool, run: u32, within_2tau: f64) -> Stream {
        Stream {
            dataset: "moon8192".into(),
            path: path.into(),
            latency_ms,
            prefetch,
            run,
            summary: FlySummary {
                within_tau: within_2tau - 0.01,
                within_2tau,
                warmup_frames: 30,
                steady_within_2tau: 1.0,
                p99_stream_us: 250.0,
                stream: StreamTotals {
                    requests: 26.0,
                    bytes: 18e6,
                },
            },
        }
    }

    fn records(pass_150: f64, canyon_150: f64) -> Vec<Stream> {
        let mut r = Vec::new();
        for run in 1..=3 {
            for (path, at_150) in [("pass", pass_150), ("canyon", canyon_150)] {
                r.push(rec(path, 150.0, true, run, at_150));
                r.push(rec(path, 150.0, false, run, at_150 - 0.02));
                r.push(rec(path, 0.0, true, run, 0.999));
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
    fn every_path_at_99_percent_meets_the_aim() {
        let s = section(Some(&records(0.995, 0.992)), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::Met, "{}", s.aims[0].measured);
        assert!(
            s.aims[0].measured.contains("`pass`: 99.5%"),
            "{}",
            s.aims[0].measured
        );
        // Latencies ascending, prefetch on before off.
        let zero = s.markdown.find("| `pass` | 0 ms | on").expect("0 ms row");
        let on = s.markdown.find("| `pass` | 150 ms | on").expect("150 on");
        let off = s.markdown.find("| `pass` | 150 ms | off").expect("150 off");
        assert!(zero < on && on < off);
        assert!(s.markdown.contains("| 18 (18–18) |"), "{}", s.markdown);
        assert_eq!(s.charts[0].file, "stream.png");
    }

    #[test]
    fn one_path_below_99_percent_fails_the_aim() {
        let s = section(Some(&records(0.962, 0.995)), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::NotMet);
        assert!(
            s.aims[0]
                .measured
                .contains("`pass`: 96.2% (after warm-up 100.0%)")
        );
        let r: Vec<Stream> = records(0.995, 0.995)
            .into_iter()
            .filter(|r| r.latency_ms != 150.0)
            .collect();
        assert_eq!(
            section(Some(&r), &ctx()).aims[0].verdict,
            Verdict::NotMeasured
        );
    }
}
