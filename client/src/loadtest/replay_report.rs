//! The report of a replay (DECISIONS.md "Load testing: replay"): what `--json` prints and
//! `--out DIR` writes as `DIR/load.json`; how the reports of many load processes
//! (`--shard K/N`) add up into one (`tessera load merge`) is in `merge.rs`.
//!
//! Latencies are HDR histograms written into the report V2-encoded (`latency.rs`), so
//! that merging adds the histograms themselves.

use super::check::ErrorKind;
use serde::{Deserialize, Serialize};

/// The `tessera_load` value of the reports this build writes and merges.
pub const REPORT_VERSION: u32 = 1;

pub use super::latency::{Histograms, Latency, Percentiles};

/// Failed requests by kind (the JSON keys of `errors`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ErrorCounts {
    pub connect: u64,
    pub timeout: u64,
    pub http_status: u64,
    pub corrupt: u64,
    pub truncated: u64,
    pub mismatch: u64,
    /// (0 in reports written before the kind existed.)
    #[serde(default)]
    pub request: u64,
}

impl ErrorCounts {
    pub fn get(&self, kind: ErrorKind) -> u64 {
        match kind {
            ErrorKind::Connect => self.connect,
            ErrorKind::Timeout => self.timeout,
            ErrorKind::HttpStatus => self.http_status,
            ErrorKind::Corrupt => self.corrupt,
            ErrorKind::Truncated => self.truncated,
            ErrorKind::Mismatch => self.mismatch,
            ErrorKind::Request => self.request,
        }
    }

    fn slot(&mut self, kind: ErrorKind) -> &mut u64 {
        match kind {
            ErrorKind::Connect => &mut self.connect,
            ErrorKind::Timeout => &mut self.timeout,
            ErrorKind::HttpStatus => &mut self.http_status,
            ErrorKind::Corrupt => &mut self.corrupt,
            ErrorKind::Truncated => &mut self.truncated,
            ErrorKind::Mismatch => &mut self.mismatch,
            ErrorKind::Request => &mut self.request,
        }
    }

    /// Counts `n` more of `kind` (saturating: a run counts far fewer than 2⁶⁴).
    pub fn add(&mut self, kind: ErrorKind, n: u64) {
        let c = self.slot(kind);
        *c = c.saturating_add(n);
    }

    /// Sets the count of one kind.
    pub fn set(&mut self, kind: ErrorKind, n: u64) {
        *self.slot(kind) = n;
    }

    /// All kinds together (saturating: the counts of a report that passed
    /// [`ReplayReport::validate`] sum to at most its requests).
    pub fn total(&self) -> u64 {
        ErrorKind::ALL
            .iter()
            .fold(0u64, |t, &k| t.saturating_add(self.get(k)))
    }
}

/// How the replay paced its requests.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    Recorded,
    Rate,
    Ramp,
    Saturation,
}

impl Mode {
    pub fn name(self) -> &'static str {
        match self {
            Self::Recorded => "recorded",
            Self::Rate => "rate",
            Self::Ramp => "ramp",
            Self::Saturation => "saturation",
        }
    }
}

/// The HTTP version spoken.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Http {
    #[serde(rename = "1.1")]
    Http1,
    #[serde(rename = "2")]
    Http2,
}

impl Http {
    pub fn name(self) -> &'static str {
        match self {
            Self::Http1 => "1.1",
            Self::Http2 => "2",
        }
    }
}

/// Where latency is measured from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LatencyFrom {
    /// The request's scheduled start (open model; coordinated-omission corrected).
    Scheduled,
    /// The actual send (saturation's closed loop has no schedule: both histograms are
    /// the same).
    Sent,
}

