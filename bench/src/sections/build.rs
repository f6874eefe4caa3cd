//! `{{build}}`: pyramid builds, Tessera against GDAL's translate + overviews on the
//! moon, and Tessera alone on synthetic terrains of growing size.
//!
//! Aims: faster (wall) than GDAL on the same input, and peak RSS flat within ±10%
//! from `synthetic:16385` to `synthetic:65537` (out-of-core building).

use super::{Aim, Ctx, Section, Table, Verdict, distinct};
use crate::chart::{BarChart, BarSeries, HEIGHT, Reference, WIDTH};
use crate::results::Build;
use crate::stats::{Spread, num, ratio};

pub const ANCHOR: &str = "build";
const NAME: &str = "Build";
const SMALL: &str = "synthetic:16385";
const LARGE: &str = "synthetic:65537";
/// How far peak RSS may move between the two synthetic sizes.
const FLAT: f64 = 0.10;

fn aim_faster(measured: String, verdict: Verdict) -> Aim {
    Aim {
        anchor: ANCHOR,
        section: NAME,
        goal: "build faster (wall) than GDAL's translate + overviews on the same input, \
              while also computing error tables"
            .into(),
        measured,
        verdict,
    }
}

fn aim_flat(measured: String, verdict: Verdict) -> Aim {
    Aim {
        anchor: ANCHOR,
        section: NAME,
        goal: format!("peak RSS flat (±10%) from `{SMALL}` to `{LARGE}`"),
        measured,
        verdict,
    }
}

/// The medians (and spreads) of one tool on one input.
struct Row<'a> {
    tool: &'a str,
    input: &'a str,
    wall: Spread,
    cpu: Spread,
    rss: Spread,
    rate: Spread,
    bytes_per_sample: Spread,
}

impl Row<'_> {
    fn of<'a>(tool: &'a str, input: &'a str, runs: &[&Build]) -> Option<Row<'a>> {
        let s = |f: fn(&Build) -> f64| Spread::of(runs.iter().map(|r| f(r)));
        Some(Row {
            tool,
            input,
            wall: s(|r| r.wall_s)?,
            cpu: s(|r| r.cpu_s)?,
            rss: s(|r| r.rss_mib)?,
            rate: s(|r| r.samples / r.wall_s / 1e6)?,
            bytes_per_sample: s(|r| r.bytes / r.samples)?,
        })
    }
}

fn tool_label(tool: &str) -> String {
    match tool {
        "tessera" => "Tessera `build`".into(),
        "gdal" => "GDAL `gdal_translate` + `gdaladdo`".into(),
        t => format!("`{t}`"),
    }
}

fn tool_short(tool: &str) -> String {
    match tool {
        "tessera" => "Tessera".into(),
        "gdal" => "GDAL".into(),
        t => t.into(),
    }
}

/// A short name for charts: "moon 8192", "synthetic 65537".
fn input_short(input: &str) -> String {
    if let Some(size) = input.strip_prefix("synthetic:") {
        return format!("synthetic {size}");
    }
    let stem = input.rsplit('/').next().unwrap_or(input);
    let stem = stem.split('.').next().unwrap_or(stem);
    if stem.contains("moon") {
        let size: String = stem
            .rsplit('_')
            .next()
            .unwrap_or("")
            .chars()
            .filter(char::is_ascii_digit)
            .collect();
        return format!("moon {size}").trim_end().to_string();
    }
    stem.to_string()
}

/// Files first (in order of appearance), then synthetic terrains by size.
fn input_order(inputs: &mut [&str]) {
    let size = |i: &str| -> (u8, u64) {
        match i.strip_prefix("synthetic:") {
            Some(s) => (
                1,
                s.split(':')
                    .next()
                    .and_then(|n| n.parse().ok())
                    .unwrap_or(u64::MAX),
            ),
            None => (0, 0),
        }
    };
    inputs.sort_by_key(|i| size(i));
}

