//! `tessera-bench report`: turns the raw results that `./run bench` writes (JSON
//! and JSON Lines, one file per benchmark) into BENCHMARKS.md and its PNG charts.
//!
//! The document is regenerated whole from a template (`bench/BENCHMARKS.md.in`:
//! the prose, with `{{name}}` placeholders for the generated parts), so every
//! number in it comes from one results directory. Nothing is written until
//! everything has been read and checked; the Markdown is written to a temporary
//! file beside the output and renamed into place, so a failed report never
//! leaves a partial BENCHMARKS.md.
//!
//! Modules: `results` (reading and checking the raw results), `stats` (medians and
//! ratios), `sections` (one per BENCHMARKS.md section), `chart` (the PNG charts) and
//! `template` (filling the template's placeholders).

mod chart;
mod results;
mod sections;
mod stats;
mod template;

use anyhow::Context;
use clap::{Parser, Subcommand};
use sections::{Aim, Ctx, Section};
use std::collections::BTreeMap;
use std::path::{Component, Path, PathBuf};

#[derive(Debug, Parser)]
#[command(
    name = "tessera-bench",
    version,
    about = "Tessera's benchmark report generator"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Write BENCHMARKS.md and its charts from a results directory.
    Report {
        /// The results directory (meta.json, build.jsonl, serve.jsonl, …); a
        /// missing file makes its section say "not run".
        #[arg(long)]
        results: PathBuf,
        /// The Markdown template with `{{name}}` placeholders.
        #[arg(long)]
        template: PathBuf,
        /// The Markdown to write (replaced atomically).
        #[arg(long)]
        out: PathBuf,
        /// Where to write the PNG charts; linked relative to `--out`.
        #[arg(long)]
        plots: PathBuf,
    },
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Report {
            results,
            template,
            out,
            plots,
        } => report(&results, &template, &out, &plots),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn report(results: &Path, template: &Path, out: &Path, plots: &Path) -> anyhow::Result<()> {
    let r = results::Results::load(results)?;
    let text = std::fs::read_to_string(template)
        .with_context(|| format!("{}: cannot read the template", template.display()))?;
    let out_dir = parent(out);
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("{}: cannot create", out_dir.display()))?;
    std::fs::create_dir_all(plots)
        .with_context(|| format!("{}: cannot create", plots.display()))?;
    let ctx = Ctx {
        plots: link(out_dir, plots)?,
    };

    let parts: Vec<(&str, Section)> = vec![
        ("build", sections::build::section(r.build.as_deref(), &ctx)),
        ("serve", sections::serve::section(r.serve.as_deref(), &ctx)),
        ("load", sections::load::section(r.load.as_deref(), &ctx)),
        (
            "loadreplay",
            sections::loadreplay::section(r.loadreplay.as_deref()),
        ),
        (
            "policy",
            sections::policy::section(r.policy.as_deref(), &ctx),
        ),
        (
            "gonzalez",
            sections::gonzalez::section(r.gonzalez.as_deref(), &ctx),
        ),
        (
            "stream",
            sections::stream::section(r.stream.as_deref(), &ctx),
        ),
        (
            "select",
            sections::select::section(r.select.as_deref(), &ctx),
        ),
        ("gpu", sections::gpu::section(r.gpu.as_deref())),
        ("ingest", sections::ingest::section(r.ingest.as_deref())),
        (
            "webtiles",
            sections::webtiles::section(
                r.webtiles.as_deref(),
                r.webtiles_check.as_deref(),
                r.meta.as_ref().map(|m| m.cores),
                &ctx,
            ),
        ),
        (
            "terrain",
            sections::terrain::section(r.terrain_mesh.as_deref(), r.terrain_serve.as_deref()),
        ),
    ];
    let aims: Vec<Aim> = parts.iter().flat_map(|(_, s)| s.aims.clone()).collect();
    let mut values: BTreeMap<&str, String> = BTreeMap::new();
    values.insert("meta", sections::meta::section(r.meta.as_ref()));
    values.insert("aims", sections::aims::section(&aims));
    for (name, s) in &parts {
        values.insert(name, s.markdown.clone());
    }
    let doc = template::render(&text, &values).with_context(|| template.display().to_string())?;
    for anchor in sections::aims::broken_links(&doc) {
        eprintln!(
            "warning: {}: no heading for the link #{anchor}",
            template.display()
        );
    }

    let mut written = 0;
    for (_, s) in &parts {
        for c in &s.charts {
            c.image.write(&plots.join(&c.file))?;
            written += 1;
        }
    }
    write_atomically(out, doc.as_bytes())?;
    let met = aims
        .iter()
        .filter(|a| a.verdict == sections::Verdict::Met)
        .count();
    println!(
        "{}: {met} of {} aims met; {written} charts in {}",
        out.display(),
        aims.len(),
        plots.display()
    );
    Ok(())
}

