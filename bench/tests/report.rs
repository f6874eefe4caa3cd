//! End to end: `tessera-bench report` on the hand-made results in
//! `bench/testdata/results` with the real template, and its failures.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use tessera_charts::png::read_png;

fn crate_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn report(results: &Path, template: &Path, out: &Path, plots: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_tessera-bench"))
        .arg("report")
        .arg("--results")
        .arg(results)
        .arg("--template")
        .arg(template)
        .arg("--out")
        .arg(out)
        .arg("--plots")
        .arg(plots)
        .output()
        .expect("run tessera-bench")
}

fn template() -> PathBuf {
    crate_dir().join("BENCHMARKS.md.in")
}

fn testdata() -> PathBuf {
    crate_dir().join("testdata/results")
}

/// GitHub's anchor of a heading (the test's own, to check the report's links).
fn anchor(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

/// The line of `doc` containing `needle`.
fn line_with<'a>(doc: &'a str, needle: &str) -> &'a str {
    doc.lines()
        .find(|l| l.contains(needle))
        .unwrap_or_else(|| panic!("no line with {needle:?}"))
}

#[test]
fn the_report_has_every_section_the_numbers_and_the_verdicts() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("doc/BENCHMARKS.md");
    let plots = dir.path().join("plots");
    let o = report(&testdata(), &template(), &out, &plots);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let doc = std::fs::read_to_string(&out).expect("BENCHMARKS.md written");

    assert!(!doc.contains("{{"), "a placeholder is left");
    for heading in [
        "## Aims",
        "## Build",
        "## Serving",
        "## Load replay",
        "## Selection policy",
        "## Parallax: the González table",
        "## Streaming under latency",
        "## Selection time",
        "## Real datasets",
        "## Web tiles",
        "## Cesium terrain",
        "## GPU",
    ] {
        assert!(doc.contains(&format!("\n{heading}\n")), "no {heading}");
    }
    // Every results file is there, so only the GPU section is not measured.
    assert!(!doc.contains("Not run"), "a section says it was not run");
    assert!(doc.contains("Not measured: no GPU lent"));
    assert!(doc.contains("| runs per measurement | 3 |"));
    assert!(!doc.contains("Quick run"));

    // Known medians (min–max) from the hand-made records.
    let moon = line_with(&doc, "| Tessera `build` | `moon_crisium_gld100_8192.png` |");
    assert!(moon.contains("| 2.16 (2.14–2.18) |"), "{moon}");
    let nginx64 = line_with(&doc, "| nginx: one static tile file per request | 64 |");
    assert!(nginx64.contains("| 0.98 (0.95–1.01) |"), "{nginx64}");
    let canyon = line_with(&doc, "| `synthetic:65537` | `canyon` |");
    assert!(canyon.contains("| 595 (571–619) |"), "{canyon}");

    // The mosaic: medians 23 s against 21 s, 1.095× (≤ 1.1, met), per-run ratios
    // 1.05–1.19; reprojection alone 4.0, 4.2, 4.1 s against gdalwarp's 3.0, 3.2,
    // 3.1 s (0.76×, not met).
    let mosaic = line_with(&doc, "| [Real datasets](#real-datasets): a 64-file mosaic");
    assert!(mosaic.ends_with("| **met** |"), "{mosaic}");
    assert!(mosaic.contains("1.10× (1.05–1.19×)"), "{mosaic}");
    let warp = line_with(&doc, "| [Real datasets](#real-datasets): reprojection");
    assert!(warp.ends_with("| **not met** |"), "{warp}");
    assert!(
        doc.contains("| reproject | `gdalwarp -r bilinear` | 3 | 3.1 (3.0–3.2) |"),
        "{doc}"
    );
    // Mixed grids: the build 0.66, 0.72, 0.70 s against gdalwarp + the single build
    // 0.60, 0.64, 0.59 s: 1.17× (≤ 1.3, met); 47 MiB at most against 256.
    let mixed = line_with(
        &doc,
        "| [Real datasets](#real-datasets): a mosaic of 64 pieces",
    );
    assert!(mixed.ends_with("| **met** |"), "{mixed}");
    assert!(mixed.contains("1.17× (1.10–1.19×)"), "{mixed}");
    let budget = line_with(
        &doc,
        "| [Real datasets](#real-datasets): the mixed-grid build's",
    );
    assert!(
        budget.contains("47 MiB at most in 3 runs, budget 256 MiB"),
        "{budget}"
    );
    assert!(budget.ends_with("| **met** |"), "{budget}");
    assert!(
        doc.contains("| mixed | `64 pieces in 3 CRSs` | 3 | 0.70 (0.66–0.72) |"),
        "{doc}"
    );

    // Load replay: Tessera 11500 tiles/s against wrk's 10200 (median), runs 1.10,
    // 1.15, 1.13: met; oha's half-rate row held its rate in 3 of 3 runs.
    let replay = line_with(
        &doc,
        "| [Load replay](#load-replay): one `tessera load --replay`",
    );
    assert!(replay.ends_with("| **met** |"), "{replay}");
    assert!(replay.contains("1.13× (1.10–1.15×)"), "{replay}");
    let oha_half = line_with(&doc, "| oha (`--urls-from-file`) | 3 | 1438 (1438–1438) |");
    assert!(oha_half.contains("| 3 of 3 runs |"), "{oha_half}");

    // Verdicts in the aims table.
    let faster = line_with(&doc, "| [Build](#build): build faster");
    assert!(faster.ends_with("| **met** |"), "{faster}");
    let flat = line_with(&doc, "| [Build](#build): peak RSS flat");
    assert!(flat.ends_with("| **not met** |"), "{flat}");
    assert!(flat.contains("+27%"), "{flat}");
    let binary = line_with(&doc, "binary-search parallax MSE ≤ 1/5");
    assert!(
        binary.contains("0.15×") && binary.ends_with("| **met** |"),
        "{binary}"
    );
    let select = line_with(&doc, "| [Selection time](#selection-time)");
    assert!(select.ends_with("| **not met** |"), "{select}");
    // Web tiles: cold 63 against 8 tiles/s (7.88×), source-warm 42 against 10.5
    // (4.0×): the 10× aim not met; warm 5500 tiles/s on 2 cores, 2750 per core: met.
    let web = line_with(&doc, "| [Web tiles](#web-tiles): Web Mercator");
    assert!(web.ends_with("| **not met** |"), "{web}");
    assert!(
        web.contains("cold 7.88×, source-warm 4.00×, warm 524×"),
        "{web}"
    );
    let core = line_with(&doc, "| [Web tiles](#web-tiles): ≥ 2000 tiles/s per core");
    assert!(core.ends_with("| **met** |"), "{core}");
    let warm = line_with(&doc, "| Tessera warm: made tiles cached |");
    assert!(
        warm.contains("| 5500 (5000–6000) | 2750 (2500–3000) |"),
        "{warm}"
    );
    assert!(doc.contains("Tessera decodes to 1436.0 m, TiTiler to 1436.0 m"));
    // Cesium terrain: N46E008 zoom 10 meshes in 8 ms (median), the moon's zoom 8 in
    // 400 µs: the 0.5 ms aim not met; 3000 and 2000 of 8192 triangles (0.37×, 0.24×)
    // at 0.95× the grid's error: met. Serving: cold 460 and 470 tiles/s.
    let mesh = line_with(&doc, "| [Cesium terrain](#cesium-terrain): ≤ 0.5 ms");
    assert!(mesh.ends_with("| **not met** |"), "{mesh}");
    assert!(
        mesh.contains("`N46E008` zoom 10 (≈ 211² samples): 8 ms"),
        "{mesh}"
    );
    let tri = line_with(
        &doc,
        "| [Cesium terrain](#cesium-terrain): ≤ 0.5× the triangles",
    );
    assert!(tri.ends_with("| **met** |"), "{tri}");
    assert!(tri.contains("`N46E008` zoom 10: 0.37×"), "{tri}");
    let cold = line_with(&doc, "| `N46E008` | 12 | 552 |");
    assert!(
        cold.contains("| cold | curl -Z | 2 | 465 (460–470) |"),
        "{cold}"
    );
    // Serving CPU: 0.26 s per GB of payload for batches of 16 against nginx's 0.20, per
    // GB that wrk read 1.30× all the same (not met).
    let cpu = line_with(
        &doc,
        "| [Serving](#serving): Morton batches of 16 spend ≤ 1.2×",
    );
    assert!(cpu.ends_with("| **not met** |"), "{cpu}");
    assert!(cpu.contains("64 connections: 1.30×"), "{cpu}");
    assert!(
        doc.contains("11 of 20 aims met, 9 not met, 0 not measured."),
        "{doc}"
    );

    // Every link to a section lands on a heading.
    let headings: Vec<String> = doc
        .lines()
        .filter_map(|l| l.strip_prefix("## "))
        .map(anchor)
        .collect();
    for part in doc.split("](#").skip(1) {
        let a = part.split(')').next().unwrap_or("");
        assert!(headings.iter().any(|h| h == a), "no heading for #{a}");
    }

    // The charts: linked relative to the document, 900×500 PNGs.
    for name in [
        "build.png",
        "build_rss.png",
        "serve.png",
        "load.png",
        "policy.png",
        "gonzalez.png",
        "stream.png",
        "select.png",
        "webtiles.png",
    ] {
        assert!(
            doc.contains(&format!("](../plots/{name})")),
            "{name} not linked"
        );
        let (_, w, h) = read_png(&plots.join(name)).expect("a PNG");
        assert_eq!((w, h), (900, 500), "{name}");
    }
    // Nothing left behind but the outputs.
    let names: Vec<String> = std::fs::read_dir(out.parent().expect("dir"))
        .expect("list")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["BENCHMARKS.md"]);
}

