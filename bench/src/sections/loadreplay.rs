//! `{{loadreplay}}`: one recorded trace's requests replayed by `tessera load
//! --replay`, wrk and oha side by side (bench/load.sh;
//! DECISIONS.md "Load testing: the proof around the tool"): at saturation (closed loops
//! on one pinned core) and at half of Tessera's saturation rate (open model, latency from
//! the scheduled start where the tool can).
//!
//! Aim (DECISIONS.md "Load testing: replay"): one `tessera load --replay` process on one
//! core drives at least the tiles/s that wrk drives through the same requests, so the
//! tool is never the bottleneck. Ratios are of the medians, with the spread of the
//! run-by-run ratios (the runner alternates the tools within a run).

use super::{Aim, Section, Table, Verdict, distinct};
use crate::results::LoadReplay;
use crate::stats::{Spread, fmt_paired, num, paired_ratio};
use std::fmt::Write as _;

pub const ANCHOR: &str = "load-replay";
const NAME: &str = "Load replay";

fn aim(measured: String, verdict: Verdict) -> Aim {
    Aim {
        anchor: ANCHOR,
        section: NAME,
        goal: "one `tessera load --replay` process on one core drives ≥ wrk's tiles/s on the same requests"
            .into(),
        measured,
        verdict,
    }
}

fn tool_label(tool: &str) -> String {
    match tool {
        "tessera" => "`tessera load --replay`".into(),
        "wrk" => "wrk (Lua script over the trace's targets)".into(),
        "oha" => "oha (`--urls-from-file`)".into(),
        t => t.into(),
    }
}

/// Tessera first, then wrk, then oha, then anything else.
fn tool_rank(tool: &str) -> u8 {
    match tool {
        "tessera" => 0,
        "wrk" => 1,
        "oha" => 2,
        _ => 3,
    }
}

fn runs<'a>(records: &'a [LoadReplay], tool: &str, phase: &str) -> Vec<&'a LoadReplay> {
    records
        .iter()
        .filter(|r| r.tool == tool && r.phase == phase)
        .collect()
}

fn spread(runs: &[&LoadReplay], f: impl Fn(&LoadReplay) -> Option<f64>) -> String {
    Spread::of(runs.iter().filter_map(|r| f(r))).map_or_else(|| "—".into(), |s| s.fmt())
}

/// The load generator's CPU use over its run, in cores: below 1 on its one pinned
/// core, it was waiting for the server, not the other way round.
fn cores(r: &LoadReplay) -> Option<f64> {
    r.tool_cpu_s.map(|c| c / r.seconds)
}

fn errors(runs: &[&LoadReplay]) -> String {
    match Spread::of(runs.iter().map(|r| r.errors)) {
        Some(s) if s.max == 0.0 => "none".into(),
        Some(s) => s.fmt(),
        None => "—".into(),
    }
}

