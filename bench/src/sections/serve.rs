//! `{{serve}}`: wrk against Tessera (Morton batches of 4, 16 and 64 tiles; one
//! tile per request) and nginx (the same tiles as static files), at each
//! connection count.
//!
//! Aims, per connection count: batches of 16 deliver at least nginx's payload
//! MB/s, at least 3× Tessera's own single-tile tiles/s, and spend at most 1.2×
//! nginx's server CPU seconds per byte served (DECISIONS.md "Object storage", serving
//! efficiency). Ratios are of the medians, with the spread of the run-by-run ratios (run
//! k against run k: the runner alternates servers within a run, so run k shares its
//! machine state). CPU figures come from rows that recorded them (`server_cpu_s`,
//! `wrk_cpu_s`, `machine_cpu_s`), per GB that wrk read (`wrk_bytes`); older results
//! without them leave that aim not measured.

use super::{Aim, Ctx, Section, Table, Verdict, distinct};
use crate::chart::{BarChart, BarSeries, HEIGHT, WIDTH};
use crate::results::Serve;
use crate::stats::{Spread, fmt_paired, paired_ratio, ratio};

pub const ANCHOR: &str = "serving";
const NAME: &str = "Serving";

/// (server, request, tiles per request).
type Kind = (String, String, u32);

fn batch16() -> Kind {
    ("tessera".into(), "batch".into(), 16)
}
fn single() -> Kind {
    ("tessera".into(), "single".into(), 1)
}
fn nginx() -> Kind {
    ("nginx".into(), "static".into(), 1)
}

fn kind_of(r: &Serve) -> Kind {
    (r.server.clone(), r.request.clone(), r.tiles_per_request)
}

fn label(k: &Kind) -> String {
    match (k.0.as_str(), k.1.as_str()) {
        ("tessera", "batch") => format!("Tessera: Morton batch of {} tiles", k.2),
        ("tessera", "single") => "Tessera: one tile per request".into(),
        ("nginx", "static") => "nginx: one static tile file per request".into(),
        (s, r) => format!("{s}: {r}, {} tiles per request", k.2),
    }
}

fn short(k: &Kind) -> String {
    match (k.0.as_str(), k.1.as_str()) {
        ("tessera", "batch") => format!("batch {}", k.2),
        ("tessera", "single") => "single".into(),
        ("nginx", "static") => "nginx".into(),
        (s, r) => format!("{s} {r} {}", k.2),
    }
}

/// Tessera batches by size, then single tiles, then nginx, then anything else.
fn kind_rank(k: &Kind) -> (u8, u32) {
    match (k.0.as_str(), k.1.as_str()) {
        ("tessera", "batch") => (0, k.2),
        ("tessera", "single") => (1, 0),
        ("nginx", _) => (2, 0),
        _ => (3, 0),
    }
}

fn aim_nginx(measured: String, verdict: Verdict) -> Aim {
    Aim {
        anchor: ANCHOR,
        section: NAME,
        goal: "Morton batches of 16 deliver at least nginx's payload MB/s on the same tiles".into(),
        measured,
        verdict,
    }
}

/// At most this many times nginx's server CPU per byte served.
const CPU_AIM: f64 = 1.2;

fn aim_cpu(measured: String, verdict: Verdict) -> Aim {
    Aim {
        anchor: ANCHOR,
        section: NAME,
        goal: format!(
            "Morton batches of 16 spend ≤ {CPU_AIM}× nginx's server CPU seconds per byte served"
        ),
        measured,
        verdict,
    }
}

fn aim_single(measured: String, verdict: Verdict) -> Aim {
    Aim {
        anchor: ANCHOR,
        section: NAME,
        goal: "Morton batches of 16 deliver ≥ 3× Tessera's one-tile-per-request tiles/s".into(),
        measured,
        verdict,
    }
}

/// (run, value) of `kind` at `conns`, for the runs that have the value.
fn per_run(
    records: &[Serve],
    kind: &Kind,
    conns: u32,
    f: fn(&Serve) -> Option<f64>,
) -> Vec<(u32, f64)> {
    records
        .iter()
        .filter(|r| r.connections == conns && kind_of(r) == *kind)
        .filter_map(|r| Some((r.run, f(r)?)))
        .collect()
}

/// One aim's ratio at every connection count: the table cells, the verdict per
/// count and the "64: 0.82×" summaries.
struct RatioAim {
    cells: Vec<String>,
    verdicts: Vec<Verdict>,
    measured: Vec<String>,
}

