//! `{{terrain}}`: Cesium terrain (DECISIONS.md "Cesium terrain") — quantized-mesh tiles
//! meshed from the pyramid's error tables (`bench/terrain.sh`): per-tile meshing time and
//! quality against CesiumJS's geometric error and a regular 65 × 65 heightmap at equal
//! error (`terrain_mesh.jsonl`), and tiles/s served cold and warm at 64 connections
//! (`terrain_serve.jsonl`).
//!
//! Aims: ≤ 0.5 ms to mesh a tile (median, sources decoded, every dataset × zoom
//! measured); ≤ 0.5× the regular 65² grid's 8192 triangles at its error (median per
//! dataset × zoom), our mesh's true error then no larger than the grid's (max ≤ 1).

use super::{Aim, Section, Table, Verdict, distinct};
use crate::results::{TerrainMesh, TerrainServe};
use crate::stats::{Spread, median, num, pct_spread, ratio};
use std::fmt::Write as _;

pub const ANCHOR: &str = "cesium-terrain";
const NAME: &str = "Cesium terrain";
const AIM_MESH_US: f64 = 500.0;
const AIM_TRIANGLES: f64 = 0.5;
/// Martini's published figures for one 513² tile (mesh at 30 m error), ms.
const MARTINI_SAMPLES: f64 = 513.0 * 513.0;
const MARTINI_JS_MS: f64 = 6.0;
const MARTINI_CYTHON_MS: f64 = 1.0;

fn aim(goal: &str, measured: String, verdict: Verdict) -> Aim {
    Aim {
        anchor: ANCHOR,
        section: NAME,
        goal: goal.into(),
        measured,
        verdict,
    }
}

const GOAL_MESH: &str = "≤ 0.5 ms to mesh one Cesium terrain tile (median, sources decoded)";
const GOAL_TRIANGLES: &str = "≤ 0.5× the triangles of a regular 65 × 65 heightmap at its \
     error (median), with a true error no larger than the heightmap's";

/// The `p`-quantile (0–1) by nearest rank.
fn quantile(values: &[f64], p: f64) -> Option<f64> {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    (n > 0).then(|| v[((p * n as f64).ceil() as usize).clamp(1, n) - 1])
}

fn fold_max(values: impl IntoIterator<Item = f64>) -> Option<f64> {
    values.into_iter().reduce(f64::max)
}

/// A duration in µs as the aims write it: "780 µs", "7.9 ms".
fn duration(us: f64) -> String {
    if us < 1000.0 {
        format!("{} µs", num(us))
    } else {
        format!("{} ms", num(us / 1000.0))
    }
}

/// "44521 (≈ 211²)".
fn samples(n: f64) -> String {
    format!("{} (≈ {}²)", num(n), num(n.sqrt().round()))
}

/// The measured period and commits of a set of records.
fn provenance(md: &mut String, what: &str, times: &[&str], commits: &[&str]) {
    if let (Some(first), Some(last)) = (times.iter().min(), times.iter().max()) {
        let _ = writeln!(
            md,
            "{what} measured {first} to {last} on commit {}.\n",
            distinct(commits.iter().copied())
                .iter()
                .map(|c| format!("`{c}`"))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
}

/// One dataset × zoom of the mesh records.
struct Case<'a> {
    dataset: &'a str,
    zoom: u8,
    tiles: Vec<&'a TerrainMesh>,
}

impl Case<'_> {
    fn values(&self, f: fn(&TerrainMesh) -> f64) -> Vec<f64> {
        self.tiles.iter().map(|t| f(t)).collect()
    }
    fn median(&self, f: fn(&TerrainMesh) -> f64) -> f64 {
        median(&self.values(f)).unwrap_or(f64::NAN)
    }
    fn label(&self) -> String {
        format!("`{}` zoom {}", self.dataset, self.zoom)
    }
}