/// One second of the run (second `s` covers `[s, s+1)` s after the start). Requests
/// count in the second they were scheduled (`scheduled`), sent (`sent`) and completed
/// (`completed`, `tiles`, `errors`, latencies).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Second {
    pub second: u64,
    pub scheduled: u64,
    pub sent: u64,
    pub completed: u64,
    pub tiles: u64,
    pub errors: u64,
    /// `None` (null) in a second in which nothing completed.
    pub corrected_p50_ms: Option<f64>,
    pub corrected_p99_ms: Option<f64>,
    pub uncorrected_p50_ms: Option<f64>,
    pub uncorrected_p99_ms: Option<f64>,
    /// This second's histograms, so that merged seconds have exact percentiles too.
    pub histograms: Histograms,
}

impl Second {
    /// A second with these counts and latencies (percentiles computed from them).
    pub fn new(second: u64, corrected: &Latency, uncorrected: &Latency) -> Self {
        let q = |l: &Latency, q: f64| (!l.is_empty()).then(|| l.quantile_ms(q));
        Self {
            second,
            corrected_p50_ms: q(corrected, 0.5),
            corrected_p99_ms: q(corrected, 0.99),
            uncorrected_p50_ms: q(uncorrected, 0.5),
            uncorrected_p99_ms: q(uncorrected, 0.99),
            histograms: Histograms::of(corrected, uncorrected),
            ..Self::default()
        }
    }
}

/// The report of one replay, or of several merged.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReplayReport {
    /// Always [`REPORT_VERSION`]; names the file as a load report.
    pub tessera_load: u32,
    pub mode: Mode,
    /// Requests per second the schedule asked of this process (of all, when merged):
    /// `--rate`, the ramp's or the recording's mean. Null at saturation.
    pub target_rate: Option<f64>,
    /// `K/N`; a merged report lists its shards' (`0/2,1/2`).
    pub shard: String,
    /// Load processes whose results are in this report.
    pub shards: u32,
    /// `--connections` (summed over shards when merged).
    pub connections: u32,
    pub http: Http,
    pub latency_from: LatencyFrom,
    /// From the start to the last answer (or the end of the wait for it); the longest
    /// shard's when merged.
    pub seconds: f64,
    /// Requests the schedule asked for (at saturation: sent).
    pub scheduled: u64,
    /// Requests sent.
    pub sent: u64,
    /// Requests answered (whatever the answer: `errors` says which were wrong).
    pub completed: u64,
    /// Tile frames received and verified.
    pub tiles: u64,
    /// Body bytes received.
    pub bytes: u64,
    /// Requests scheduled but not yet sent when the schedule ended.
    pub backlog: u64,
    /// Requests scheduled but never sent: the run's deadline (the schedule's end +
    /// `--timeout`) came first. Not errors: the server never saw them. (0 in reports
    /// written before the deadline existed.)
    #[serde(default)]
    pub unsent: u64,
    pub errors: ErrorCounts,
    /// The `http_status` errors by the status that came back (`{"414": 3, "503":
    /// 10}`): a 4xx (the request) is not a 5xx (the server). Empty in reports
    /// written before it existed.
    #[serde(default)]
    pub http_statuses: std::collections::BTreeMap<u16, u64>,
    pub requests_per_s: f64,
    pub tiles_per_s: f64,
    pub mb_per_s: f64,
    /// Whether the server kept up with the schedule (see [`rate_held`]); null at
    /// saturation. Merged: whether every shard held its share.
    pub rate_held: Option<bool>,
    /// Coordinated-omission corrected: from the scheduled start.
    pub latency_ms: Percentiles,
    /// From the actual send.
    pub uncorrected_latency_ms: Percentiles,
    pub histograms: Histograms,
    pub timeline: Vec<Second>,
}

