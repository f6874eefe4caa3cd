//! `tessera report`: a flight's `stats.jsonl` (and frames) into `stats.png`,
//! `contact_sheet.png` and a few lines of summary.

use super::animation::AnimationError;
use super::contact_sheet::{contact_sheet_labelled, pick_evenly_indices};
use crate::errors::PngError;
use std::fmt::Write as _;
use std::path::Path;
use std::path::PathBuf;
use tessera_charts::plot::{Series, plot_panels};
use tessera_charts::png::{read_png, write_png};

/// A flight's statistics as read: the frames' records, and the last line if it was
/// cut short and dropped.
#[derive(Clone, Debug, PartialEq)]
pub struct Stats {
    pub records: Vec<serde_json::Value>,
    pub torn: Option<TornLine>,
}

/// The last line of a stats file, cut short (a flight killed mid-write, `kill -9`
/// or a full disk) and dropped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TornLine {
    /// 1-based.
    pub line: usize,
    /// The bytes of it dropped.
    pub bytes: usize,
}

impl std::fmt::Display for TornLine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "line {} is cut short (the flight stopped while writing it): dropped its {} bytes",
            self.line, self.bytes
        )
    }
}

/// A `stats.jsonl` that could not be read: the file, or a line that is not JSON.
#[derive(Debug, thiserror::Error)]
pub enum StatsError {
    #[error("{}: cannot read", path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// What was wrong in the file at `path`.
    #[error("{}", path.display())]
    File {
        path: PathBuf,
        #[source]
        source: Box<StatsError>,
    },
    #[error("line {line} is not JSON")]
    Line {
        line: usize,
        #[source]
        source: LineError,
    },
}