#[test]
fn missing_results_say_not_run_and_aims_not_measured() {
    let dir = tempfile::tempdir().expect("tempdir");
    let results = dir.path().join("results");
    std::fs::create_dir(&results).expect("mkdir");
    std::fs::copy(testdata().join("meta.json"), results.join("meta.json")).expect("copy");
    let out = dir.path().join("BENCHMARKS.md");
    let o = report(&results, &template(), &out, &dir.path().join("plots"));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let doc = std::fs::read_to_string(&out).expect("written");
    assert!(doc.contains("*Not run: the results have no `serve.jsonl`.*"));
    assert!(doc.contains("*Not run: the results have no `terrain_mesh.jsonl`.*"));
    assert!(
        doc.contains("0 of 20 aims met, 0 not met, 20 not measured."),
        "{doc}"
    );
}

#[test]
fn bad_input_fails_naming_the_file_and_leaves_the_old_report() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("BENCHMARKS.md");
    std::fs::write(&out, "old").expect("write");
    let plots = dir.path().join("plots");

    // A record with a field missing.
    let results = dir.path().join("results");
    std::fs::create_dir(&results).expect("mkdir");
    for e in std::fs::read_dir(testdata()).expect("list") {
        let e = e.expect("entry");
        std::fs::copy(e.path(), results.join(e.file_name())).expect("copy");
    }
    let serve = std::fs::read_to_string(results.join("serve.jsonl")).expect("read");
    let broken = serve.replacen("\"p99_ms\":", "\"p98_ms\":", 1);
    std::fs::write(results.join("serve.jsonl"), broken).expect("write");
    let o = report(&results, &template(), &out, &plots);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("serve.jsonl") && err.contains("line 1") && err.contains("p99_ms"),
        "{err}"
    );
    assert_eq!(std::fs::read_to_string(&out).expect("read"), "old");

    // An unknown placeholder in the template.
    let bad = dir.path().join("bad.md.in");
    let text = std::fs::read_to_string(template()).expect("template");
    std::fs::write(&bad, text.replace("{{load}}", "{{lod}}")).expect("write");
    let o = report(&testdata(), &bad, &out, &plots);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("bad.md.in") && err.contains("{{lod}}"),
        "{err}"
    );
    assert_eq!(std::fs::read_to_string(&out).expect("read"), "old");
    assert!(!plots.exists() || std::fs::read_dir(&plots).expect("list").next().is_none());
}