fn mesh_part(records: Option<&[TerrainMesh]>, md: &mut String) -> Vec<Aim> {
    let Some(records) = records.filter(|r| !r.is_empty()) else {
        md.push_str("*Meshing not run: the results have no `terrain_mesh.jsonl`.*\n\n");
        return vec![
            aim(GOAL_MESH, "not run".into(), Verdict::NotMeasured),
            aim(GOAL_TRIANGLES, "not run".into(), Verdict::NotMeasured),
        ];
    };
    provenance(
        md,
        "Meshing",
        &records
            .iter()
            .filter_map(|r| r.measured.as_deref())
            .collect::<Vec<_>>(),
        &records
            .iter()
            .filter_map(|r| r.commit.as_deref())
            .collect::<Vec<_>>(),
    );
    if let Some(load) = Spread::of(records.iter().filter_map(|r| r.loadavg_1m)) {
        let _ = writeln!(
            md,
            "The machine's 1-minute load average after each zoom: {} (one core meshes; \
             others may share the machine).\n",
            load.fmt()
        );
    }
    let cases: Vec<Case> = distinct(records.iter().map(|r| (r.dataset.as_str(), r.zoom)))
        .into_iter()
        .map(|(dataset, zoom)| Case {
            dataset,
            zoom,
            tiles: records
                .iter()
                .filter(|r| r.dataset == dataset && r.zoom == zoom)
                .collect(),
        })
        .collect();
    let mut table = Table::new(&[
        "dataset",
        "zoom",
        "tiles",
        "samples per tile (median)",
        "CesiumJS ε m",
        "mesh µs median",
        "mesh µs p90",
        "cold µs median",
        "encode µs median",
        "triangles median",
        "worst error ÷ ε (max)",
        "triangles ÷ regular 65² at its error (median)",
        "error ÷ regular's (max)",
    ]);
    let (mut mesh_parts, mut mesh_verdicts) = (Vec::new(), Vec::new());
    let (mut tri_parts, mut tri_verdicts) = (Vec::new(), Vec::new());
    let mut worst_eps: Option<f64> = None;
    let mut martini = Vec::new();
    let mut regular_eps = Vec::new();
    for c in &cases {
        let mesh = c.values(|t| t.mesh_us);
        let mesh_median = c.median(|t| t.mesh_us);
        let eps_ratio = fold_max(c.values(|t| t.error_m / t.geometric_error_m));
        let tri_ratio = c.median(|t| t.at_regular_triangles / t.regular_triangles);
        let err_ratio = fold_max(c.values(|t| t.at_regular_error_m / t.regular_error_m));
        let n = c.median(|t| t.samples);
        worst_eps = fold_max(worst_eps.into_iter().chain(eps_ratio));
        table.row(vec![
            format!("`{}`", c.dataset),
            c.zoom.to_string(),
            c.tiles.len().to_string(),
            samples(n),
            num(c.median(|t| t.geometric_error_m)),
            num(mesh_median),
            quantile(&mesh, 0.9).map_or_else(|| "—".into(), num),
            num(c.median(|t| t.cold_us)),
            num(c.median(|t| t.encode_us)),
            num(c.median(|t| t.triangles)),
            eps_ratio.map_or_else(|| "—".into(), |r| format!("{r:.3}")),
            ratio(tri_ratio),
            err_ratio.map_or_else(|| "—".into(), |r| format!("{r:.3}")),
        ]);
        mesh_parts.push(format!(
            "{} (≈ {}² samples): {}",
            c.label(),
            num(n.sqrt().round()),
            duration(mesh_median)
        ));
        mesh_verdicts.push(Verdict::from_bool(mesh_median <= AIM_MESH_US));
        let err_ok = err_ratio.is_some_and(|r| r <= 1.0);
        tri_parts.push(format!(
            "{}: {} (true error ≤ {} the grid's)",
            c.label(),
            ratio(tri_ratio),
            err_ratio.map_or_else(|| "—".into(), |r| format!("{r:.3}×"))
        ));
        tri_verdicts.push(Verdict::from_bool(tri_ratio <= AIM_TRIANGLES && err_ok));
        if let Some(r) = Spread::of(c.values(|t| t.regular_error_m / t.geometric_error_m)) {
            regular_eps.push(format!("{} {}", c.label(), r.fmt_unit("×")));
        }
        // µs per 1000 samples, to set beside Martini's 513² tile.
        martini.push(format!(
            "{} {} µs",
            c.label(),
            num(mesh_median / n * 1000.0)
        ));
    }
    md.push_str(&table.render());
    md.push('\n');
    if let Some(w) = worst_eps {
        let _ = writeln!(
            md,
            "- Every tile within CesiumJS's ε of every finest sample: {} (worst {w:.3} ε).",
            if w <= 1.0 { "yes" } else { "**no**" }
        );
    }
    let _ = writeln!(
        md,
        "- The regular 65² grid's own worst error ÷ ε, median (min–max) over the tiles: {} \
         (above 1, the grid is coarser than CesiumJS asks, and our mesh at ε can have more \
         than its 8192 triangles).",
        regular_eps.join(", ")
    );
    let _ = writeln!(
        md,
        "- Meshing time per 1000 finest samples (median): {}; Martini's 513² tile: {} µs \
         (JavaScript, {} ms) and {} µs (Cython, {} ms), at 30 m error.",
        martini.join(", "),
        num(MARTINI_JS_MS * 1000.0 / MARTINI_SAMPLES * 1000.0),
        num(MARTINI_JS_MS),
        num(MARTINI_CYTHON_MS * 1000.0 / MARTINI_SAMPLES * 1000.0),
        num(MARTINI_CYTHON_MS)
    );
    vec![
        aim(
            GOAL_MESH,
            mesh_parts.join("; "),
            Verdict::all(mesh_verdicts),
        ),
        aim(
            GOAL_TRIANGLES,
            tri_parts.join("; "),
            Verdict::all(tri_verdicts),
        ),
    ]
}