/// Why a line of `stats.jsonl` is not JSON.
#[derive(Debug, thiserror::Error)]
pub enum LineError {
    #[error(transparent)]
    Utf8(#[from] std::str::Utf8Error),
    #[error(transparent)]
    Json(#[from] serde_json::Error),
}

/// Why a flight's report could not be made.
#[derive(Debug, thiserror::Error)]
pub enum FlightReportError {
    #[error(transparent)]
    Stats(#[from] StatsError),
    #[error("{}: no frames", path.display())]
    NoFrames { path: PathBuf },
    #[error("{}: cannot create", dir.display())]
    Create {
        dir: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    Png(#[from] PngError),
    #[error(transparent)]
    Animation(#[from] AnimationError),
}

/// Reads `stats.jsonl`: one JSON object per frame. A flight killed while writing
/// leaves its last line cut short: that line (not ending in a newline, or ending
/// mid-JSON) is dropped and said in [`Stats::torn`], since every frame before it is
/// whole. Any other line that is not JSON is an error naming it: that is a damaged
/// file, not a cut one.
pub fn read_stats(path: &Path) -> Result<Stats, StatsError> {
    let bytes = std::fs::read(path).map_err(|source| StatsError::Read {
        path: path.into(),
        source,
    })?;
    parse_stats(&bytes).map_err(|e| StatsError::File {
        path: path.into(),
        source: Box::new(e),
    })
}

/// [`read_stats`] on the file's bytes.
pub fn parse_stats(bytes: &[u8]) -> Result<Stats, StatsError> {
    // Bytes (not a String): a cut can split a UTF-8 character, which only the torn
    // line may hold.
    let complete = bytes.ends_with(b"\n");
    let lines: Vec<&[u8]> = bytes
        .strip_suffix(b"\n")
        .unwrap_or(bytes)
        .split(|&b| b == b'\n')
        .collect();
    let last = lines.iter().rposition(|l| !l.trim_ascii().is_empty());
    let mut stats = Stats {
        records: Vec::with_capacity(lines.len()),
        torn: None,
    };
    for (i, line) in lines.iter().enumerate() {
        if line.trim_ascii().is_empty() {
            continue;
        }
        let n = i + 1;
        let parsed = std::str::from_utf8(line)
            .map_err(LineError::from)
            .and_then(|t| serde_json::from_str::<serde_json::Value>(t).map_err(Into::into));
        match parsed {
            Ok(v) => stats.records.push(v),
            Err(e) if Some(i) == last && (!complete || ends_mid_json(&e)) => {
                stats.torn = Some(TornLine {
                    line: n,
                    bytes: line.len(),
                });
            }
            Err(source) => return Err(StatsError::Line { line: n, source }),
        }
    }
    Ok(stats)
}

/// Whether a parse failed because the text ended inside a JSON value (what a cut
/// leaves), not on bad syntax.
fn ends_mid_json(e: &LineError) -> bool {
    matches!(e, LineError::Json(e) if e.classify() == serde_json::error::Category::Eof)
}

fn column(records: &[serde_json::Value], key: &str, scale: f64) -> Vec<f64> {
    records
        .iter()
        .map(|r| r[key].as_f64().map_or(f64::NAN, |v| v * scale))
        .collect()
}

/// The median of the finite values (NaN when there are none).
fn median(v: &[f64]) -> f64 {
    let finite: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    tessera_charts::stats::median(&finite).unwrap_or(f64::NAN)
}

/// Writes `out/stats.png` and, with `frames`, `out/contact_sheet.png` (12 frames
/// spread over the flight). Returns a short summary for people.
pub fn write_report(
    stats: &Path,
    frames: Option<&Path>,
    out: &Path,
) -> Result<String, FlightReportError> {
    let Stats { records, torn } = read_stats(stats)?;
    if let Some(torn) = torn {
        crate::output::progress(format_args!("warning: {}: {torn}\n", stats.display()));
    }
    if records.is_empty() {
        return Err(FlightReportError::NoFrames { path: stats.into() });
    }
    std::fs::create_dir_all(out).map_err(|source| FlightReportError::Create {
        dir: out.into(),
        source,
    })?;
    let series = [
        Series::new("triangles", "", column(&records, "triangles", 1.0)),
        Series::new("draw calls", "", column(&records, "draw_calls", 1.0)),
        Series::new(
            "resident tiles (CPU)",
            "",
            column(&records, "resident", 1.0),
        ),
        Series::new(
            "bytes fetched",
            "MB",
            column(&records, "bytes_fetched", 1e-6),
        ),
        Series::new(
            "deficit (max rho / tau)",
            "",
            column(&records, "deficit", 1.0),
        ),
        Series::new("selection + upload", "ms", {
            let sel = column(&records, "select_us", 1e-3);
            let up = column(&records, "upload_ms", 1.0);
            sel.iter()
                .zip(&up)
                .map(|(a, b)| a + if b.is_finite() { *b } else { 0.0 })
                .collect()
        }),
    ];
    let (rgba, w, h) = plot_panels(&series, "frame", 1200, 180);
    write_png(&out.join("stats.png"), &rgba, w, h).map_err(PngError::from)?;
    if let Some(dir) = frames {
        let names = super::animation::frame_files(dir)?;
        let picked = pick_evenly_indices(names.len(), 12);
        let mut thumbs = Vec::new();
        let mut labels = Vec::new();
        for &i in &picked {
            thumbs.push(read_png(&names[i]).map_err(PngError::from)?);
            labels.push(format!(
                "#{}",
                names[i]
                    .file_stem()
                    .and_then(|s| s.to_str())
                    .and_then(|s| s.rsplit('_').next())
                    .and_then(|n| n.parse::<u32>().ok())
                    .unwrap_or(i as u32)
            ));
        }
        let (rgba, w, h) = contact_sheet_labelled(&thumbs, &labels, 4, 320);
        write_png(&out.join("contact_sheet.png"), &rgba, w, h).map_err(PngError::from)?;
    }
    let n = records.len();
    let within_by = |field: &str, limit: f64| {
        100.0
            * records
                .iter()
                .filter(|r| {
                    r[field].as_f64().is_some_and(|d| d <= limit)
                        && r["tiles"].as_u64().unwrap_or(0) > 0
                })
                .count() as f64
            / n as f64
    };
    let within = |limit: f64| within_by("deficit", limit);
    // The surface as drawn, geomorph transitions included (stats written before
    // it was recorded have none).
    let drawn = if records.iter().any(|r| r.get("drawn_deficit").is_some()) {
        format!(
            " (as drawn, transitions included: {:.1}% and {:.1}%)",
            within_by("drawn_deficit", 1.0),
            within_by("drawn_deficit", 2.0)
        )
    } else {
        String::new()
    };
    let last = &records[n - 1];
    let max_draws = column(&records, "draw_calls", 1.0)
        .into_iter()
        .filter(|v| v.is_finite())
        .fold(0f64, f64::max);
    // What the client could not get is reported as missing, never as a huge deficit, with
    // the error that explains it (docs/ARCHITECTURE.md#the-client-never-goes-blind).
    let missing = records
        .iter()
        .filter(|r| r.get("max_rho").is_some_and(serde_json::Value::is_null))
        .count();
    let most_missing = records
        .iter()
        .filter_map(|r| r["missing"].as_u64())
        .max()
        .unwrap_or(0);
    let blind = records
        .iter()
        .all(|r| r["tiles"].as_u64().unwrap_or(0) == 0);
    let mut trouble = String::new();
    if blind {
        trouble.push_str("; nothing drawn in any frame");
    }
    if missing > 0 {
        let _ = write!(
            trouble,
            "; deficit missing in {missing} frames (up to {most_missing} tiles in view with nothing drawn)"
        );
    }
    if let Some(e) = last["last_error"].as_str() {
        let _ = write!(trouble, "; last error: {e}");
    }
    Ok(format!(
        "{n} frames: median {:.0} triangles, at most {max_draws:.0} terrain draw calls; {:.1}% of frames within τ, {:.1}% within 2τ{drawn}; \
         {:.1} MB in {} requests; median selection {:.2} ms, upload {:.2} ms, render {:.1} ms{trouble}",
        median(&column(&records, "triangles", 1.0)),
        within(1.0),
        within(2.0),
        last["bytes_fetched"].as_f64().unwrap_or(0.0) / 1e6,
        last["requests"].as_u64().unwrap_or(0),
        median(&column(&records, "select_us", 1e-3)),
        median(&column(&records, "upload_ms", 1.0)),
        median(&column(&records, "render_ms", 1.0)),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_plots_and_a_sheet_and_rejects_bad_stats() {
        let dir = tempfile::tempdir().unwrap();
        let stats = dir.path().join("stats.jsonl");
        let lines: Vec<String> = (0..30)
            .map(|f| {
                format!(
                    r#"{{"frame":{f},"tiles":3,"triangles":{},"draw_calls":4,"resident":{f},"bytes_fetched":{},"requests":2,"deficit":{},"drawn_deficit":{},"select_us":300,"upload_ms":1.5,"render_ms":40}}"#,
                    1000 + f * 10,
                    f * 100_000,
                    if f < 10 { 3.0 } else { 0.9 },
                    // As drawn: five more frames past τ (transitions in flight).
                    match f {
                        0..10 => 3.0,
                        10..15 => 1.5,
                        _ => 0.9,
                    }
                )
            })
            .collect();
        std::fs::write(&stats, lines.join("\n")).unwrap();
        let frames = dir.path().join("frames");
        std::fs::create_dir(&frames).unwrap();
        for f in 0..30 {
            let img = vec![(f * 8) as u8; 64 * 36 * 4];
            write_png(&frames.join(format!("frame_{f:05}.png")), &img, 64, 36).unwrap();
        }
        let out = dir.path().join("out");
        let summary = write_report(&stats, Some(&frames), &out).unwrap();
        // 1000, 1010, …, 1290: the median of an even count is the mean of the middle
        // two (1140 and 1150), the one median of `tessera_charts::stats`.
        assert!(
            summary.starts_with("30 frames: median 1145 triangles"),
            "{summary}"
        );
        assert!(summary.contains("66.7% of frames within τ"), "{summary}");
        assert!(
            summary.contains("(as drawn, transitions included: 50.0% and 66.7%)"),
            "{summary}"
        );
        assert!(!summary.contains("missing"), "{summary}");
        assert!(read_png(&out.join("stats.png")).is_ok());
        let (_, w, _) = read_png(&out.join("contact_sheet.png")).unwrap();
        assert!(w > 4 * 320);
        // Frames with tiles missing: the deficit is `null`, the summary says so.
        let lines: Vec<String> = (0..4)
            .map(|f| {
                let (tiles, rho, missing) = if f < 3 { (0, "null", 1) } else { (4, "0.5", 0) };
                format!(
                    r#"{{"frame":{f},"tiles":{tiles},"triangles":10,"max_rho":{rho},"deficit":{rho},"missing":{missing},"requests":5,"last_error":"level 0 tile (0, 0) morton 0: corrupt"}}"#
                )
            })
            .collect();
        std::fs::write(&stats, lines.join("\n")).unwrap();
        let summary = write_report(&stats, None, &out).unwrap();
        assert!(summary.contains("25.0% of frames within τ"), "{summary}");
        assert!(!summary.contains("as drawn"), "{summary}");
        assert!(
            summary.contains("deficit missing in 3 frames (up to 1 tiles"),
            "{summary}"
        );
        assert!(summary.contains("last error: level 0 tile (0, 0) morton 0: corrupt"));
        std::fs::write(&stats, "{\"frame\":0}\nnot json\n").unwrap();
        let e = write_report(&stats, None, &out).unwrap_err();
        let e = crate::errors::Chain(&e).to_string();
        assert!(e.contains("line 2 is not JSON"), "{e}");
    }

    const FRAME: &str = r#"{"frame":0,"tiles":3,"triangles":10,"last_error":"a é"}"#;

    #[test]
    fn a_last_line_cut_short_is_dropped_and_said() {
        let whole = format!("{FRAME}\n{FRAME}\n{FRAME}\n");
        let read = parse_stats(whole.as_bytes()).unwrap();
        assert_eq!((read.records.len(), read.torn), (3, None));
        // Cut anywhere inside the third line (kill -9 mid-write), even inside the
        // two-byte é: two frames and the cut line said, with its length. The whole
        // file used to be refused.
        let third = 2 * (FRAME.len() + 1);
        for cut in [
            third + 1,
            third + 10,
            whole.len() - 5,
            whole.len() - 4,
            whole.len() - 3,
            whole.len() - 2,
        ] {
            let read = parse_stats(&whole.as_bytes()[..cut]).unwrap();
            assert_eq!(read.records.len(), 2, "cut at {cut}");
            assert_eq!(
                read.torn,
                Some(TornLine {
                    line: 3,
                    bytes: cut - third
                }),
                "cut at {cut}"
            );
        }
        let said = TornLine { line: 3, bytes: 17 }.to_string();
        assert!(
            said.contains("line 3") && said.contains("17 bytes"),
            "{said}"
        );
        // Partial JSON with its newline (the rest of the line lost): dropped too.
        let partial = format!("{FRAME}\n{}\n", &FRAME[..20]);
        let read = parse_stats(partial.as_bytes()).unwrap();
        assert_eq!(read.torn, Some(TornLine { line: 2, bytes: 20 }));
        // A whole last line without its newline is a frame, not a cut.
        let read = parse_stats(whole.trim_end().as_bytes()).unwrap();
        assert_eq!((read.records.len(), read.torn), (3, None));
        // Blank lines after the cut do not hide it.
        let read = parse_stats(format!("{FRAME}\n{}\n\n", &FRAME[..9]).as_bytes()).unwrap();
        assert_eq!(read.torn, Some(TornLine { line: 2, bytes: 9 }));
    }

    #[test]
    fn a_bad_line_before_the_last_is_still_an_error_naming_it() {
        let err = |text: String| {
            crate::errors::Chain(&parse_stats(text.as_bytes()).unwrap_err()).to_string()
        };
        // Cut short in the middle: not what a killed writer leaves.
        let e = err(format!("{FRAME}\n{}\n{FRAME}\n", &FRAME[..20]));
        assert!(e.contains("line 2 is not JSON"), "{e}");
        // A complete last line that is not JSON is damage, not a cut.
        let e = err(format!("{FRAME}\n{FRAME}\nnot json\n"));
        assert!(e.contains("line 3 is not JSON"), "{e}");
        // Bytes that are not UTF-8, in the middle.
        let mut bad = format!("{FRAME}\n").into_bytes();
        bad.extend_from_slice(&[0xFF, 0xFE, b'\n']);
        bad.extend_from_slice(FRAME.as_bytes());
        let e = crate::errors::Chain(&parse_stats(&bad).unwrap_err()).to_string();
        assert!(e.contains("line 2 is not JSON"), "{e}");
        // Through the file, naming it.
        let dir = tempfile::tempdir().unwrap();
        let stats = dir.path().join("stats.jsonl");
        std::fs::write(&stats, format!("{FRAME}\nnot json\n{FRAME}\n")).unwrap();
        let e = crate::errors::Chain(&read_stats(&stats).unwrap_err()).to_string();
        assert!(
            e.contains("stats.jsonl") && e.contains("line 2 is not JSON"),
            "{e}"
        );
        // And the report of a cut file is made from the frames before the cut.
        std::fs::write(&stats, format!("{FRAME}\n{FRAME}\n{}", &FRAME[..30])).unwrap();
        let summary = write_report(&stats, None, &dir.path().join("out")).unwrap();
        assert!(summary.starts_with("2 frames"), "{summary}");
    }
}
