//! How a replay is paced, as the command line asks for it: as recorded, a constant
//! rate (`--rate N`), ramping stages (`--ramp`) or saturation (`--rate max`); the
//! limits of a run in time and rate; and why a pacing or a schedule is refused
//! ([`ScheduleError`]).

use std::time::Duration;

/// The longest schedule a replay runs: 7 days (`--duration`, a ramp's stages, or a
/// recorded trace's last time). A bound, so that every instant of a schedule is one a
/// `Duration` and an `Instant` can hold, and a report's timeline stays small enough
/// to merge; longer soak tests are several runs.
pub const MAX_RUN: Duration = Duration::from_secs(7 * 24 * 3600);

/// The longest `--timeout`: an hour, the longest latency the report's histograms
/// hold. It also bounds a run: at most [`MAX_RUN`] of schedule and one timeout.
pub const MAX_TIMEOUT: Duration = Duration::from_secs(3600);

/// The highest rate one load process schedules, requests per second (its share of
/// `--rate` or a ramp's stage). One scheduling thread hands out one arrival every
/// microsecond at best, and one core sends far fewer; a higher rate is a typo, or
/// several processes' work (`--shard K/N`).
pub const MAX_RATE: f64 = 1e6;

/// A request rate, in requests per second: finite and above zero.
#[derive(Clone, Copy, Debug, PartialEq, PartialOrd)]
pub struct Rate(f64);

impl Rate {
    /// `None` unless `per_second` is finite and positive.
    pub fn new(per_second: f64) -> Option<Self> {
        (per_second.is_finite() && per_second > 0.0).then_some(Self(per_second))
    }

    pub fn per_second(self) -> f64 {
        self.0
    }
}

/// `--rate`: a number of requests per second (`500`, `500/s`) or `max` (saturation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RateArg {
    PerSecond(Rate),
    Max,
}

impl std::str::FromStr for RateArg {
    type Err = ScheduleError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let t = s.trim();
        if t.eq_ignore_ascii_case("max") {
            return Ok(Self::Max);
        }
        let n = t.strip_suffix("/s").unwrap_or(t);
        n.trim()
            .parse::<f64>()
            .ok()
            .and_then(Rate::new)
            .map(Self::PerSecond)
            .ok_or_else(|| ScheduleError::Rate(s.to_string()))
    }
}

/// One `--ramp` stage (k6's ramping-arrival-rate): over `duration`, the rate moves
/// linearly from where the previous stage ended to `target`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RampStage {
    duration: Duration,
    target: f64,
}

impl RampStage {
    /// `None` unless the duration is above zero and the target finite and ≥ 0.
    pub fn new(duration: Duration, target: f64) -> Option<Self> {
        (!duration.is_zero() && target.is_finite() && target >= 0.0)
            .then_some(Self { duration, target })
    }

    /// A stage as it is, without [`RampStage::new`]'s checks: a constant rate's
    /// one stage, which [`super::schedule::Schedule::new`] checks as a whole.
    pub(super) fn unchecked(duration: Duration, target: f64) -> Self {
        Self { duration, target }
    }

    pub fn duration(self) -> Duration {
        self.duration
    }

    /// Requests per second at the end of the stage.
    pub fn target(self) -> f64 {
        self.target
    }
}

/// `--ramp d1:r1,d2:r2,…`: at least one stage.
#[derive(Clone, Debug, PartialEq)]
pub struct RampStages(Vec<RampStage>);

impl RampStages {
    pub fn stages(&self) -> &[RampStage] {
        &self.0
    }

    /// The stages with every target multiplied by `factor` (a shard's share).
    pub(super) fn scaled(&self, factor: f64) -> Vec<RampStage> {
        self.0
            .iter()
            .map(|s| RampStage {
                duration: s.duration,
                target: s.target * factor,
            })
            .collect()
    }
}

/// Why a `--rate`, `--ramp` or schedule was refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ScheduleError {
    #[error("rate {0:?} is not a number of requests per second above 0 (e.g. 500) or max")]
    Rate(String),
    #[error("ramp {0:?} has no stages (expected e.g. 10s:100,20s:400)")]
    EmptyRamp(String),
    #[error("ramp stage {stage:?} is not DURATION:RATE (e.g. 10s:100)")]
    StageSyntax { stage: String },
    #[error(
        "ramp stage {stage:?}: duration {duration:?} is not a duration above 0 (e.g. 10s, 2m, 500ms)"
    )]
    StageDuration { stage: String, duration: String },
    #[error("ramp stage {stage:?}: rate {rate:?} is not a number of requests per second ≥ 0")]
    StageRate { stage: String, rate: String },
    #[error("the trace has no requests to replay (in this shard)")]
    NoRequests,
    #[error("the schedule sends no request: its rate is 0 throughout, or its duration too short")]
    Empty,
    #[error(
        "a rate of {rate:?} requests/s for this process is above the {max} requests/s one load process can schedule; use a lower rate, or split it over processes with --shard K/N",
        max = MAX_RATE
    )]
    RateTooHigh { rate: f64 },
    #[error(
        "the schedule lasts {seconds:?} s, longer than the {max} s (7 days) a replay runs",
        max = MAX_RUN.as_secs()
    )]
    TooLong { seconds: f64 },
    #[error(
        "request {number} of the replayed requests is at {t_ms:?} ms: not a time from 0 to {max} ms (7 days)",
        number = .index + 1,
        max = MAX_RUN.as_secs() * 1000
    )]
    Time { index: usize, t_ms: f64 },
}