fn serve_part(records: Option<&[TerrainServe]>, md: &mut String) {
    let Some(records) = records.filter(|r| !r.is_empty()) else {
        md.push_str("*Serving not run: the results have no `terrain_serve.jsonl`.*\n");
        return;
    };
    provenance(
        md,
        "Serving",
        &records
            .iter()
            .filter_map(|r| r.measured.as_deref())
            .collect::<Vec<_>>(),
        &records
            .iter()
            .filter_map(|r| r.commit.as_deref())
            .collect::<Vec<_>>(),
    );
    if let Some(load) = Spread::of(records.iter().filter_map(|r| r.loadavg_1m)) {
        let _ = writeln!(
            md,
            "The machine's 1-minute load average at the end of each row: {}.\n",
            load.fmt()
        );
    }
    if let Some(r) = records.first() {
        let _ = writeln!(
            md,
            "{} connections; the server on CPUs {} of the machine's {} cores, which the load \
             generator shares. Requests carry `Accept: {}` and `Accept-Encoding: gzip`.\n",
            r.connections,
            r.server_cpus.as_deref().unwrap_or("(not recorded)"),
            r.cores
                .map_or_else(|| "(not recorded)".into(), |c| c.to_string()),
            r.accept.as_deref().unwrap_or("(not recorded)")
        );
    }
    let mut table = Table::new(&[
        "dataset",
        "zoom",
        "tiles",
        "mean tile kB sent (raw)",
        "mode",
        "client",
        "runs",
        "tiles/s",
        "p50 ms",
        "p99 ms",
        "terrain-cache hits",
        "peak RSS MiB",
        "errors",
    ]);
    for (ds, zoom) in distinct(records.iter().map(|r| (r.dataset.as_str(), r.zoom))) {
        for mode in ["cold", "warm"] {
            let rs: Vec<&TerrainServe> = records
                .iter()
                .filter(|r| r.dataset == ds && r.zoom == zoom && r.mode == mode)
                .collect();
            let s = |f: fn(&TerrainServe) -> f64| Spread::of(rs.iter().map(|r| f(r)));
            let (Some(tps), Some(p50), Some(p99), Some(rss), Some(err)) = (
                s(TerrainServe::tiles_per_s),
                s(|r| r.p50_ms),
                s(|r| r.p99_ms),
                s(|r| r.rss_mib),
                s(|r| r.errors + r.non2xx),
            ) else {
                continue;
            };
            let first = rs[0];
            let hits = Spread::of(rs.iter().filter_map(|r| {
                let (h, m) = (r.tile_cache_hits?, r.tile_cache_misses?);
                (h + m > 0.0).then(|| h / (h + m))
            }));
            let sent = format!(
                "{}{}{}",
                num(first.mean_tile_bytes / 1e3),
                first
                    .content_encoding
                    .as_deref()
                    .filter(|e| *e != "identity")
                    .map_or_else(String::new, |e| format!(" {e}")),
                first
                    .mean_raw_bytes
                    .map_or_else(String::new, |b| format!(" ({})", num(b / 1e3)))
            );
            table.row(vec![
                format!("`{ds}`"),
                zoom.to_string(),
                first.tiles.to_string(),
                sent,
                mode.into(),
                first.client.clone(),
                rs.len().to_string(),
                tps.fmt(),
                p50.fmt(),
                p99.fmt(),
                hits.map_or_else(|| "—".into(), |h| pct_spread(&h)),
                rss.fmt(),
                if err.max == 0.0 {
                    "none".into()
                } else {
                    err.fmt()
                },
            ]);
        }
    }
    md.push_str(&table.render());
}

