//! When a replay sends each request (DECISIONS.md "Load testing: replay"): the arrival
//! schedules of `tessera load --replay` — as recorded, at a constant rate (`--rate N`),
//! in ramping stages (`--ramp`) — and saturation (`--rate max`), which has no schedule.
//!
//! A schedule is a list of instants measured from the start of the run, each with the
//! trace request to send then. The instants are computed from the start (`k / rate`,
//! or the inverse of the ramp's cumulative count), never by adding intervals, so a long
//! run does not drift. Latency is measured from these instants (the open model: see
//! `replay`).

use super::pacing::{MAX_RATE, MAX_RUN, Pacing, RampStage, ScheduleError};
use std::time::Duration;

/// A request to send and when, measured from the start of the run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Arrival {
    pub at: Duration,
    /// Index into the replayed requests.
    pub request: usize,
}

/// One piece of a piecewise-linear rate: from `r0` to `r1` requests/s over `d` seconds,
/// starting at `t0` seconds with `n0` arrivals before it (the cumulative count, real).
#[derive(Clone, Copy, Debug)]
struct Segment {
    t0: f64,
    d: f64,
    r0: f64,
    r1: f64,
    n0: f64,
}

impl Segment {
    fn count(&self) -> f64 {
        (self.r0 + self.r1) * 0.5 * self.d
    }

    /// The time, within the segment, at which the cumulative count reaches `n0 + x`:
    /// the root of `r0·τ + (r1 − r0)·τ²/(2d) = x` in `[0, d]`, in the form
    /// `2x / (r0 + √(r0² + 2(r1 − r0)x/d))`, which is stable when `r1 = r0` (then
    /// `x/r0`) and when `r0 = 0`.
    fn time_of(&self, x: f64) -> f64 {
        let a2 = 2.0 * (self.r1 - self.r0) / self.d;
        let disc = (self.r0 * self.r0 + a2 * x).max(0.0);
        let den = self.r0 + disc.sqrt();
        if den <= 0.0 {
            return 0.0;
        }
        (2.0 * x / den).clamp(0.0, self.d)
    }
}

/// An arrival schedule over `requests` trace requests (see [`Pacing`]).
#[derive(Clone, Debug)]
pub struct Schedule {
    kind: Kind,
    requests: usize,
    scheduled: u64,
    span: Duration,
}

#[derive(Clone, Debug)]
enum Kind {
    /// Offsets in seconds, one per request.
    Recorded(Vec<f64>),
    /// Piecewise-linear rate (a constant rate is one flat segment).
    Segments(Vec<Segment>),
}

