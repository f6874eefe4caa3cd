//! The replay's tally: answers, tiles, bytes, errors by kind and HTTP status, and
//! the latency histograms (from the scheduled instant and from the send), over the
//! run and per second of it.

use crate::loadtest::check::{ErrorKind, Outcome};
use crate::loadtest::replay_report::{ErrorCounts, Latency, Second};
use std::time::Duration;

/// The histograms and counts, behind one lock (uncontended on one thread).
#[derive(Debug)]
pub(super) struct Tally {
    /// Set when the run ends: answers arriving later are not counted.
    pub(super) closed: bool,
    /// Requests that finished (answered or failed).
    pub(super) finished: u64,
    pub(super) completed: u64,
    pub(super) tiles: u64,
    pub(super) bytes: u64,
    pub(super) errors: ErrorCounts,
    /// The `http_status` errors by status.
    pub(super) statuses: std::collections::BTreeMap<u16, u64>,
    pub(super) corrected: Latency,
    pub(super) uncorrected: Latency,
    /// Finished seconds.
    pub(super) seconds: Vec<Second>,
    /// The second being filled, its histograms and counts.
    pub(super) current: u64,
    pub(super) cur_corrected: Latency,
    pub(super) cur_uncorrected: Latency,
    pub(super) cur: Second,
}

impl Tally {
    pub(super) fn new() -> Self {
        Self {
            closed: false,
            finished: 0,
            completed: 0,
            tiles: 0,
            bytes: 0,
            errors: ErrorCounts::default(),
            statuses: std::collections::BTreeMap::new(),
            corrected: Latency::new(),
            uncorrected: Latency::new(),
            seconds: Vec::new(),
            current: 0,
            cur_corrected: Latency::new(),
            cur_uncorrected: Latency::new(),
            cur: Second::default(),
        }
    }

    /// Closes the seconds before `second`.
    pub(super) fn roll_to(&mut self, second: u64) {
        while self.current < second {
            let done = Second {
                completed: self.cur.completed,
                tiles: self.cur.tiles,
                errors: self.cur.errors,
                ..Second::new(self.current, &self.cur_corrected, &self.cur_uncorrected)
            };
            self.seconds.push(done);
            self.cur = Second::default();
            self.cur_corrected.clear();
            self.cur_uncorrected.clear();
            self.current += 1;
        }
    }

    /// Counts a finished request: `status` is the answer's, if one came.
    pub(super) fn record(
        &mut self,
        out: &Outcome,
        status: Option<u16>,
        second: u64,
        corrected: Duration,
        uncorrected: Duration,
    ) {
        if self.closed {
            return;
        }
        self.roll_to(second);
        self.finished += 1;
        if out.error.is_none_or(ErrorKind::answered) {
            self.completed += 1;
            self.tiles += u64::from(out.tiles);
            self.bytes += out.bytes;
            self.corrected.record(corrected);
            self.uncorrected.record(uncorrected);
            self.cur_corrected.record(corrected);
            self.cur_uncorrected.record(uncorrected);
            self.cur.completed += 1;
            self.cur.tiles += u64::from(out.tiles);
        }
        if let Some(kind) = out.error {
            self.errors.add(kind, 1);
            self.cur.errors += 1;
            if let (ErrorKind::HttpStatus, Some(status)) = (kind, status) {
                *self.statuses.entry(status).or_insert(0) += 1;
            }
        }
    }
}