/// The directory `path` is in ("." for a bare file name).
fn parent(path: &Path) -> &Path {
    path.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// `to` relative to `from` (both existing directories), with `/` separators, for
/// a Markdown link; "" when they are the same.
fn link(from: &Path, to: &Path) -> anyhow::Result<String> {
    let canon = |p: &Path| {
        p.canonicalize()
            .with_context(|| format!("{}: cannot resolve", p.display()))
    };
    let rel = relative(&canon(from)?, &canon(to)?);
    let parts: Vec<String> = rel
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    Ok(parts.join("/"))
}

/// `to` relative to `from`, both absolute and normalised.
fn relative(from: &Path, to: &Path) -> PathBuf {
    let f: Vec<Component> = from.components().collect();
    let t: Vec<Component> = to.components().collect();
    let common = f.iter().zip(&t).take_while(|(a, b)| a == b).count();
    let mut out = PathBuf::new();
    for _ in common..f.len() {
        out.push("..");
    }
    for c in &t[common..] {
        out.push(c.as_os_str());
    }
    out
}

/// Writes `bytes` to a temporary file beside `path`, then renames it into place.
fn write_atomically(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let name = path
        .file_name()
        .with_context(|| format!("{}: not a file name", path.display()))?;
    let tmp = parent(path).join(format!(
        ".{}.partial-{}",
        name.to_string_lossy(),
        std::process::id()
    ));
    let result = std::fs::write(&tmp, bytes).and_then(|()| std::fs::rename(&tmp, path));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.with_context(|| format!("{}: cannot write", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_links() {
        let r = |a: &str, b: &str| relative(Path::new(a), Path::new(b));
        assert_eq!(
            r("/w/main", "/w/main/bench/plots"),
            PathBuf::from("bench/plots")
        );
        assert_eq!(r("/tmp/r", "/tmp/r"), PathBuf::new());
        assert_eq!(r("/tmp/r/doc", "/tmp/plots"), PathBuf::from("../../plots"));
        let dir = tempfile::tempdir().expect("tempdir");
        let plots = dir.path().join("bench/plots");
        std::fs::create_dir_all(&plots).expect("mkdir");
        assert_eq!(link(dir.path(), &plots).expect("link"), "bench/plots");
        assert_eq!(link(dir.path(), dir.path()).expect("link"), "");
    }

    #[test]
    fn atomic_write_replaces_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("B.md");
        std::fs::write(&path, "old").expect("write");
        write_atomically(&path, b"new").expect("replace");
        assert_eq!(std::fs::read_to_string(&path).expect("read"), "new");
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .expect("list")
            .map(|e| e.expect("entry").file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("B.md")]);
        // Into a directory that does not exist: an error naming the file.
        let e = write_atomically(&dir.path().join("no/B.md"), b"x").expect_err("no dir");
        assert!(format!("{e:#}").contains("B.md"));
    }
}