impl Schedule {
    /// The schedule of one shard out of `shards`: `times_ms` are the shard's requests'
    /// recorded times (non-decreasing, ms after the recording started); rates are the
    /// total of all shards, so this shard runs `1/shards` of them. `None` for
    /// [`Pacing::Saturation`], which has no schedule.
    pub fn new(
        pacing: &Pacing,
        times_ms: &[f64],
        shards: u32,
    ) -> Result<Option<Self>, ScheduleError> {
        if times_ms.is_empty() {
            return Err(ScheduleError::NoRequests);
        }
        let share = 1.0 / f64::from(shards.max(1));
        let segments = |start: f64, stages: &[RampStage]| {
            let mut segs = Vec::with_capacity(stages.len());
            let (mut t0, mut n0, mut r0) = (0.0, 0.0, start);
            for s in stages {
                let seg = Segment {
                    t0,
                    d: s.duration().as_secs_f64(),
                    r0,
                    r1: s.target(),
                    n0,
                };
                t0 += seg.d;
                n0 += seg.count();
                r0 = s.target();
                segs.push(seg);
            }
            segs
        };
        let kind = match pacing {
            Pacing::Saturation { .. } => return Ok(None),
            Pacing::Recorded => {
                // `Trace::read` checks its times; these may come from elsewhere, and
                // each becomes a `Duration`, which panics on what it cannot hold.
                let max_ms = MAX_RUN.as_secs_f64() * 1e3;
                if let Some((index, &t_ms)) = times_ms
                    .iter()
                    .enumerate()
                    .find(|(_, t)| !(0.0..=max_ms).contains(*t))
                {
                    return Err(ScheduleError::Time { index, t_ms });
                }
                Kind::Recorded(times_ms.iter().map(|t| t / 1e3).collect())
            }
            Pacing::Constant { rate, duration } => {
                let r = rate.per_second() * share;
                let stage = RampStage::unchecked(*duration, r);
                Kind::Segments(segments(r, &[stage]))
            }
            Pacing::Ramp { start, stages } => {
                Kind::Segments(segments(start * share, &stages.scaled(share)))
            }
        };
        let (scheduled, span) = match &kind {
            Kind::Recorded(t) => (t.len() as u64, secs(t.iter().copied().fold(0.0, f64::max))),
            Kind::Segments(segs) => {
                let Some(last) = segs.last() else {
                    return Err(ScheduleError::Empty);
                };
                if let Some(rate) = segs
                    .iter()
                    .flat_map(|s| [s.r0, s.r1])
                    .find(|r| r.is_nan() || *r > MAX_RATE)
                {
                    return Err(ScheduleError::RateTooHigh { rate });
                }
                let seconds = last.t0 + last.d;
                if seconds.is_nan() || seconds > MAX_RUN.as_secs_f64() {
                    return Err(ScheduleError::TooLong { seconds });
                }
                let total = last.n0 + last.count();
                // Arrival k is sent when the cumulative count reaches k (k = 0, 1, …),
                // so those with k < total fall inside the schedule. The small epsilon
                // keeps `rate × duration` = 1000.0000000002 from scheduling a 1001st.
                // At most MAX_RATE × MAX_RUN (6·10¹¹): a u64 holds it exactly.
                let n = (total - 1e-9).ceil().max(0.0) as u64;
                (n, secs(seconds))
            }
        };
        if scheduled == 0 {
            return Err(ScheduleError::Empty);
        }
        Ok(Some(Self {
            kind,
            requests: times_ms.len(),
            scheduled,
            span,
        }))
    }

    /// How many requests the schedule sends.
    pub fn scheduled(&self) -> u64 {
        self.scheduled
    }

    /// From the start to the end of the schedule (to the last recorded request for a
    /// recorded one, the sum of the stages otherwise).
    pub fn span(&self) -> Duration {
        self.span
    }

    /// The mean scheduled rate, requests per second (this shard's).
    pub fn mean_rate(&self) -> f64 {
        let s = self.span.as_secs_f64();
        if s > 0.0 {
            self.scheduled as f64 / s
        } else {
            self.scheduled as f64
        }
    }

    /// The `k`-th arrival (`k < scheduled()`).
    pub fn arrival(&self, k: u64) -> Arrival {
        match &self.kind {
            Kind::Recorded(t) => Arrival {
                at: secs(t.get(k as usize).copied().unwrap_or(0.0)),
                request: k as usize,
            },
            Kind::Segments(segs) => {
                let n = k as f64;
                // The segment in which the cumulative count reaches n.
                let i = segs.partition_point(|s| s.n0 + s.count() <= n);
                let s = segs[i.min(segs.len() - 1)];
                let t = s.t0 + s.time_of(n - s.n0);
                Arrival {
                    at: secs(t),
                    request: (k % self.requests as u64) as usize,
                }
            }
        }
    }

    /// How many arrivals are scheduled before `t` (at instants `< t`), computed from
    /// the schedule without listing its arrivals: a run that stops at its deadline
    /// still reports every second's scheduled requests, however many it never got to.
    pub fn scheduled_before(&self, t: Duration) -> u64 {
        match &self.kind {
            Kind::Recorded(times) => {
                let t = t.as_secs_f64();
                times.partition_point(|&x| x < t) as u64
            }
            Kind::Segments(segs) => {
                let t = t.as_secs_f64();
                // The segment holding t (the last one past the end).
                let i = segs.partition_point(|s| s.t0 + s.d <= t);
                let Some(s) = segs.get(i) else {
                    return self.scheduled;
                };
                let tau = (t - s.t0).clamp(0.0, s.d);
                // The cumulative count N(t); arrival k is at N = k, so those before t
                // are k < N(t): ⌈N(t)⌉ of them (with `new`'s epsilon).
                let n = s.n0 + s.r0 * tau + (s.r1 - s.r0) * tau * tau / (2.0 * s.d);
                ((n - 1e-9).ceil().max(0.0) as u64).min(self.scheduled)
            }
        }
    }

