//! `{{gpu}}`: frames per second on a real GPU, measured only when the run was
//! lent one (the project's machine has none); otherwise the section says so.

use super::{Section, Table, distinct, tau};
use crate::results::GpuRun;
use crate::stats::Spread;

pub fn section(records: Option<&[GpuRun]>) -> Section {
    let Some(records) = records.filter(|r| !r.is_empty()) else {
        return Section {
            markdown: "*Not measured: no GPU lent (the results have no `gpu.jsonl`).*\n".into(),
            ..Section::default()
        };
    };
    let keys = distinct(
        records
            .iter()
            .map(|r| (r.gpu.as_str(), r.width, r.height, r.tau)),
    );
    let mut table = Table::new(&[
        "GPU",
        "viewport",
        "τ",
        "runs",
        "fps, median (min–max of runs)",
    ]);
    for k in keys {
        let runs: Vec<&GpuRun> = records
            .iter()
            .filter(|r| (r.gpu.as_str(), r.width, r.height, r.tau) == k)
            .collect();
        let Some(fps) = Spread::of(runs.iter().map(|r| r.fps_median)) else {
            continue;
        };
        table.row(vec![
            k.0.to_string(),
            format!("{}×{}", k.1, k.2),
            tau(k.3),
            runs.len().to_string(),
            fps.fmt(),
        ]);
    }
    Section {
        markdown: table.render(),
        ..Section::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn absent_is_not_measured_and_present_is_tabled() {
        assert!(section(None).markdown.contains("Not measured: no GPU lent"));
        let rec = |run, fps_median| GpuRun {
            gpu: "NVIDIA H100".into(),
            width: 1920,
            height: 1080,
            tau: 1.0,
            run,
            fps_median,
        };
        let s = section(Some(&[rec(1, 300.0), rec(2, 320.0), rec(3, 310.0)]));
        assert!(
            s.markdown
                .contains("| NVIDIA H100 | 1920×1080 | 1 | 3 | 310 (300–320) |"),
            "{}",
            s.markdown
        );
    }
}