/// Whether a run held its target rate: the answers came at ≥ 95 % of the scheduled
/// rate (`completed / seconds ≥ 0.95 · target_rate`) and at most 1 % of the scheduled
/// requests were still waiting to be sent when the schedule ended (`backlog ≤ 0.01 ·
/// scheduled`). The first catches a server that answers slower than asked; the second
/// a run whose sends fell behind (every connection busy) even if they caught up
/// during the final wait.
pub fn rate_held(
    target_rate: f64,
    completed: u64,
    seconds: f64,
    backlog: u64,
    scheduled: u64,
) -> bool {
    let achieved = if seconds > 0.0 {
        completed as f64 / seconds
    } else {
        0.0
    };
    achieved >= 0.95 * target_rate && backlog as f64 <= 0.01 * scheduled as f64
}

impl ReplayReport {
    /// A report of nothing yet: zero counts, empty histograms, shard `0/1`, no target.
    pub fn empty(mode: Mode, http: Http, latency_from: LatencyFrom) -> Self {
        let none = Latency::new();
        Self {
            tessera_load: REPORT_VERSION,
            mode,
            target_rate: None,
            shard: "0/1".into(),
            shards: 1,
            connections: 0,
            http,
            latency_from,
            seconds: 0.0,
            scheduled: 0,
            sent: 0,
            completed: 0,
            tiles: 0,
            bytes: 0,
            backlog: 0,
            unsent: 0,
            errors: ErrorCounts::default(),
            http_statuses: std::collections::BTreeMap::new(),
            requests_per_s: 0.0,
            tiles_per_s: 0.0,
            mb_per_s: 0.0,
            rate_held: None,
            latency_ms: Percentiles::default(),
            uncorrected_latency_ms: Percentiles::default(),
            histograms: Histograms::of(&none, &none),
            timeline: Vec::new(),
        }
    }

    /// Totals / seconds.
    pub fn set_rates(&mut self) {
        let per_s = |n: f64| {
            if self.seconds > 0.0 {
                n / self.seconds
            } else {
                0.0
            }
        };
        self.requests_per_s = per_s(self.completed as f64);
        self.tiles_per_s = per_s(self.tiles as f64);
        self.mb_per_s = per_s(self.bytes as f64 / 1e6);
    }
}