fn ratio_aim(
    records: &[Serve],
    conns: &[u32],
    (a, b): (&Kind, &Kind),
    f: fn(&Serve) -> Option<f64>,
    met: impl Fn(f64) -> bool,
) -> RatioAim {
    let mut out = RatioAim {
        cells: Vec::new(),
        verdicts: Vec::new(),
        measured: Vec::new(),
    };
    for &c in conns {
        if let Some((r, spread)) =
            paired_ratio(&per_run(records, a, c, f), &per_run(records, b, c, f))
        {
            out.cells.push(fmt_paired(r, spread.as_ref()));
            out.verdicts.push(Verdict::from_bool(met(r)));
            out.measured.push(format!("{c} connections: {}", ratio(r)));
        } else {
            out.cells.push("—".into());
            out.verdicts.push(Verdict::NotMeasured);
            out.measured.push(format!("{c} connections: not measured"));
        }
    }
    out
}

pub fn section(records: Option<&[Serve]>, ctx: &Ctx) -> Section {
    let Some(records) = records.filter(|r| !r.is_empty()) else {
        return Section::not_run(
            "serve.jsonl",
            vec![
                aim_nginx("not run".into(), Verdict::NotMeasured),
                aim_single("not run".into(), Verdict::NotMeasured),
                aim_cpu("not run".into(), Verdict::NotMeasured),
            ],
        );
    };
    let mut conns = distinct(records.iter().map(|r| r.connections));
    conns.sort_unstable();
    let mut kinds = distinct(records.iter().map(kind_of));
    kinds.sort_by_key(kind_rank);

    let mut table = Table::new(&[
        "server and request",
        "connections",
        "runs",
        "requests/s",
        "tiles/s",
        "payload MB/s",
        "p50 ms",
        "p99 ms",
        "errors",
    ]);
    let mut cpu = Table::new(&[
        "server and request",
        "connections",
        "server CPU s/GB",
        "wrk CPU s/GB",
        "server CPU, cores",
        "other load, cores",
    ]);
    let mut any_cpu = false;
    // Median payload MB/s per (kind, connections), for the chart.
    let mut payload: Vec<(Kind, u32, f64)> = Vec::new();
    for &c in &conns {
        for k in &kinds {
            let runs: Vec<&Serve> = records
                .iter()
                .filter(|r| r.connections == c && kind_of(r) == *k)
                .collect();
            let s = |f: fn(&Serve) -> f64| Spread::of(runs.iter().map(|r| f(r)));
            let (Some(rps), Some(tps), Some(mbps), Some(p50), Some(p99), Some(err)) = (
                s(Serve::requests_per_s),
                s(Serve::tiles_per_s),
                s(Serve::payload_mb_per_s),
                s(|r| r.p50_ms),
                s(|r| r.p99_ms),
                s(|r| r.errors),
            ) else {
                continue;
            };
            payload.push((k.clone(), c, mbps.median));
            let opt = |f: fn(&Serve) -> Option<f64>| {
                Spread::of(runs.iter().filter_map(|r| f(r))).map_or_else(|| "—".into(), |s| s.fmt())
            };
            if runs.iter().any(|r| r.server_cpu_s.is_some()) {
                any_cpu = true;
                cpu.row(vec![
                    label(k),
                    c.to_string(),
                    opt(Serve::server_cpu_s_per_gb),
                    opt(Serve::wrk_cpu_s_per_gb),
                    opt(|r| Some(r.server_cpu_s? / r.duration_s)),
                    opt(Serve::other_cores),
                ]);
            }
            table.row(vec![
                label(k),
                c.to_string(),
                runs.len().to_string(),
                rps.fmt(),
                tps.fmt(),
                mbps.fmt(),
                p50.fmt(),
                p99.fmt(),
                if err.max == 0.0 {
                    "none".into()
                } else {
                    err.fmt()
                },
            ]);
        }
    }

    let vs_nginx = ratio_aim(
        records,
        &conns,
        (&batch16(), &nginx()),
        |r| Some(r.payload_mb_per_s()),
        |r| r >= 1.0,
    );
    let vs_single = ratio_aim(
        records,
        &conns,
        (&batch16(), &single()),
        |r| Some(r.tiles_per_s()),
        |r| r >= 3.0,
    );
    let cpu_vs_nginx = ratio_aim(
        records,
        &conns,
        (&batch16(), &nginx()),
        Serve::server_cpu_s_per_gb,
        |r| r <= CPU_AIM,
    );
    let mut ratios = Table::new(&[
        "connections",
        "batch-16 payload MB/s ÷ nginx (aim ≥ 1)",
        "batch-16 tiles/s ÷ Tessera single (aim ≥ 3)",
        "batch-16 server CPU s/GB ÷ nginx (aim ≤ 1.2)",
    ]);
    for (i, c) in conns.iter().enumerate() {
        ratios.row(vec![
            c.to_string(),
            vs_nginx.cells[i].clone(),
            vs_single.cells[i].clone(),
            cpu_vs_nginx.cells[i].clone(),
        ]);
    }
    let aims = vec![
        aim_nginx(
            vs_nginx.measured.join("; "),
            Verdict::all(vs_nginx.verdicts.iter().copied()),
        ),
        aim_single(
            vs_single.measured.join("; "),
            Verdict::all(vs_single.verdicts.iter().copied()),
        ),
        aim_cpu(
            cpu_vs_nginx.measured.join("; "),
            Verdict::all(cpu_vs_nginx.verdicts.iter().copied()),
        ),
    ];
    let cpu_table = if any_cpu {
        format!(
            "\nCPU seconds (user + system, from `/proc/PID/stat` before and after the row; nginx: \
             master and workers) per GB that wrk read in the row (responses still in flight at its \
             end count, so megabyte responses at 1024 connections are not missed; headers are under \
             0.3%), for the server and for wrk, the CPU the server got, and what every other process \
             on the machine used meanwhile (noise):\n\n{}",
            cpu.render()
        )
    } else {
        String::new()
    };
    let mut s = Section {
        markdown: format!(
            "{}{cpu_table}\nRatios of the medians, with the range of the run-by-run ratios in brackets:\n\n{}\n",
            table.render(),
            ratios.render()
        ),
        aims,
        charts: Vec::new(),
    };
    for a in &s.aims {
        s.markdown.push_str(&a.bullet());
    }
    let chart = BarChart {
        title: "Payload MB/s by connections (median of runs)".into(),
        y_label: "payload MB/s".into(),
        categories: conns.iter().map(|c| format!("{c} connections")).collect(),
        series: kinds
            .iter()
            .map(|k| BarSeries {
                name: short(k),
                values: conns
                    .iter()
                    .map(|c| {
                        payload
                            .iter()
                            .find(|(pk, pc, _)| pk == k && pc == c)
                            .map(|p| p.2)
                    })
                    .collect(),
            })
            .collect(),
        references: Vec::new(),
        log_y: false,
    };
    ctx.chart(
        &mut s,
        "serve.png",
        "Payload MB/s of Tessera's batches and single tiles and of nginx, by connections",
        chart.draw(WIDTH, HEIGHT),
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 10 s row with `tps` tiles/s of 100 kB tiles.
    fn rec(kind: &Kind, connections: u32, run: u32, tps: f64) -> Serve {
        Serve {
            server: kind.0.clone(),
            request: kind.1.clone(),
            tiles_per_request: kind.2,
            connections,
            run,
            duration_s: 10.0,
            requests: tps * 10.0 / f64::from(kind.2),
            errors: 0.0,
            p50_ms: 2.0,
            p99_ms: 5.0,
            mean_tile_bytes: 100_000.0,
            wrk_bytes: None,
            server_cpu_s: None,
            wrk_cpu_s: None,
            machine_cpu_s: None,
        }
    }

    fn ctx() -> Ctx {
        Ctx {
            plots: "plots".into(),
        }
    }

    fn records(batch: [f64; 2], single_tps: f64, nginx_tps: f64) -> Vec<Serve> {
        let mut r = Vec::new();
        for c in [256, 64] {
            for run in 1..=2 {
                r.push(rec(&batch16(), c, run, batch[run as usize - 1]));
                r.push(rec(&single(), c, run, single_tps));
                r.push(rec(&nginx(), c, run, nginx_tps));
            }
        }
        r
    }

    #[test]
    fn batches_beating_nginx_and_singles_meet_both_aims() {
        let r = records([40_000.0, 44_000.0], 10_000.0, 30_000.0);
        let s = section(Some(&r), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::Met, "{}", s.aims[0].measured);
        assert_eq!(s.aims[1].verdict, Verdict::Met, "{}", s.aims[1].measured);
        // 42 000 tiles/s of 100 kB = 4200 MB/s; ÷ nginx's 3000 = 1.40.
        assert!(
            s.markdown.contains("| 4200 (4000–4400) |"),
            "{}",
            s.markdown
        );
        assert!(
            s.markdown.contains("| 1.40× (1.33–1.47×) |"),
            "{}",
            s.markdown
        );
        // Connection counts in ascending order.
        assert!(s.markdown.find("| 64 |") < s.markdown.find("| 256 |"));
        assert_eq!(s.charts[0].file, "serve.png");
        assert!(s.markdown.contains("](plots/serve.png)"));
    }

    #[test]
    fn slower_batches_do_not_meet_the_aims() {
        let r = records([28_000.0, 28_000.0], 26_000.0, 34_000.0);
        let s = section(Some(&r), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::NotMet);
        assert_eq!(s.aims[1].verdict, Verdict::NotMet);
        assert!(
            s.aims[1].measured.contains("64 connections: 1.08×"),
            "{}",
            s.aims[1].measured
        );
    }

    /// `records` with CPU figures: each server spends `per_gb` CPU seconds per GB
    /// of payload (a 10 s row of 100 kB tiles), wrk 1 s, and 2 s go elsewhere.
    fn with_cpu(mut r: Vec<Serve>, batch_per_gb: f64, nginx_per_gb: f64) -> Vec<Serve> {
        for x in &mut r {
            let gb = x.requests * f64::from(x.tiles_per_request) * 100_000.0 / 1e9;
            let per_gb = if x.server == "nginx" {
                nginx_per_gb
            } else {
                batch_per_gb
            };
            x.server_cpu_s = Some(per_gb * gb);
            x.wrk_cpu_s = Some(1.0);
            x.machine_cpu_s = Some(per_gb * gb + 3.0);
        }
        r
    }

    #[test]
    fn cpu_per_byte_within_the_aim_is_met_and_absent_figures_are_not_measured() {
        let r = with_cpu(records([40_000.0, 44_000.0], 10_000.0, 30_000.0), 0.33, 0.3);
        let s = section(Some(&r), &ctx());
        assert_eq!(s.aims[2].verdict, Verdict::Met, "{}", s.aims[2].measured);
        assert!(
            s.markdown.contains("| 1.10× (1.10–1.10×) |"),
            "{}",
            s.markdown
        );
        // The CPU table: 0.33 s/GB; wrk's 1 s over 40 or 44 GB; 2 s of 10 elsewhere.
        assert!(
            s.markdown.contains(
                "| Tessera: Morton batch of 16 tiles | 64 | 0.33 (0.33–0.33) | 0.0239 (0.0227–0.0250) |"
            ),
            "{}",
            s.markdown
        );
        assert!(s.markdown.contains("| 0.2 (0.2–0.2) |"), "{}", s.markdown);

        let r = with_cpu(records([40_000.0, 44_000.0], 10_000.0, 30_000.0), 0.5, 0.3);
        let s = section(Some(&r), &ctx());
        assert_eq!(s.aims[2].verdict, Verdict::NotMet);
        assert!(
            s.aims[2].measured.contains("64 connections: 1.67×"),
            "{}",
            s.aims[2].measured
        );

        // Results from before CPU was recorded: no CPU table, the aim not measured.
        let s = section(
            Some(&records([40_000.0, 44_000.0], 10_000.0, 30_000.0)),
            &ctx(),
        );
        assert_eq!(s.aims[2].verdict, Verdict::NotMeasured);
        assert!(!s.markdown.contains("server CPU s/GB |"), "{}", s.markdown);
    }

    #[test]
    fn one_failing_connection_count_fails_the_aim_and_missing_peers_are_not_measured() {
        let mut r = records([40_000.0, 40_000.0], 10_000.0, 30_000.0);
        for x in r
            .iter_mut()
            .filter(|x| x.connections == 256 && x.server == "nginx")
        {
            x.requests *= 2.0;
        }
        let s = section(Some(&r), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::NotMet);
        let r: Vec<Serve> = records([40_000.0, 40_000.0], 10_000.0, 30_000.0)
            .into_iter()
            .filter(|x| x.server != "nginx")
            .collect();
        let s = section(Some(&r), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::NotMeasured);
        assert_eq!(s.aims[1].verdict, Verdict::Met);
    }
}
