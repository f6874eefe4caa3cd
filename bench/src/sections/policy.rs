//! `{{policy}}`: the screen-space error policy against the distance-only baseline
//! (Kang's brute-force comparison), at equal image quality.
//!
//! Quality is PSNR against the full-resolution reference on the measured frames
//! (those with a `psnr`, drawing what the policy asks for). For each path the
//! screen-error policy's PSNR at τ = 1 is the target; the distance setting that
//! "matches" is the one with the fewest triangles whose median PSNR is at least
//! that. Aims: screen-error needs ≤ 0.5× the triangles of that distance setting,
//! and never more than 7 draw calls a frame.

use super::{Aim, Ctx, Section, Table, Verdict, distinct, tau};
use crate::chart::{HEIGHT, Point, WIDTH, XyChart, XySeries};
use crate::results::{Frame, PolicyFlight};
use crate::stats::{Spread, median, num, ratio};

pub const ANCHOR: &str = "selection-policy";
const NAME: &str = "Selection policy";
const SCREEN: &str = "screen-error";
const DISTANCE: &str = "distance";
/// The aim's triangle ratio at equal PSNR.
const TRIANGLE_AIM: f64 = 0.5;
const DRAW_CALL_AIM: u32 = 7;

fn aim_triangles(measured: String, verdict: Verdict) -> Aim {
    Aim {
        anchor: ANCHOR,
        section: NAME,
        goal: "triangles at equal PSNR ≤ 0.5× the distance policy's (screen-error τ = 1)".into(),
        measured,
        verdict,
    }
}

fn aim_draw_calls(measured: String, verdict: Verdict) -> Aim {
    Aim {
        anchor: ANCHOR,
        section: NAME,
        goal: "draw calls ≤ 7 per frame".into(),
        measured,
        verdict,
    }
}

/// One (dataset, path, policy, τ) over its runs.
#[derive(Debug)]
struct Row<'a> {
    dataset: &'a str,
    path: &'a str,
    policy: &'a str,
    tau: f64,
    runs: usize,
    /// Per-run medians over drawn frames.
    triangles: Option<Spread>,
    draw_calls_median: Option<f64>,
    draw_calls_max: Option<u32>,
    measured: usize,
    /// Over the measured frames of every run.
    psnr: Option<Spread>,
    mse: Option<f64>,
}