impl std::fmt::Display for ReplayReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let target = match self.target_rate {
            Some(r) => format!("at {r:.0} requests/s"),
            None => format!("at saturation on {} connections", self.connections),
        };
        let held = match self.rate_held {
            Some(true) => ", rate held",
            Some(false) => ", rate NOT held",
            None => "",
        };
        let l = &self.latency_ms;
        let u = &self.uncorrected_latency_ms;
        let from = match self.latency_from {
            LatencyFrom::Scheduled => "from the scheduled start",
            LatencyFrom::Sent => "from the send (closed loop)",
        };
        write!(
            f,
            "replay ({} mode, shard {}, HTTP/{}) {target} for {:.1} s: {} of {} requests \
             answered ({:.0}/s{held}), {} tiles ({:.0} tiles/s), {:.1} MB/s; latency {from} \
             p50 {:.2} ms, p90 {:.2}, p99 {:.2}, p99.9 {:.2}, max {:.2} (from the send: p50 \
             {:.2}, p99 {:.2}, p99.9 {:.2}); errors: ",
            self.mode.name(),
            self.shard,
            self.http.name(),
            self.seconds,
            self.completed,
            self.scheduled,
            self.requests_per_s,
            self.tiles,
            self.tiles_per_s,
            self.mb_per_s,
            l.p50,
            l.p90,
            l.p99,
            l.p999,
            l.max,
            u.p50,
            u.p99,
            u.p999,
        )?;
        if self.errors.total() == 0 {
            write!(f, "none")?;
        } else {
            let parts: Vec<String> = ErrorKind::ALL
                .iter()
                .filter(|&&k| self.errors.get(k) > 0)
                .map(|&k| {
                    let n = self.errors.get(k);
                    if k == ErrorKind::HttpStatus && !self.http_statuses.is_empty() {
                        let by: Vec<String> = self
                            .http_statuses
                            .iter()
                            .map(|(s, n)| format!("{s}: {n}"))
                            .collect();
                        format!("{k} {n} ({})", by.join(", "))
                    } else {
                        format!("{k} {n}")
                    }
                })
                .collect();
            write!(f, "{}", parts.join(", "))?;
        }
        if self.backlog > 0 {
            write!(f, "; {} not yet sent when the schedule ended", self.backlog)?;
        }
        if self.unsent > 0 {
            write!(
                f,
                "; {} never sent (the run stops at the schedule's end + --timeout)",
                self.unsent
            )?;
        }
        write!(f, ".")
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// A deterministic spread of latencies (µs), long-tailed.
    pub(in crate::loadtest) fn values(seed: u64, n: usize) -> Vec<u64> {
        let mut x = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        (0..n)
            .map(|_| {
                x = x
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                let r = (x >> 33) % 1_000_000;
                // Mostly 0.2–2 ms, a tail up to seconds.
                if r.is_multiple_of(100) {
                    10_000 + r * 3
                } else {
                    200 + r % 1800
                }
            })
            .collect()
    }

    pub(in crate::loadtest) fn latency(v: &[u64]) -> Latency {
        let mut l = Latency::new();
        for &x in v {
            l.record_micros(x);
        }
        l
    }

    pub(in crate::loadtest) fn report(
        shard: &str,
        seed: u64,
        n: usize,
        secs: usize,
    ) -> ReplayReport {
        let v = values(seed, n);
        let c = latency(&v);
        let u = latency(&v.iter().map(|x| x / 2).collect::<Vec<_>>());
        let per = n / secs;
        let timeline = (0..secs)
            .map(|s| {
                let part = &v[s * per..(s + 1) * per];
                Second {
                    scheduled: per as u64,
                    sent: per as u64,
                    completed: per as u64,
                    tiles: 16 * per as u64,
                    errors: s as u64,
                    ..Second::new(s as u64, &latency(part), &latency(&part[..per / 2]))
                }
            })
            .collect();
        let mut r = ReplayReport {
            tessera_load: REPORT_VERSION,
            mode: Mode::Rate,
            target_rate: Some(n as f64 / secs as f64),
            shard: shard.into(),
            shards: 1,
            connections: 8,
            http: Http::Http1,
            latency_from: LatencyFrom::Scheduled,
            seconds: secs as f64,
            scheduled: n as u64,
            sent: n as u64,
            completed: n as u64 - 3,
            tiles: 16 * n as u64,
            bytes: 1000 * n as u64,
            backlog: 1,
            unsent: 0,
            http_statuses: std::collections::BTreeMap::new(),
            errors: ErrorCounts {
                timeout: 3,
                corrupt: seed,
                ..ErrorCounts::default()
            },
            requests_per_s: 0.0,
            tiles_per_s: 0.0,
            mb_per_s: 0.0,
            rate_held: Some(true),
            latency_ms: c.percentiles(),
            uncorrected_latency_ms: u.percentiles(),
            histograms: Histograms::of(&c, &u),
            timeline,
        };
        r.set_rates();
        r
    }

    #[test]
    fn rate_held_needs_the_rate_and_no_backlog() {
        assert!(rate_held(100.0, 1000, 10.0, 0, 1000));
        assert!(rate_held(100.0, 950, 10.0, 10, 1000));
        assert!(!rate_held(100.0, 940, 10.0, 0, 1000));
        assert!(!rate_held(100.0, 1000, 10.0, 11, 1000));
    }

    #[test]
    fn the_summary_names_the_figures() {
        let r = report("0/1", 5, 1000, 1);
        let s = r.to_string();
        assert!(s.contains("rate mode"), "{s}");
        assert!(s.contains("rate held"), "{s}");
        assert!(s.contains(&format!("p99 {:.2}", r.latency_ms.p99)), "{s}");
        assert!(s.contains("timeout 3, corrupt 5"), "{s}");
        assert!(!s.contains('\n'));
    }
}
