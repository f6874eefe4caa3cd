//! `DIR/latency.png` of a replay (DECISIONS.md "Load testing: replay"): latency and rate
//! over the run, one panel per series over a shared axis of seconds, drawn by the charts
//! crate.

use super::replay_report::ReplayReport;
use crate::errors::PngError;
use std::path::Path;
use tessera_charts::plot::{Series, plot_panels};

/// The series plotted: corrected and uncorrected p50 and p99 per second, the target
/// (scheduled) and achieved (completed) requests per second. Seconds in which nothing
/// completed are gaps in the latency lines.
pub fn series(report: &ReplayReport) -> Vec<Series> {
    let t = &report.timeline;
    let ms = |f: fn(&super::replay_report::Second) -> Option<f64>| {
        t.iter()
            .map(|s| f(s).unwrap_or(f64::NAN))
            .collect::<Vec<f64>>()
    };
    let count =
        |f: fn(&super::replay_report::Second) -> u64| t.iter().map(|s| f(s) as f64).collect();
    let mut out = vec![
        Series::new(
            "corrected p50 (from the scheduled start)",
            "ms",
            ms(|s| s.corrected_p50_ms),
        ),
        Series::new("corrected p99", "ms", ms(|s| s.corrected_p99_ms)),
        Series::new(
            "uncorrected p50 (from the send)",
            "ms",
            ms(|s| s.uncorrected_p50_ms),
        ),
        Series::new("uncorrected p99", "ms", ms(|s| s.uncorrected_p99_ms)),
    ];
    if report.target_rate.is_some() {
        out.push(Series::new(
            "target rate (scheduled)",
            "requests/s",
            count(|s| s.scheduled),
        ));
    }
    out.push(Series::new(
        "achieved rate (completed)",
        "requests/s",
        count(|s| s.completed),
    ));
    out
}

/// Writes the plot to `path` (temp and rename: never a partial PNG).
pub fn write(report: &ReplayReport, path: &Path) -> Result<(), PngError> {
    let (rgba, w, h) = plot_panels(&series(report), "second", 1200, 170);
    Ok(tessera_charts::png::write_png(path, &rgba, w, h)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::loadtest::replay_report::{Http, Latency, LatencyFrom, Mode, Second};

    #[test]
    fn the_plot_has_a_point_per_second_and_gaps_where_nothing_completed() {
        let mut l = Latency::new();
        l.record_micros(1500);
        let mut s0 = Second::new(0, &l, &l);
        s0.scheduled = 10;
        s0.completed = 9;
        let s1 = Second::new(1, &Latency::new(), &Latency::new());
        let mut report = ReplayReport::empty(Mode::Rate, Http::Http1, LatencyFrom::Scheduled);
        report.target_rate = Some(10.0);
        report.timeline = vec![s0, s1];
        let series = series(&report);
        assert_eq!(series.len(), 6);
        assert!(series.iter().all(|s| s.values.len() == 2));
        assert!((series[0].values[0] - 1.5).abs() < 0.01);
        assert!(series[0].values[1].is_nan());
        assert_eq!(series[4].values, vec![10.0, 0.0]);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("latency.png");
        write(&report, &path).unwrap();
        let (_, w, h) = tessera_charts::png::read_png(&path).unwrap();
        assert_eq!(w, 1200);
        assert!(h >= 6 * 170);
    }
}