pub fn section(records: Option<&[LoadReplay]>) -> Section {
    let Some(records) = records.filter(|r| !r.is_empty()) else {
        return Section::not_run(
            "loadreplay.jsonl",
            vec![aim("not run".into(), Verdict::NotMeasured)],
        );
    };
    let mut tools = distinct(records.iter().map(|r| r.tool.as_str()));
    tools.sort_by_key(|t| tool_rank(t));
    let mut md = String::new();
    let first = &records[0];
    let _ = writeln!(
        md,
        "The trace: {} requests (those with a recorded 200 answer), {} tiles per request on average; {} connections.\n",
        first.trace_requests,
        num(first.trace_mean_tiles),
        distinct(records.iter().map(|r| r.connections.to_string())).join(", ")
    );

    md.push_str("**At saturation** (closed loops: each connection sends its next request when the last is answered; latency from the actual send). A generator using less than one core of CPU on its one pinned core was waiting for the server:\n\n");
    let mut table = Table::new(&[
        "load generator",
        "runs",
        "requests/s",
        "tiles/s",
        "p50 ms",
        "p99 ms",
        "p99.9 ms",
        "errors",
        "generator CPU, cores",
        "tiles per CPU second of the generator",
    ]);
    for tool in &tools {
        let rs = runs(records, tool, "saturation");
        if rs.is_empty() {
            continue;
        }
        table.row(vec![
            tool_label(tool),
            rs.len().to_string(),
            spread(&rs, |r| Some(r.requests_per_s)),
            spread(&rs, |r| Some(r.tiles_per_s)),
            spread(&rs, |r| Some(r.latency_ms_p50)),
            spread(&rs, |r| Some(r.latency_ms_p99)),
            spread(&rs, |r| r.latency_ms_p999),
            errors(&rs),
            spread(&rs, cores),
            spread(&rs, |r| {
                r.tool_cpu_s
                    .filter(|c| *c > 0.0)
                    .map(|c| r.tiles_per_s * r.seconds / c)
            }),
        ]);
    }
    md.push_str(&table.render());
    md.push('\n');
    let tiles = |tool: &str| -> Vec<(u32, f64)> {
        runs(records, tool, "saturation")
            .iter()
            .map(|r| (r.run, r.tiles_per_s))
            .collect()
    };
    let mut aims = Vec::new();
    for peer in ["wrk", "oha"] {
        let (shown, verdict) = if let Some((r, per_run)) =
            paired_ratio(&tiles("tessera"), &tiles(peer))
        {
            let shown = fmt_paired(r, per_run.as_ref());
            let _ = writeln!(
                md,
                "- Tessera ÷ {peer}, tiles/s at saturation: {shown} (ratio of the medians; run-by-run range in brackets)."
            );
            (
                format!("{shown} of wrk's tiles/s"),
                Verdict::from_bool(r >= 1.0),
            )
        } else {
            let _ = writeln!(
                md,
                "- Tessera ÷ {peer}, tiles/s at saturation: not measured (a tool is missing)."
            );
            ("not measured".into(), Verdict::NotMeasured)
        };
        if peer == "wrk" {
            aims.push(aim(shown, verdict));
        }
    }
    for a in &aims {
        md.push_str(&a.bullet());
    }

    md.push_str("\n**At half of Tessera's saturation rate** (open model: requests start on schedule whether or not earlier ones are answered):\n\n");
    let mut table = Table::new(&[
        "load generator",
        "runs",
        "target requests/s",
        "achieved requests/s",
        "rate held",
        "p50 ms",
        "p99 ms",
        "p99.9 ms",
        "errors",
        "generator CPU, cores",
        "latency from",
    ]);
    let mut any = false;
    for tool in &tools {
        let rs = runs(records, tool, "half");
        if rs.is_empty() {
            continue;
        }
        any = true;
        let held = rs.iter().filter(|r| r.rate_held == Some(true)).count();
        let known = rs.iter().filter(|r| r.rate_held.is_some()).count();
        table.row(vec![
            tool_label(tool),
            rs.len().to_string(),
            spread(&rs, |r| r.target_rate),
            spread(&rs, |r| Some(r.requests_per_s)),
            if known == 0 {
                "—".into()
            } else {
                format!("{held} of {known} runs")
            },
            spread(&rs, |r| Some(r.latency_ms_p50)),
            spread(&rs, |r| Some(r.latency_ms_p99)),
            spread(&rs, |r| r.latency_ms_p999),
            errors(&rs),
            spread(&rs, cores),
            distinct(rs.iter().map(|r| r.latency_from.as_str())).join(", "),
        ]);
    }
    if any {
        md.push_str(&table.render());
    } else {
        md.push_str("*Not run: no record of phase `half`.*\n");
    }
    Section {
        markdown: md,
        aims,
        charts: Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(tool: &str, phase: &str, run: u32, tiles_per_s: f64) -> LoadReplay {
        LoadReplay {
            tool: tool.into(),
            phase: phase.into(),
            run,
            connections: 64,
            seconds: 10.0,
            requests_per_s: tiles_per_s / 4.0,
            tiles_per_s,
            latency_ms_p50: 2.0,
            latency_ms_p99: 9.0,
            latency_ms_p999: (tool != "wrk").then_some(20.0),
            latency_from: if phase == "half" {
                "scheduled".into()
            } else {
                "closed loop".into()
            },
            target_rate: (phase == "half").then_some(1000.0),
            rate_held: (phase == "half").then_some(run != 2),
            errors: 0.0,
            tool_cpu_s: Some(5.0),
            trace_requests: 5000,
            trace_mean_tiles: 4.0,
        }
    }

    #[test]
    fn tools_are_compared_run_by_run_and_the_aim_follows_the_ratio() {
        let r = vec![
            rec("wrk", "saturation", 1, 10000.0),
            rec("tessera", "saturation", 1, 11000.0),
            rec("oha", "saturation", 1, 8000.0),
            rec("wrk", "saturation", 2, 10000.0),
            rec("tessera", "saturation", 2, 12000.0),
            rec("oha", "saturation", 2, 8000.0),
            rec("tessera", "half", 1, 4000.0),
            rec("tessera", "half", 2, 4000.0),
            rec("oha", "half", 1, 4000.0),
        ];
        let s = section(Some(&r));
        let md = &s.markdown;
        // Tessera's row first whatever the file's order.
        assert!(
            md.find("| `tessera load").expect("tessera") < md.find("| wrk").expect("wrk"),
            "{md}"
        );
        assert!(md.contains("| 11500 (11000–12000) |"), "{md}");
        // Medians 11500 / 10000; runs 1.10 and 1.20.
        assert!(
            md.contains("Tessera ÷ wrk, tiles/s at saturation: 1.15× (1.10–1.20×)"),
            "{md}"
        );
        // 11000 tiles/s × 10 s / 5 CPU s; 5 CPU s in 10 s.
        assert!(
            md.contains("| 0.5 (0.5–0.5) | 23000 (22000–24000) |"),
            "{md}"
        );
        assert!(md.contains("| 1 of 2 runs |"), "{md}");
        assert_eq!(s.aims.len(), 1);
        assert_eq!(s.aims[0].verdict, Verdict::Met);

        let slower = vec![
            rec("wrk", "saturation", 1, 10000.0),
            rec("tessera", "saturation", 1, 9000.0),
        ];
        assert_eq!(section(Some(&slower)).aims[0].verdict, Verdict::NotMet);
    }

    #[test]
    fn a_missing_file_or_peer_leaves_the_aim_not_measured() {
        assert_eq!(section(None).aims[0].verdict, Verdict::NotMeasured);
        let alone = vec![rec("tessera", "saturation", 1, 9000.0)];
        let s = section(Some(&alone));
        assert_eq!(s.aims[0].verdict, Verdict::NotMeasured);
        assert!(
            s.markdown.contains("no record of phase `half`"),
            "{}",
            s.markdown
        );
    }
}