pub fn section(mesh: Option<&[TerrainMesh]>, serve: Option<&[TerrainServe]>) -> Section {
    let no = |r: Option<usize>| r.is_none_or(|n| n == 0);
    if no(mesh.map(<[_]>::len)) && no(serve.map(<[_]>::len)) {
        return Section::not_run(
            "terrain_mesh.jsonl",
            vec![
                aim(GOAL_MESH, "not run".into(), Verdict::NotMeasured),
                aim(GOAL_TRIANGLES, "not run".into(), Verdict::NotMeasured),
            ],
        );
    }
    let mut md = String::new();
    let aims = mesh_part(mesh, &mut md);
    for a in &aims {
        md.push_str(&a.bullet());
    }
    md.push('\n');
    serve_part(serve, &mut md);
    Section {
        markdown: md,
        aims,
        charts: Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tile(ds: &str, zoom: u8, i: u32, mesh_us: f64, at_regular: f64) -> TerrainMesh {
        TerrainMesh {
            dataset: ds.into(),
            zoom,
            tile: format!("{zoom}/{i}/7"),
            run: 1,
            samples: 44521.0,
            cold_us: mesh_us * 2.0,
            mesh_us,
            encode_us: 100.0,
            triangles: 3000.0,
            error_m: 70.0,
            geometric_error_m: 75.0,
            regular_triangles: 8192.0,
            regular_error_m: 500.0,
            at_regular_triangles: at_regular,
            at_regular_error_m: 480.0,
            measured: Some(format!("2026-12-01T18:0{i}:00Z")),
            commit: Some("abc1234".into()),
            loadavg_1m: Some(1.0),
        }
    }

    fn serve(mode: &str, run: u32, tps: f64) -> TerrainServe {
        TerrainServe {
            dataset: "N46E008".into(),
            zoom: 12,
            mode: mode.into(),
            run,
            client: if mode == "cold" { "curl -Z" } else { "wrk" }.into(),
            tiles: 552,
            connections: 64,
            duration_s: 2.0,
            requests: tps * 2.0,
            errors: 0.0,
            non2xx: 0.0,
            p50_ms: 50.0,
            p99_ms: 90.0,
            mean_tile_bytes: 16300.0,
            mean_raw_bytes: Some(31500.0),
            content_encoding: Some("gzip".into()),
            accept: Some("application/vnd.quantized-mesh;extensions=octvertexnormals".into()),
            rss_mib: 40.0,
            tile_cache_hits: Some(if mode == "cold" { 0.0 } else { 100.0 }),
            tile_cache_misses: Some(if mode == "cold" { 552.0 } else { 0.0 }),
            cores: Some(2),
            server_cpus: Some("0-1".into()),
            measured: Some("2026-12-01T19:00:00Z".into()),
            commit: Some("abc1234".into()),
            loadavg_1m: Some(1.2),
        }
    }

    #[test]
    fn fast_small_meshes_meet_both_aims() {
        let mesh: Vec<_> = (1..=5).map(|i| tile("moon", 8, i, 400.0, 2000.0)).collect();
        let s = section(
            Some(&mesh),
            Some(&[serve("cold", 1, 500.0), serve("warm", 1, 900.0)]),
        );
        assert_eq!(s.aims[0].verdict, Verdict::Met, "{}", s.aims[0].measured);
        assert_eq!(s.aims[1].verdict, Verdict::Met, "{}", s.aims[1].measured);
        assert!(
            s.aims[1].measured.contains("0.24×"),
            "{}",
            s.aims[1].measured
        );
        assert!(s.markdown.contains("44521 (≈ 211²)"), "{}", s.markdown);
        assert!(s.markdown.contains("(worst 0.933 ε)"), "{}", s.markdown);
        assert!(
            s.markdown.contains("| cold | curl -Z | 1 | 500 |"),
            "{}",
            s.markdown
        );
        assert!(s.markdown.contains("16.3 gzip (31.5)"), "{}", s.markdown);
        assert!(
            s.markdown.contains("| warm | wrk | 1 | 900 |"),
            "{}",
            s.markdown
        );
        assert!(s.markdown.contains("CPUs 0-1 of the machine's 2 cores"));
    }

    #[test]
    fn slow_or_dense_meshes_fail_and_missing_results_are_not_run() {
        let mut mesh: Vec<_> = (1..=3).map(|i| tile("moon", 8, i, 400.0, 2000.0)).collect();
        mesh.extend((1..=3).map(|i| tile("N46E008", 10, i, 8000.0, 5000.0)));
        let s = section(Some(&mesh), None);
        assert_eq!(s.aims[0].verdict, Verdict::NotMet);
        assert!(s.aims[0].measured.contains("`N46E008` zoom 10"));
        assert!(
            s.aims[0].measured.contains("8 ms"),
            "{}",
            s.aims[0].measured
        );
        assert_eq!(s.aims[1].verdict, Verdict::NotMet, "0.61× the grid");
        assert!(s.markdown.contains("Serving not run"), "{}", s.markdown);
        // A mesh worse than the grid it is compared with fails the aim however few
        // triangles it has.
        let mut worse = tile("moon", 8, 1, 400.0, 1000.0);
        worse.at_regular_error_m = 510.0;
        let s = section(Some(&[worse]), None);
        assert_eq!(s.aims[1].verdict, Verdict::NotMet);
        let none = section(None, None);
        assert!(none.markdown.contains("Not run"), "{}", none.markdown);
        assert!(none.aims.iter().all(|a| a.verdict == Verdict::NotMeasured));
        let s = section(None, Some(&[serve("cold", 1, 500.0)]));
        assert!(s.markdown.contains("Meshing not run"), "{}", s.markdown);
        assert!(s.aims.iter().all(|a| a.verdict == Verdict::NotMeasured));
    }

    #[test]
    fn quantiles_by_nearest_rank() {
        let v: Vec<f64> = (1..=10).map(f64::from).collect();
        assert_eq!(quantile(&v, 0.9), Some(9.0));
        assert_eq!(quantile(&v, 0.5), Some(5.0));
        assert_eq!(quantile(&[], 0.9), None);
    }
}