    /// The requests scheduled in each second of the run (second `s` holds the
    /// arrivals at instants in `[s, s + 1)`), for the report's timeline.
    pub fn per_second(&self) -> Vec<u64> {
        let seconds = self.span.as_secs() + 1;
        (0..seconds)
            .map(|s| {
                self.scheduled_before(Duration::from_secs(s + 1))
                    - self.scheduled_before(Duration::from_secs(s))
            })
            .collect()
    }

    /// Every arrival, in order.
    pub fn arrivals(&self) -> impl Iterator<Item = Arrival> + '_ {
        (0..self.scheduled).map(|k| self.arrival(k))
    }
}

/// Seconds as a `Duration`: the schedule's instants, which [`Schedule::new`] has
/// checked lie within [`MAX_RUN`]; anything else (never reached) is clamped rather
/// than a panic.
fn secs(s: f64) -> Duration {
    Duration::try_from_secs_f64(s.clamp(0.0, MAX_RUN.as_secs_f64())).unwrap_or(MAX_RUN)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::loadtest::pacing::Rate;

    fn secs(s: f64) -> Duration {
        Duration::from_secs_f64(s)
    }

    fn close(a: Duration, b: f64) -> bool {
        (a.as_secs_f64() - b).abs() < 1e-6
    }

    #[test]
    fn a_constant_rate_sends_k_over_rate_cycling_through_the_trace() {
        let pacing = Pacing::Constant {
            rate: Rate::new(100.0).unwrap(),
            duration: secs(2.0),
        };
        let s = Schedule::new(&pacing, &[0.0, 5.0, 7.0], 1)
            .unwrap()
            .unwrap();
        assert_eq!(s.scheduled(), 200);
        assert_eq!(s.span(), secs(2.0));
        let a: Vec<Arrival> = s.arrivals().collect();
        assert_eq!(a.len(), 200);
        for (k, x) in a.iter().enumerate() {
            assert!(close(x.at, k as f64 / 100.0), "{k}: {:?}", x.at);
            assert_eq!(x.request, k % 3);
        }
        // No drift: the 200th instant is exactly 1.99 s, not a sum of 199 intervals.
        assert_eq!(a[199].at, secs(1.99));
    }

    #[test]
    fn shards_share_the_total_rate() {
        let pacing = Pacing::Constant {
            rate: Rate::new(300.0).unwrap(),
            duration: secs(1.0),
        };
        let s = Schedule::new(&pacing, &[0.0], 3).unwrap().unwrap();
        assert_eq!(s.scheduled(), 100);
        assert!(close(s.arrival(1).at, 0.01));
        assert!((s.mean_rate() - 100.0).abs() < 1e-9);
    }

    #[test]
    fn a_fractional_count_rounds_up_and_stays_inside_the_span() {
        let pacing = Pacing::Constant {
            rate: Rate::new(2.5).unwrap(),
            duration: secs(1.0),
        };
        let s = Schedule::new(&pacing, &[0.0], 1).unwrap().unwrap();
        // Arrivals at 0, 0.4 and 0.8 s; the next (1.2 s) is past the end.
        assert_eq!(s.scheduled(), 3);
        assert!(close(s.arrival(2).at, 0.8));
    }

    #[test]
    fn a_ramp_interpolates_the_rate_linearly() {
        // 0 → 100/s over 10 s: N(t) = 5t², so arrival k is at √(k/5); then 100/s flat.
        let pacing = Pacing::Ramp {
            start: 0.0,
            stages: "10s:100,5s:100".parse().unwrap(),
        };
        let s = Schedule::new(&pacing, &[0.0, 1.0], 1).unwrap().unwrap();
        assert_eq!(s.scheduled(), 500 + 500);
        assert_eq!(s.span(), secs(15.0));
        for k in [0u64, 1, 7, 20, 125, 499] {
            let want = (k as f64 / 5.0).sqrt();
            assert!(
                close(s.arrival(k).at, want),
                "{k}: {:?} vs {want}",
                s.arrival(k).at
            );
        }
        for k in [500u64, 501, 999] {
            let want = 10.0 + (k - 500) as f64 / 100.0;
            assert!(close(s.arrival(k).at, want), "{k}");
        }
        assert_eq!(s.arrival(7).request, 1);
        // Arrivals are in order and ever closer together as the rate climbs.
        let a: Vec<f64> = s.arrivals().map(|a| a.at.as_secs_f64()).collect();
        assert!(a.windows(2).all(|w| w[1] >= w[0]));
        assert!(a[2] - a[1] > a[400] - a[399]);
    }

    #[test]
    fn a_ramp_down_from_the_start_rate_and_a_stage_at_zero() {
        // 200/s → 0 over 2 s (N(t) = 200t − 50t², 200 arrivals), then 0 for 3 s (none).
        let pacing = Pacing::Ramp {
            start: 200.0,
            stages: "2s:0,3s:0".parse().unwrap(),
        };
        let s = Schedule::new(&pacing, &[0.0], 2).unwrap().unwrap();
        // Two shards: 100/s → 0, 100 arrivals; N(t) = 100t − 25t².
        assert_eq!(s.scheduled(), 100);
        for k in [1u64, 50, 99] {
            let n = k as f64;
            let want = (100.0 - (100.0f64 * 100.0 - 100.0 * n).sqrt()) / 50.0;
            assert!(close(s.arrival(k).at, want), "{k}");
        }
        assert_eq!(s.span(), secs(5.0));
    }

    #[test]
    fn recorded_instants_are_the_trace_times() {
        let s = Schedule::new(&Pacing::Recorded, &[0.0, 12.5, 12.5, 3000.0], 4)
            .unwrap()
            .unwrap();
        assert_eq!(s.scheduled(), 4);
        let a: Vec<Arrival> = s.arrivals().collect();
        assert_eq!(a[1].at, secs(0.0125));
        assert_eq!(a[2].request, 2);
        assert_eq!(s.span(), secs(3.0));
    }

    #[test]
    fn saturation_has_no_schedule_and_empty_ones_are_errors() {
        let sat = Pacing::Saturation {
            duration: secs(1.0),
        };
        assert!(Schedule::new(&sat, &[0.0], 1).unwrap().is_none());
        assert_eq!(
            Schedule::new(&Pacing::Recorded, &[], 1).unwrap_err(),
            ScheduleError::NoRequests
        );
        let zero = Pacing::Ramp {
            start: 0.0,
            stages: "5s:0".parse().unwrap(),
        };
        assert_eq!(
            Schedule::new(&zero, &[0.0], 1).unwrap_err(),
            ScheduleError::Empty
        );
    }

    #[test]
    fn times_no_duration_can_hold_are_errors_not_panics() {
        for (t, index) in [
            (vec![0.0, 1e300], 1),
            (vec![-1.0], 0),
            (vec![0.0, 5.0, f64::NAN], 2),
            (vec![f64::INFINITY], 0),
        ] {
            match Schedule::new(&Pacing::Recorded, &t, 1) {
                Err(ScheduleError::Time { index: i, .. }) => assert_eq!(i, index, "{t:?}"),
                other => panic!("{t:?}: {other:?}"),
            }
        }
        let e = Schedule::new(&Pacing::Recorded, &[1e300], 1).unwrap_err();
        assert!(e.to_string().contains("7 days"), "{e}");
        // The last instant allowed is a schedule of its own.
        let max_ms = MAX_RUN.as_secs_f64() * 1e3;
        let s = Schedule::new(&Pacing::Recorded, &[0.0, max_ms], 1)
            .unwrap()
            .unwrap();
        assert_eq!(s.span(), MAX_RUN);
        assert_eq!(s.arrival(1).at, MAX_RUN);
    }

    #[test]
    fn rates_and_spans_one_process_cannot_hold_are_refused() {
        let constant = |rate: f64, d: f64| Pacing::Constant {
            rate: Rate::new(rate).unwrap(),
            duration: secs(d),
        };
        // --rate 1e18 --duration 1s once ran for 25 s and grew to 2.9 GB.
        assert_eq!(
            Schedule::new(&constant(1e18, 1.0), &[0.0], 1).unwrap_err(),
            ScheduleError::RateTooHigh { rate: 1e18 }
        );
        let e = Schedule::new(&constant(1e18, 1.0), &[0.0], 1).unwrap_err();
        assert!(e.to_string().contains("--shard"), "{e}");
        // The limit is per process: 4 shards share 4 × MAX_RATE.
        let s = Schedule::new(&constant(4.0 * MAX_RATE, 1.0), &[0.0], 4)
            .unwrap()
            .unwrap();
        assert_eq!(s.scheduled(), 1_000_000);
        assert!(matches!(
            Schedule::new(&constant(4.0 * MAX_RATE, 1.0), &[0.0], 3),
            Err(ScheduleError::RateTooHigh { .. })
        ));
        // A ramp's start and every stage's target.
        let ramp = |start: f64, stages: &str| Pacing::Ramp {
            start,
            stages: stages.parse().unwrap(),
        };
        assert!(matches!(
            Schedule::new(&ramp(0.0, "1s:10,1s:2e6"), &[0.0], 1),
            Err(ScheduleError::RateTooHigh { rate }) if rate == 2e6
        ));
        assert!(matches!(
            Schedule::new(&ramp(5e6, "1s:10"), &[0.0], 1),
            Err(ScheduleError::RateTooHigh { rate }) if rate == 5e6
        ));
        // Longer than a replay runs.
        let week = MAX_RUN.as_secs_f64();
        assert!(Schedule::new(&constant(1.0, week), &[0.0], 1).is_ok());
        assert_eq!(
            Schedule::new(&constant(1.0, 2.0 * week), &[0.0], 1).unwrap_err(),
            ScheduleError::TooLong {
                seconds: 2.0 * week
            }
        );
        assert!(matches!(
            Schedule::new(&ramp(1.0, "400000s:1,400000s:1"), &[0.0], 1),
            Err(ScheduleError::TooLong { .. })
        ));
    }

    #[test]
    fn a_huge_schedule_is_lazy() {
        // A million requests a second for a week: 6·10¹¹ arrivals, none of them in
        // memory; any one of them is computed when asked for.
        let pacing = Pacing::Constant {
            rate: Rate::new(MAX_RATE).unwrap(),
            duration: MAX_RUN,
        };
        let s = Schedule::new(&pacing, &[0.0, 1.0, 2.0], 1)
            .unwrap()
            .unwrap();
        assert_eq!(s.scheduled(), 604_800_000_000);
        let last = s.arrival(s.scheduled() - 1);
        assert!(
            last.at < MAX_RUN && last.at + secs(1e-5) > MAX_RUN,
            "{:?}",
            last.at
        );
        assert_eq!(last.request, ((s.scheduled() - 1) % 3) as usize);
    }

    #[test]
    fn per_second_counts_agree_with_the_arrivals() {
        let schedules = [
            Schedule::new(
                &Pacing::Constant {
                    rate: Rate::new(100.0).unwrap(),
                    duration: secs(2.0),
                },
                &[0.0, 5.0],
                1,
            ),
            Schedule::new(
                &Pacing::Constant {
                    rate: Rate::new(2.5).unwrap(),
                    duration: secs(3.3),
                },
                &[0.0],
                1,
            ),
            Schedule::new(
                &Pacing::Ramp {
                    start: 0.0,
                    stages: "10s:100,5s:100,3s:0".parse().unwrap(),
                },
                &[0.0],
                3,
            ),
            Schedule::new(
                &Pacing::Recorded,
                &[0.0, 12.5, 999.9, 1000.0, 1000.0, 3000.0],
                1,
            ),
        ];
        for s in schedules {
            let s = s.unwrap().unwrap();
            let mut want = vec![0u64; s.span().as_secs() as usize + 1];
            for a in s.arrivals() {
                want[a.at.as_secs() as usize] += 1;
            }
            assert_eq!(s.per_second(), want, "{s:?}");
            assert_eq!(s.per_second().iter().sum::<u64>(), s.scheduled());
            assert_eq!(s.scheduled_before(Duration::ZERO), 0);
            assert_eq!(s.scheduled_before(s.span() + secs(1.0)), s.scheduled());
        }
    }
}