impl<'a> Row<'a> {
    fn of(runs: &[&'a PolicyFlight]) -> Row<'a> {
        let first = runs[0];
        let drawn: Vec<&Frame> = runs
            .iter()
            .flat_map(|r| r.frames.iter())
            .filter(|f| f.drawn())
            .collect();
        let measured: Vec<&Frame> = runs
            .iter()
            .flat_map(|r| r.frames.iter())
            .filter(|f| f.measured())
            .collect();
        let calls: Vec<f64> = drawn.iter().map(|f| f64::from(f.draw_calls)).collect();
        Row {
            dataset: &first.dataset,
            path: &first.path,
            policy: &first.policy,
            tau: first.tau,
            runs: runs.len(),
            triangles: Spread::of(runs.iter().filter_map(|r| {
                let t: Vec<f64> = r
                    .frames
                    .iter()
                    .filter(|f| f.drawn())
                    .map(|f| f.triangles as f64)
                    .collect();
                median(&t)
            })),
            draw_calls_median: median(&calls),
            draw_calls_max: drawn.iter().map(|f| f.draw_calls).max(),
            measured: measured.len(),
            psnr: Spread::of(measured.iter().filter_map(|f| f.psnr)),
            mse: median(&measured.iter().filter_map(|f| f.mse).collect::<Vec<_>>()),
        }
    }

    fn tris(&self) -> Option<f64> {
        self.triangles.map(|t| t.median)
    }

    fn psnr(&self) -> Option<f64> {
        self.psnr.map(|p| p.median)
    }
}

/// The distance row with the fewest triangles whose PSNR is at least `target`.
fn matching<'r, 'a>(distance: &[&'r Row<'a>], target: f64) -> Option<&'r Row<'a>> {
    distance
        .iter()
        .filter(|d| d.psnr().is_some_and(|p| p >= target) && d.tris().is_some())
        .min_by(|a, b| a.tris().unwrap_or(0.0).total_cmp(&b.tris().unwrap_or(0.0)))
        .copied()
}

fn opt(v: Option<f64>, f: impl Fn(f64) -> String) -> String {
    v.map_or_else(|| "—".into(), f)
}

pub fn section(records: Option<&[PolicyFlight]>, ctx: &Ctx) -> Section {
    let Some(records) = records.filter(|r| !r.is_empty()) else {
        return Section::not_run(
            "policy.jsonl",
            vec![
                aim_triangles("not run".into(), Verdict::NotMeasured),
                aim_draw_calls("not run".into(), Verdict::NotMeasured),
            ],
        );
    };
    let flights = distinct(
        records
            .iter()
            .map(|r| (r.dataset.as_str(), r.path.as_str())),
    );
    let mut policies = distinct(records.iter().map(|r| r.policy.as_str()));
    policies.sort_by_key(|p| (*p != SCREEN, *p != DISTANCE));
    let mut rows: Vec<Row> = Vec::new();
    for &(dataset, path) in &flights {
        for &policy in &policies {
            let mut taus = distinct(
                records
                    .iter()
                    .filter(|r| r.dataset == dataset && r.path == path && r.policy == policy)
                    .map(|r| r.tau),
            );
            taus.sort_by(f64::total_cmp);
            for t in taus {
                let runs: Vec<&PolicyFlight> = records
                    .iter()
                    .filter(|r| {
                        r.dataset == dataset && r.path == path && r.policy == policy && r.tau == t
                    })
                    .collect();
                rows.push(Row::of(&runs));
            }
        }
    }
    let many_datasets = distinct(flights.iter().map(|f| f.0)).len() > 1;
    let flight_name = |dataset: &str, path: &str| {
        if many_datasets {
            format!("{dataset} `{path}`")
        } else {
            format!("`{path}`")
        }
    };

    let mut table = Table::new(&[
        "path",
        "policy",
        "τ",
        "runs",
        "median triangles (min–max of runs)",
        "draw calls median / max",
        "measured frames",
        "PSNR dB, median (min–max of frames)",
        "median MSE",
    ]);
    for r in &rows {
        table.row(vec![
            flight_name(r.dataset, r.path),
            r.policy.to_string(),
            tau(r.tau),
            r.runs.to_string(),
            r.triangles.map_or_else(|| "—".into(), |t| t.fmt()),
            match (r.draw_calls_median, r.draw_calls_max) {
                (Some(m), Some(x)) => format!("{} / {x}", num(m)),
                _ => "—".into(),
            },
            r.measured.to_string(),
            r.psnr.map_or_else(|| "—".into(), |p| p.fmt()),
            opt(r.mse, num),
        ]);
    }

    // Equal PSNR, per flight and screen-error τ.
    let mut equal = Table::new(&[
        "path",
        "screen-error τ",
        "its PSNR dB",
        "its triangles",
        "matching distance τ",
        "distance PSNR dB",
        "distance triangles",
        "triangles screen ÷ distance",
    ]);
    let mut notes = Vec::new();
    let mut verdicts = Vec::new();
    let mut measured = Vec::new();
    for &(dataset, path) in &flights {
        let of = |p: &str| -> Vec<&Row> {
            rows.iter()
                .filter(|r| r.dataset == dataset && r.path == path && r.policy == p)
                .collect()
        };
        let (screen, distance) = (of(SCREEN), of(DISTANCE));
        let name = flight_name(dataset, path);
        let mut at_one = None;
        for s in &screen {
            let (Some(target), Some(tris)) = (s.psnr(), s.tris()) else {
                continue;
            };
            let found = matching(&distance, target);
            let r = found.and_then(Row::tris).map(|d| tris / d);
            equal.row(vec![
                name.clone(),
                tau(s.tau),
                num(target),
                num(tris),
                found.map_or_else(|| "none reaches it".into(), |d| tau(d.tau)),
                opt(found.and_then(Row::psnr), num),
                opt(found.and_then(Row::tris), num),
                opt(r, ratio),
            ]);
            if s.tau == 1.0 {
                at_one = Some((target, tris, found, r));
            }
        }
        match at_one {
            Some((target, tris, Some(d), Some(r))) => {
                verdicts.push(Verdict::from_bool(r <= TRIANGLE_AIM));
                measured.push(format!(
                    "{name}: {} ({} triangles against {} at distance τ = {}, {} dB)",
                    ratio(r),
                    num(tris),
                    opt(d.tris(), num),
                    tau(d.tau),
                    num(target)
                ));
            }
            Some((target, tris, _, _)) => {
                verdicts.push(Verdict::NotMeasured);
                let finest = distance
                    .iter()
                    .filter(|d| d.tris().is_some())
                    .max_by(|a, b| a.tris().unwrap_or(0.0).total_cmp(&b.tris().unwrap_or(0.0)));
                let bound = finest.map_or(String::new(), |f| {
                    format!(
                        "; the finest, τ = {}, gives {} dB with {} triangles ({} at most)",
                        tau(f.tau),
                        opt(f.psnr(), num),
                        opt(f.tris(), num),
                        opt(f.tris().map(|d| tris / d), ratio)
                    )
                });
                let msg = format!(
                    "{name}: no distance τ reaches screen-error τ = 1's {} dB{bound}",
                    num(target)
                );
                notes.push(format!("- {msg}.\n"));
                measured.push(msg);
            }
            None => {
                verdicts.push(Verdict::NotMeasured);
                measured.push(format!("{name}: screen-error τ = 1 not measured"));
            }
        }
    }
    let triangles = aim_triangles(measured.join("; "), Verdict::all(verdicts));

    // Draw calls of the screen-error policy over every drawn frame.
    let screen_calls: Vec<u32> = records
        .iter()
        .filter(|r| r.policy == SCREEN)
        .flat_map(|r| r.frames.iter())
        .filter(|f| f.drawn())
        .map(|f| f.draw_calls)
        .collect();
    let calls_median = median(
        &screen_calls
            .iter()
            .map(|&c| f64::from(c))
            .collect::<Vec<_>>(),
    );
    let draw_calls = match (screen_calls.iter().max(), calls_median) {
        (Some(&max), Some(med)) => {
            notes.push(format!(
                "- Draw calls per frame with screen-error: median {} (max {max}) over {} drawn frames, \
                 against the seeds' 69 for SCSLOD (Kang; {} ours) and 146–421 for CLOD.\n",
                num(med),
                screen_calls.len(),
                ratio(69.0 / med.max(1.0))
            ));
            aim_draw_calls(
                format!(
                    "max {max} over {} screen-error frames (median {})",
                    screen_calls.len(),
                    num(med)
                ),
                Verdict::from_bool(max <= DRAW_CALL_AIM),
            )
        }
        _ => aim_draw_calls("no drawn screen-error frames".into(), Verdict::NotMeasured),
    };

    let mut s = Section {
        markdown: format!(
            "{}\nAt equal quality (the distance τ with the fewest triangles whose median PSNR \
             is at least the screen-error policy's):\n\n{}\n",
            table.render(),
            equal.render()
        ),
        aims: vec![triangles, draw_calls],
        charts: Vec::new(),
    };
    for n in &notes {
        s.markdown.push_str(n);
    }
    for a in &s.aims {
        s.markdown.push_str(&a.bullet());
    }

    let mut series = Vec::new();
    for &(dataset, path) in &flights {
        for &policy in &policies {
            let points: Vec<Point> = rows
                .iter()
                .filter(|r| r.dataset == dataset && r.path == path && r.policy == policy)
                .filter_map(|r| {
                    Some(Point {
                        x: r.tris()?,
                        y: r.psnr()?,
                        label: Some(format!("τ={}", tau(r.tau))),
                    })
                })
                .collect();
            if !points.is_empty() {
                let name = if many_datasets {
                    format!("{dataset} {path} {policy}")
                } else {
                    format!("{path} {policy}")
                };
                series.push(XySeries { name, points });
            }
        }
    }
    let chart = XyChart {
        title: "Image quality against triangles (medians)".into(),
        x_label: "triangles per frame (log scale)".into(),
        y_label: "PSNR dB".into(),
        series,
        log_x: true,
    };
    ctx.chart(
        &mut s,
        "policy.png",
        "PSNR against triangles per frame for the screen-error and distance policies",
        chart.draw(WIDTH, HEIGHT),
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(triangles: u64, draw_calls: u32, psnr: Option<f64>) -> Frame {
        Frame {
            triangles,
            draw_calls,
            render_ms: 10.0,
            converged: Some(true),
            mse: psnr.map(|p| 255.0 * 255.0 / 10f64.powf(p / 10.0)),
            psnr,
        }
    }

    /// A flight of three frames, the last two measured.
    fn rec(path: &str, policy: &str, tau: f64, run: u32, tris: u64, psnr: f64) -> PolicyFlight {
        PolicyFlight {
            dataset: "moon8192".into(),
            path: path.into(),
            policy: policy.into(),
            tau,
            run,
            frames: vec![
                frame(tris, 5, None),
                frame(tris, 6, Some(psnr)),
                frame(tris, 5, Some(psnr + 0.2)),
            ],
        }
    }

    fn ctx() -> Ctx {
        Ctx {
            plots: "bench/plots".into(),
        }
    }

    fn sweep(screen_tris: u64) -> Vec<PolicyFlight> {
        let mut r = Vec::new();
        for run in 1..=2 {
            r.push(rec("pass", SCREEN, 1.0, run, screen_tris, 44.4));
            r.push(rec("pass", DISTANCE, 2.0, run, 3_000_000, 49.0));
            r.push(rec("pass", DISTANCE, 4.0, run, 1_300_000, 45.5));
            r.push(rec("pass", DISTANCE, 8.0, run, 540_000, 41.9));
        }
        r
    }

    #[test]
    fn fewer_triangles_at_equal_psnr_meets_the_aim() {
        let s = section(Some(&sweep(300_000)), &ctx());
        let a = &s.aims[0];
        assert_eq!(a.verdict, Verdict::Met, "{}", a.measured);
        // τ = 4 is the cheapest distance setting at ≥ 44.5 dB: 300k / 1.3M.
        assert!(
            a.measured.contains("0.23×") && a.measured.contains("τ = 4"),
            "{}",
            a.measured
        );
        assert_eq!(s.aims[1].verdict, Verdict::Met);
        assert!(
            s.markdown.contains("| 44.5 (44.4–44.6) |"),
            "{}",
            s.markdown
        );
        assert!(s.markdown.contains("against the seeds' 69"));
        assert_eq!(s.charts[0].file, "policy.png");
    }

    #[test]
    fn too_many_triangles_or_draw_calls_do_not_meet_the_aims() {
        let mut r = sweep(900_000);
        r[0].frames[0].draw_calls = 9;
        let s = section(Some(&r), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::NotMet, "{}", s.aims[0].measured);
        assert!(
            s.aims[0].measured.contains("0.69×"),
            "{}",
            s.aims[0].measured
        );
        assert_eq!(s.aims[1].verdict, Verdict::NotMet);
        assert!(s.aims[1].measured.contains("max 9"));
    }

    #[test]
    fn no_matching_distance_setting_is_said_and_not_measured() {
        let r: Vec<PolicyFlight> = sweep(300_000)
            .into_iter()
            .filter(|p| p.tau != 2.0 && p.tau != 4.0)
            .collect();
        let s = section(Some(&r), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::NotMeasured);
        assert!(
            s.aims[0].measured.contains("no distance τ reaches"),
            "{}",
            s.aims[0].measured
        );
        assert!(s.markdown.contains("none reaches it"));
    }

    #[test]
    fn unconverged_and_unmeasured_frames_are_not_quality_samples() {
        let mut r = sweep(300_000);
        for p in r.iter_mut().filter(|p| p.policy == SCREEN) {
            p.frames[1].converged = Some(false);
        }
        let row = Row::of(&r.iter().filter(|p| p.policy == SCREEN).collect::<Vec<_>>());
        assert_eq!(row.measured, 2);
        assert_eq!(row.psnr.map(|p| p.median), Some(44.6));
    }
}
