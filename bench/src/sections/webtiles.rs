//! `{{webtiles}}`: Web Mercator 512 px Terrarium tiles
//! (DECISIONS.md "Standard-grid web tiles") — Tessera cold, source-warm and warm against
//! TiTiler serving the same DEM as a COG, at 64 connections (`bench/webtiles.sh`).
//!
//! Aims: ≥ 10× TiTiler's tiles/s (each Tessera mode against the TiTiler row it is
//! paired with: cold against TiTiler's first pass, source-warm and warm against
//! TiTiler's steady state), and ≥ 2 000 tiles/s per core warm (tiles/s ÷ the
//! machine's cores, the load generator sharing them). Ratios are of the medians,
//! with the range of the run-by-run ratios (both servers are measured in every run).

use super::{Aim, Ctx, Section, Table, Verdict, distinct};
use crate::chart::{BarChart, BarSeries, HEIGHT, Reference, WIDTH};
use crate::results::{WebTile, WebTileCheck};
use crate::stats::{Spread, fmt_paired, num, paired_ratio, ratio};
use std::fmt::Write as _;

pub const ANCHOR: &str = "web-tiles";
const NAME: &str = "Web tiles";
const AIM_RATIO: f64 = 10.0;
const AIM_PER_CORE: f64 = 2000.0;

/// (server, mode) in table order; each Tessera mode with the TiTiler mode it is
/// compared with.
const ROWS: [(&str, &str, Option<&str>); 5] = [
    ("tessera", "cold", Some("cold")),
    ("tessera", "source-warm", Some("warm")),
    ("tessera", "warm", Some("warm")),
    ("titiler", "cold", None),
    ("titiler", "warm", None),
];

fn label(server: &str, mode: &str) -> String {
    match (server, mode) {
        ("tessera", "cold") => "Tessera cold: fresh server, each tile once".into(),
        ("tessera", "source-warm") => {
            "Tessera source-warm: decoded sources cached, every tile resampled and encoded".into()
        }
        ("tessera", "warm") => "Tessera warm: made tiles cached".into(),
        ("titiler", "cold") => "TiTiler first pass: fresh server, each tile once".into(),
        ("titiler", "warm") => "TiTiler steady state (no tile cache)".into(),
        (s, m) => format!("{s} {m}"),
    }
}

fn short(server: &str, mode: &str) -> String {
    match (server, mode) {
        ("tessera", m) => format!("Tessera {m}"),
        ("titiler", "cold") => "TiTiler first pass".into(),
        ("titiler", "warm") => "TiTiler".into(),
        (s, m) => format!("{s} {m}"),
    }
}

fn aim(goal: String, measured: String, verdict: Verdict) -> Aim {
    Aim {
        anchor: ANCHOR,
        section: NAME,
        goal,
        measured,
        verdict,
    }
}

fn goal_ratio() -> String {
    format!(
        "Web Mercator 512 px Terrarium tiles at 64 connections: ≥ {}× TiTiler's tiles/s \
         (cold against its first pass, source-warm and warm against its steady state)",
        num(AIM_RATIO)
    )
}

fn goal_core() -> String {
    format!(
        "≥ {} tiles/s per core warm (made tiles cached; tiles/s ÷ the machine's cores, \
         wrk sharing them)",
        num(AIM_PER_CORE)
    )
}

fn runs<'a>(records: &'a [WebTile], ds: &str, server: &str, mode: &str) -> Vec<&'a WebTile> {
    records
        .iter()
        .filter(|r| r.dataset == ds && r.server == server && r.mode == mode)
        .collect()
}

fn per_run(records: &[WebTile], ds: &str, server: &str, mode: &str) -> Vec<(u32, f64)> {
    runs(records, ds, server, mode)
        .iter()
        .map(|r| (r.run, r.tiles_per_s()))
        .collect()
}