/// Parses the CLI's durations (`--duration`, `--timeout`) and ramp stages: a bare
/// number is seconds (`2.5`); anything else is read by `humantime` (`30s`, `1500ms`,
/// `2m`, `1h 30m`, `1m30s`). `None` unless positive and under 10⁹ s.
pub fn parse_duration(s: &str) -> Option<Duration> {
    let t = s.trim();
    let d = match t.parse::<f64>() {
        Ok(secs) if secs.is_finite() && secs > 0.0 && secs < 1e9 => Duration::from_secs_f64(secs),
        Ok(_) => return None,
        Err(_) => humantime::parse_duration(t).ok()?,
    };
    (!d.is_zero() && d.as_secs_f64() < 1e9).then_some(d)
}

impl std::str::FromStr for RampStages {
    type Err = ScheduleError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let mut stages = Vec::new();
        for stage in s.split(',').map(str::trim).filter(|t| !t.is_empty()) {
            let (d, r) = stage
                .split_once(':')
                .ok_or_else(|| ScheduleError::StageSyntax {
                    stage: stage.to_string(),
                })?;
            let duration = parse_duration(d).ok_or_else(|| ScheduleError::StageDuration {
                stage: stage.to_string(),
                duration: d.to_string(),
            })?;
            let bad_rate = || ScheduleError::StageRate {
                stage: stage.to_string(),
                rate: r.to_string(),
            };
            let r = r.trim();
            let target = r
                .strip_suffix("/s")
                .unwrap_or(r)
                .trim()
                .parse::<f64>()
                .map_err(|_| bad_rate())?;
            stages.push(RampStage::new(duration, target).ok_or_else(bad_rate)?);
        }
        if stages.is_empty() {
            return Err(ScheduleError::EmptyRamp(s.to_string()));
        }
        Ok(Self(stages))
    }
}

/// How a replay paces its requests.
#[derive(Clone, Debug, PartialEq)]
pub enum Pacing {
    /// Every request of the trace (its shard) once, at its recorded time.
    Recorded,
    /// `rate` requests per second (all shards together) for `duration`, taking the
    /// trace's requests in order, cycling.
    Constant { rate: Rate, duration: Duration },
    /// Stages starting from `start` requests per second (all shards together; 0 without
    /// `--rate`), taking the trace's requests in order, cycling.
    Ramp { start: f64, stages: RampStages },
    /// A closed loop: each connection sends the next request as soon as its last one
    /// finished, for `duration`.
    Saturation { duration: Duration },
}

#[cfg(test)]
mod tests {
    use super::*;

    fn secs(s: f64) -> Duration {
        Duration::from_secs_f64(s)
    }

    #[test]
    fn rate_parses_numbers_and_max() {
        assert_eq!("max".parse::<RateArg>().unwrap(), RateArg::Max);
        assert_eq!(
            "250/s".parse::<RateArg>().unwrap(),
            RateArg::PerSecond(Rate::new(250.0).unwrap())
        );
        for bad in ["0", "-3", "fast", "NaN", "inf", ""] {
            let e = bad.parse::<RateArg>().unwrap_err();
            assert_eq!(e, ScheduleError::Rate(bad.to_string()));
            assert!(e.to_string().contains("max"));
        }
    }

    #[test]
    fn durations_are_bare_seconds_or_humantime() {
        let d = |s: &str| parse_duration(s);
        assert_eq!(d("30s"), Some(secs(30.0)));
        assert_eq!(d(" 1500ms "), Some(secs(1.5)));
        assert_eq!(d("2m"), Some(secs(120.0)));
        assert_eq!(d("1m30s"), Some(secs(90.0)));
        assert_eq!(d("1h 30m"), Some(secs(5400.0)));
        assert_eq!(d("2.5"), Some(secs(2.5)));
        for bad in [
            "",
            "0",
            "0s",
            "-3",
            "soon",
            "NaN",
            "inf",
            "1e10",
            "40000 years",
        ] {
            assert_eq!(d(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn the_ramp_parser_names_the_stage_and_the_problem() {
        let r: RampStages = " 10s:100, 500ms:0 ,2m:40/s".parse().unwrap();
        assert_eq!(
            r.stages(),
            &[
                RampStage::new(secs(10.0), 100.0).unwrap(),
                RampStage::new(secs(0.5), 0.0).unwrap(),
                RampStage::new(secs(120.0), 40.0).unwrap(),
            ]
        );
        let err = |s: &str| s.parse::<RampStages>().unwrap_err();
        assert_eq!(err(""), ScheduleError::EmptyRamp(String::new()));
        assert_eq!(err(" , "), ScheduleError::EmptyRamp(" , ".into()));
        assert_eq!(
            err("10s:100,20s"),
            ScheduleError::StageSyntax {
                stage: "20s".into()
            }
        );
        assert_eq!(
            err("0s:100"),
            ScheduleError::StageDuration {
                stage: "0s:100".into(),
                duration: "0s".into()
            }
        );
        assert_eq!(
            err("soon:100"),
            ScheduleError::StageDuration {
                stage: "soon:100".into(),
                duration: "soon".into()
            }
        );
        assert_eq!(
            err("10s:-1"),
            ScheduleError::StageRate {
                stage: "10s:-1".into(),
                rate: "-1".into()
            }
        );
        assert_eq!(
            err("10s:lots"),
            ScheduleError::StageRate {
                stage: "10s:lots".into(),
                rate: "lots".into()
            }
        );
        assert!(err("10s:x").to_string().contains("10s:x"));
    }
}