pub fn section(records: Option<&[Build]>, ctx: &Ctx) -> Section {
    let Some(records) = records.filter(|r| !r.is_empty()) else {
        return Section::not_run(
            "build.jsonl",
            vec![
                aim_faster("not run".into(), Verdict::NotMeasured),
                aim_flat("not run".into(), Verdict::NotMeasured),
            ],
        );
    };
    let mut inputs = distinct(records.iter().map(|r| r.input.as_str()));
    input_order(&mut inputs);
    let mut tools = distinct(records.iter().map(|r| r.tool.as_str()));
    tools.sort_by_key(|t| *t != "tessera");
    let mut rows = Vec::new();
    for input in &inputs {
        for tool in &tools {
            let runs: Vec<&Build> = records
                .iter()
                .filter(|r| r.input == *input && r.tool == *tool)
                .collect();
            if let Some(row) = Row::of(tool, input, &runs) {
                rows.push(row);
            }
        }
    }
    let find = |tool: &str, input: &str| rows.iter().find(|r| r.tool == tool && r.input == input);

    let mut table = Table::new(&[
        "tool",
        "input",
        "runs",
        "wall s",
        "CPU s",
        "peak RSS MiB",
        "M samples/s",
        "bytes/sample",
    ]);
    for r in &rows {
        table.row(vec![
            tool_label(r.tool),
            format!("`{}`", r.input),
            r.wall.n.to_string(),
            r.wall.fmt(),
            r.cpu.fmt(),
            r.rss.fmt(),
            r.rate.fmt(),
            r.bytes_per_sample.fmt(),
        ]);
        if r.tool == "gdal"
            && let Some(t) = find("tessera", r.input)
        {
            let q = |a: &Spread, b: &Spread| ratio(a.median / b.median);
            table.row(vec![
                "ratio Tessera / GDAL (medians)".into(),
                format!("`{}`", r.input),
                String::new(),
                q(&t.wall, &r.wall),
                q(&t.cpu, &r.cpu),
                q(&t.rss, &r.rss),
                q(&t.rate, &r.rate),
                q(&t.bytes_per_sample, &r.bytes_per_sample),
            ]);
        }
    }

    // Aim 1: faster than GDAL wherever both ran.
    let pairs: Vec<(&Row, &Row)> = rows
        .iter()
        .filter(|r| r.tool == "gdal")
        .filter_map(|g| find("tessera", g.input).map(|t| (t, g)))
        .collect();
    let faster = if pairs.is_empty() {
        aim_faster(
            "GDAL and Tessera were not both run on one input".into(),
            Verdict::NotMeasured,
        )
    } else {
        let measured: Vec<String> = pairs
            .iter()
            .map(|(t, g)| {
                format!(
                    "`{}`: Tessera {} s, GDAL {} s, {}",
                    t.input,
                    num(t.wall.median),
                    num(g.wall.median),
                    ratio(t.wall.median / g.wall.median)
                )
            })
            .collect();
        aim_faster(
            measured.join("; "),
            Verdict::all(
                pairs
                    .iter()
                    .map(|(t, g)| Verdict::from_bool(t.wall.median < g.wall.median)),
            ),
        )
    };

    // Aim 2: flat memory.
    let flat = match (find("tessera", SMALL), find("tessera", LARGE)) {
        (Some(s), Some(l)) => {
            let change = l.rss.median / s.rss.median - 1.0;
            aim_flat(
                format!(
                    "{} MiB for `{SMALL}`, {} MiB for `{LARGE}`: {:+.0}%",
                    num(s.rss.median),
                    num(l.rss.median),
                    change * 100.0
                ),
                Verdict::from_bool(change.abs() <= FLAT),
            )
        }
        (s, l) => {
            let missing: Vec<&str> = [(s.is_none(), SMALL), (l.is_none(), LARGE)]
                .into_iter()
                .filter_map(|(m, i)| m.then_some(i))
                .collect();
            aim_flat(
                format!("Tessera not run on `{}`", missing.join("` or `")),
                Verdict::NotMeasured,
            )
        }
    };

    let mut s = Section {
        markdown: table.render(),
        aims: vec![faster, flat],
        charts: Vec::new(),
    };
    s.markdown.push('\n');
    for a in &s.aims {
        s.markdown.push_str(&a.bullet());
    }

    if let Some((t, g)) = pairs.first() {
        let chart = BarChart {
            title: format!(
                "Build of {}: Tessera relative to GDAL (GDAL = 1)",
                input_short(t.input)
            ),
            y_label: "ratio to GDAL, lower is better".into(),
            categories: ["wall", "CPU", "peak RSS", "bytes per sample"]
                .map(String::from)
                .to_vec(),
            series: vec![
                BarSeries {
                    name: "Tessera".into(),
                    values: vec![
                        Some(t.wall.median / g.wall.median),
                        Some(t.cpu.median / g.cpu.median),
                        Some(t.rss.median / g.rss.median),
                        Some(t.bytes_per_sample.median / g.bytes_per_sample.median),
                    ],
                },
                BarSeries {
                    name: "GDAL".into(),
                    values: vec![Some(1.0); 4],
                },
            ],
            references: Vec::new(),
            log_y: false,
        };
        ctx.chart(
            &mut s,
            "build.png",
            "Tessera's build relative to GDAL's",
            chart.draw(WIDTH, HEIGHT),
        );
    }
    let references = find("tessera", SMALL)
        .map(|r| {
            vec![
                Reference {
                    value: r.rss.median * (1.0 + FLAT),
                    label: "synthetic 16385 ±10%".into(),
                },
                Reference {
                    value: r.rss.median * (1.0 - FLAT),
                    label: String::new(),
                },
            ]
        })
        .unwrap_or_default();
    let chart = BarChart {
        title: "Peak RSS of the build (median)".into(),
        y_label: "MiB".into(),
        categories: inputs.iter().map(|i| input_short(i)).collect(),
        series: tools
            .iter()
            .map(|tool| BarSeries {
                name: tool_short(tool),
                values: inputs
                    .iter()
                    .map(|i| find(tool, i).map(|r| r.rss.median))
                    .collect(),
            })
            .collect(),
        references,
        log_y: false,
    };
    ctx.chart(
        &mut s,
        "build_rss.png",
        "Peak RSS of the build per input",
        chart.draw(WIDTH, HEIGHT),
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(tool: &str, input: &str, run: u32, wall_s: f64, rss_mib: f64) -> Build {
        Build {
            tool: tool.into(),
            input: input.into(),
            run,
            wall_s,
            cpu_s: wall_s * 1.5,
            rss_mib,
            bytes: 6e7,
            samples: 6.7e7,
        }
    }

    fn ctx() -> Ctx {
        Ctx {
            plots: "bench/plots".into(),
        }
    }

    const MOON: &str = "moon_crisium_gld100_8192.png";

    #[test]
    fn faster_than_gdal_and_flat_memory_are_met() {
        let r = vec![
            rec("tessera", MOON, 1, 2.2, 77.0),
            rec("tessera", MOON, 2, 2.1, 77.0),
            rec("gdal", MOON, 1, 3.6, 303.0),
            rec("gdal", MOON, 2, 3.7, 303.0),
            rec("tessera", SMALL, 1, 4.8, 80.0),
            rec("tessera", LARGE, 1, 95.0, 85.0),
        ];
        let s = section(Some(&r), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::Met, "{}", s.aims[0].measured);
        assert!(
            s.aims[0].measured.contains("Tessera 2.15 s, GDAL 3.65 s"),
            "{}",
            s.aims[0].measured
        );
        assert_eq!(s.aims[1].verdict, Verdict::Met, "{}", s.aims[1].measured);
        assert!(s.aims[1].measured.contains("+6%"), "{}", s.aims[1].measured);
        assert!(
            s.markdown.contains("| 2.15 (2.10–2.20) |"),
            "{}",
            s.markdown
        );
        assert!(s.markdown.contains("ratio Tessera / GDAL"));
        assert!(s.markdown.contains("](bench/plots/build.png)"));
        let files: Vec<&str> = s.charts.iter().map(|c| c.file.as_str()).collect();
        assert_eq!(files, ["build.png", "build_rss.png"]);
        // Rows: the moon first, then synthetic terrains by size.
        let moon = s.markdown.find(MOON).expect("moon row");
        let small = s.markdown.find(SMALL).expect("small row");
        let large = s.markdown.rfind(LARGE).expect("large row");
        assert!(moon < small && small < large);
    }

    #[test]
    fn slower_than_gdal_and_growing_memory_are_not_met() {
        let r = vec![
            rec("tessera", MOON, 1, 4.0, 77.0),
            rec("gdal", MOON, 1, 3.6, 303.0),
            rec("tessera", LARGE, 1, 95.0, 91.0),
            rec("tessera", SMALL, 1, 4.8, 72.0),
        ];
        let s = section(Some(&r), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::NotMet);
        assert_eq!(s.aims[1].verdict, Verdict::NotMet);
        assert!(
            s.aims[1].measured.contains("+26%"),
            "{}",
            s.aims[1].measured
        );
    }

    #[test]
    fn missing_peers_or_sizes_are_not_measured() {
        let r = vec![rec("tessera", SMALL, 1, 4.8, 72.0)];
        let s = section(Some(&r), &ctx());
        assert_eq!(s.aims[0].verdict, Verdict::NotMeasured);
        assert_eq!(s.aims[1].verdict, Verdict::NotMeasured);
        assert!(s.aims[1].measured.contains(LARGE));
        let s = section(None, &ctx());
        assert!(s.markdown.contains("Not run"));
        assert_eq!(s.aims.len(), 2);
        assert!(s.charts.is_empty());
    }

    #[test]
    fn short_input_names() {
        assert_eq!(input_short(MOON), "moon 8192");
        assert_eq!(input_short("synthetic:65537"), "synthetic 65537");
        assert_eq!(input_short("dem/srtm.hgt"), "srtm");
    }
}