/// The made-tile cache's hit share during a Tessera measurement, "98.7%".
fn hit_share(rs: &[&WebTile]) -> String {
    let shares: Vec<f64> = rs
        .iter()
        .filter_map(|r| {
            let (h, m) = (r.tile_cache_hits?, r.tile_cache_misses?);
            (h + m > 0.0).then(|| h / (h + m))
        })
        .collect();
    match Spread::of(shares) {
        Some(s) => crate::stats::pct_spread(&s),
        None => "—".into(),
    }
}

pub fn section(
    records: Option<&[WebTile]>,
    checks: Option<&[WebTileCheck]>,
    cores: Option<u32>,
    ctx: &Ctx,
) -> Section {
    let Some(records) = records.filter(|r| !r.is_empty()) else {
        return Section::not_run(
            "webtiles.jsonl",
            vec![
                aim(goal_ratio(), "not run".into(), Verdict::NotMeasured),
                aim(goal_core(), "not run".into(), Verdict::NotMeasured),
            ],
        );
    };
    let datasets = distinct(records.iter().map(|r| r.dataset.clone()));
    let cores = cores.filter(|c| *c > 0);
    let mut md = String::new();
    let times: Vec<&str> = records
        .iter()
        .filter_map(|r| r.measured.as_deref())
        .collect();
    if let (Some(first), Some(last)) = (times.iter().min(), times.iter().max()) {
        let commits = distinct(records.iter().filter_map(|r| r.commit.as_deref()));
        let _ = writeln!(
            md,
            "Measured {first} to {last} on commit {}.\n",
            commits
                .iter()
                .map(|c| format!("`{c}`"))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    if let Some(load) = Spread::of(records.iter().filter_map(|r| r.loadavg_1m)) {
        let _ = writeln!(
            md,
            "The machine's 1-minute load average at the end of each row: {} (a load above \
             the core count means other work shared the machine during the rows).\n",
            load.fmt()
        );
    } else {
        md.push_str("The machine's load average was not recorded with these results.\n\n");
    }
    if let Some(r) = records.iter().find(|r| r.server == "titiler") {
        let _ = writeln!(
            md,
            "TiTiler {} with {} uvicorn workers; {} connections; the machine has {} cores.\n",
            r.titiler_version,
            r.titiler_workers,
            r.connections,
            cores.map_or_else(|| "an unknown number of".into(), |c| c.to_string())
        );
    }
    let mut ratio_parts = Vec::new();
    let mut ratio_verdicts = Vec::new();
    let mut core_parts = Vec::new();
    let mut core_verdicts = Vec::new();
    // Median tiles/s per (dataset, row), for the chart.
    let mut medians: Vec<(String, usize, f64)> = Vec::new();
    for ds in &datasets {
        let any = records.iter().find(|r| &r.dataset == ds);
        let _ = writeln!(
            md,
            "**`{ds}`**: {} tiles (mean {} kB as Tessera's PNG).\n",
            any.map_or(0, |r| r.tiles),
            any.map_or_else(|| "—".into(), |r| num(r.mean_tile_bytes / 1e3))
        );
        let mut table = Table::new(&[
            "server and mode",
            "client",
            "runs",
            "tiles/s",
            "tiles/s per core",
            "p50 ms",
            "p99 ms",
            "÷ TiTiler (tiles/s)",
            "peak RSS MiB",
            "made-tile cache hits",
            "errors",
        ]);
        let mut ratio_ds = Vec::new();
        for (i, (server, mode, peer)) in ROWS.iter().enumerate() {
            let rs = runs(records, ds, server, mode);
            let s = |f: fn(&WebTile) -> f64| Spread::of(rs.iter().map(|r| f(r)));
            let (Some(tps), Some(p50), Some(p99), Some(rss), Some(err)) = (
                s(WebTile::tiles_per_s),
                s(|r| r.p50_ms),
                s(|r| r.p99_ms),
                s(|r| r.rss_mib),
                s(|r| r.errors + r.non2xx),
            ) else {
                continue;
            };
            medians.push((ds.clone(), i, tps.median));
            let vs = peer.and_then(|p| {
                paired_ratio(
                    &per_run(records, ds, server, mode),
                    &per_run(records, ds, "titiler", p),
                )
            });
            if let Some((r, _)) = &vs {
                ratio_ds.push(format!("{mode} {}", ratio(*r)));
                ratio_verdicts.push(Verdict::from_bool(*r >= AIM_RATIO));
            } else if peer.is_some() {
                ratio_ds.push(format!("{mode} not measured"));
                ratio_verdicts.push(Verdict::NotMeasured);
            }
            let per_core = cores.map(|c| tps.scaled(1.0 / f64::from(c)));
            if *server == "tessera" && *mode == "warm" {
                if let Some(pc) = per_core {
                    core_parts.push(format!("`{ds}`: {} tiles/s per core", num(pc.median)));
                    core_verdicts.push(Verdict::from_bool(pc.median >= AIM_PER_CORE));
                } else {
                    core_parts.push(format!("`{ds}`: cores unknown"));
                    core_verdicts.push(Verdict::NotMeasured);
                }
            }
            table.row(vec![
                label(server, mode),
                rs.first().map_or_else(String::new, |r| r.client.clone()),
                rs.len().to_string(),
                tps.fmt(),
                per_core.map_or_else(|| "—".into(), |pc| pc.fmt()),
                p50.fmt(),
                p99.fmt(),
                vs.map_or_else(|| "—".into(), |(r, per)| fmt_paired(r, per.as_ref())),
                rss.fmt(),
                if *server == "tessera" {
                    hit_share(&rs)
                } else {
                    "—".into()
                },
                if err.max == 0.0 {
                    "none".into()
                } else {
                    err.fmt()
                },
            ]);
        }
        md.push_str(&table.render());
        md.push('\n');
        ratio_parts.push(format!("`{ds}`: {}", ratio_ds.join(", ")));
    }
    for c in checks.unwrap_or_default() {
        let m = |v: Option<f64>| v.map_or_else(|| "no data".into(), |h| format!("{h:.1} m"));
        let _ = writeln!(
            md,
            "Check: {} ({}°E, {}°N) is pixel ({}, {}) of `{}` tile {}: Tessera decodes to {}, \
             TiTiler to {} (TiTiler's tile is {} px).\n",
            c.landmark,
            c.lon,
            c.lat,
            c.pixel[0],
            c.pixel[1],
            c.dataset,
            c.tile,
            m(c.tessera_m),
            m(c.titiler_m),
            c.titiler_size.replace(", ", " × ")
        );
    }
    let aims = vec![
        aim(
            goal_ratio(),
            ratio_parts.join("; "),
            Verdict::all(ratio_verdicts),
        ),
        aim(
            goal_core(),
            core_parts.join("; "),
            Verdict::all(core_verdicts),
        ),
    ];
    for a in &aims {
        md.push_str(&a.bullet());
    }
    let mut s = Section {
        markdown: md,
        aims,
        charts: Vec::new(),
    };
    let chart = BarChart {
        title: "Web Mercator 512 px Terrarium tiles/s at 64 connections (median of runs)".into(),
        y_label: "tiles/s (log)".into(),
        categories: datasets.clone(),
        series: ROWS
            .iter()
            .enumerate()
            .map(|(i, (server, mode, _))| BarSeries {
                name: short(server, mode),
                values: datasets
                    .iter()
                    .map(|ds| {
                        medians
                            .iter()
                            .find(|(d, j, _)| d == ds && *j == i)
                            .map(|m| m.2)
                    })
                    .collect(),
            })
            .filter(|b| b.values.iter().any(Option::is_some))
            .collect(),
        references: cores
            .map(|c| Reference {
                value: AIM_PER_CORE * f64::from(c),
                label: format!("aim warm: {} per core", num(AIM_PER_CORE)),
            })
            .into_iter()
            .collect(),
        log_y: true,
    };
    ctx.chart(
        &mut s,
        "webtiles.png",
        "Web Mercator tiles/s of Tessera (cold, source-warm, warm) and TiTiler",
        chart.draw(WIDTH, HEIGHT),
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(ds: &str, server: &str, mode: &str, run: u32, tps: f64) -> WebTile {
        WebTile {
            dataset: ds.into(),
            server: server.into(),
            mode: mode.into(),
            run,
            client: "wrk".into(),
            tiles: 100,
            connections: 64,
            duration_s: 10.0,
            requests: tps * 10.0 + 5.0,
            errors: 0.0,
            non2xx: 5.0,
            p50_ms: 2.0,
            p99_ms: 9.0,
            mean_tile_bytes: 300_000.0,
            rss_mib: 100.0,
            tile_cache_hits: (server == "tessera").then_some(90.0),
            tile_cache_misses: (server == "tessera").then_some(10.0),
            titiler_workers: 2,
            titiler_version: "2.4.0".into(),
            measured: Some(format!("2026-12-01T18:0{run}:00Z")),
            commit: Some("abc1234+dirty".into()),
            loadavg_1m: Some(1.5),
        }
    }

    fn records(warm: f64, source_warm: f64, cold: f64) -> Vec<WebTile> {
        let mut r = Vec::new();
        for run in 1..=2 {
            r.push(rec("srtm", "tessera", "cold", run, cold));
            r.push(rec("srtm", "tessera", "source-warm", run, source_warm));
            r.push(rec("srtm", "tessera", "warm", run, warm));
            r.push(rec("srtm", "titiler", "cold", run, 10.0));
            r.push(rec("srtm", "titiler", "warm", run, 20.0));
        }
        r
    }

    fn ctx() -> Ctx {
        Ctx {
            plots: "plots".into(),
        }
    }

    #[test]
    fn fast_tessera_meets_both_aims() {
        let s = section(Some(&records(8000.0, 400.0, 150.0)), None, Some(2), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::Met, "{}", s.aims[0].measured);
        assert_eq!(s.aims[1].verdict, Verdict::Met, "{}", s.aims[1].measured);
        // Non-2xx responses are not tiles: 8000 tiles/s, 4000 per core, 400× TiTiler.
        assert!(
            s.markdown
                .contains("| 8000 (8000–8000) | 4000 (4000–4000) |"),
            "{}",
            s.markdown
        );
        assert!(s.markdown.contains("| 400×"), "{}", s.markdown);
        assert!(s.markdown.contains("90.0%"), "{}", s.markdown);
        assert!(
            s.aims[0].measured.contains("cold 15.0×"),
            "{}",
            s.aims[0].measured
        );
        assert_eq!(s.charts[0].file, "webtiles.png");
        assert!(
            s.markdown.contains(
                "Measured 2026-12-01T18:01:00Z to 2026-12-01T18:02:00Z on commit `abc1234+dirty`."
            ),
            "{}",
            s.markdown
        );
    }

    #[test]
    fn one_slow_mode_fails_the_ratio_and_slow_warm_fails_per_core() {
        let s = section(Some(&records(3000.0, 150.0, 150.0)), None, Some(2), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::NotMet, "source-warm is 7.5×");
        assert_eq!(s.aims[1].verdict, Verdict::NotMet, "1500 per core");
        let s = section(Some(&records(8000.0, 400.0, 150.0)), None, None, &ctx());
        assert_eq!(s.aims[1].verdict, Verdict::NotMeasured);
        let none = section(None, None, Some(2), &ctx());
        assert!(none.aims.iter().all(|a| a.verdict == Verdict::NotMeasured));
    }

    #[test]
    fn landmark_checks_are_written() {
        let c = WebTileCheck {
            dataset: "srtm".into(),
            landmark: "Andermatt".into(),
            lon: 8.5911,
            lat: 46.635,
            tile: "10/536/361".into(),
            pixel: [223, 350],
            tessera_m: Some(1436.2),
            titiler_m: Some(1436.0),
            titiler_size: "512, 512".into(),
            run: 1,
        };
        let s = section(
            Some(&records(8000.0, 400.0, 150.0)),
            Some(&[c]),
            Some(2),
            &ctx(),
        );
        assert!(
            s.markdown.contains(
                "Tessera decodes to 1436.2 m, TiTiler to 1436.0 m (TiTiler's tile is 512 × 512 px)"
            ),
            "{}",
            s.markdown
        );
    }
}
