//! The replay engine of `tessera load --replay` (DECISIONS.md "Load testing: replay"):
//! sends a trace's requests on an arrival schedule, checks each answer as it streams in,
//! and reports latency in HDR histograms.
//!
//! **The open model.** Each request starts at its scheduled instant (an absolute
//! schedule computed from the start, see `schedule`), whether or not earlier requests
//! have finished. At most `--connections` requests are in flight on HTTP/1.1 (one per
//! keep-alive connection); when all are busy, the next request waits for one, and so
//! do those scheduled after it. Latency is recorded twice: from the *scheduled*
//! instant (corrected for coordinated omission, as wrk2 does: the wait for a
//! connection is the server's fault when it is slow) and from the actual send
//! (uncorrected, what a closed-loop tool would report). The instants are kept by a
//! thread that sleeps until each (good to tens of microseconds) and hands it to the
//! runtime; tokio's own timer, 1 ms and rounding up, would have added up to a
//! millisecond to every corrected latency.
//!
//! **Cheap per request**, so that one core drives the server as hard as `wrk` does: no
//! selection and no record decoding, only the shared frame scanner's checksum
//! verification; request URLs are parsed once up front; one small task per request;
//! a current-thread runtime unless `threads` > 1.
//!
//! **Saturation** (`--rate max`) is a closed loop instead: each of `--connections`
//! workers sends the next request as soon as its last one finished, for the duration;
//! latency is then from the send (both histograms are the same).
//!
//! The engine's parts: [`ReplayOptions`] (`options`), the requests and connections
//! the loops share and one request's send and check (`sender`), the tally of
//! answers and latencies (`tally`), the open and closed loops (`loops`), and why
//! a replay cannot run ([`ReplayError`], `error`).

mod error;
mod loops;
mod options;
mod sender;
mod tally;

pub use error::ReplayError;
pub use options::{ReplayOptions, STREAMS_PER_CONNECTION};

use options::MAX_URL_BYTES;

use super::check::ErrorKind;
use super::connections::{check_connections, open_file_limit};
use super::pacing::{MAX_RUN, MAX_TIMEOUT, Pacing};
use super::replay_report::{
    Histograms, Http, Latency, LatencyFrom, Mode, ReplayReport, Second, rate_held,
};
use super::schedule::Schedule;
use super::trace::RequestKind;
use loops::{closed_loop, open_loop, progress_line};
use sender::{Prepared, Shared, clients};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering::Relaxed};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tally::Tally;
use tokio::time::Instant;

/// Replays `opts.trace` (its shard) and reports. Blocking: it runs its own tokio
/// runtime, so call it from a plain thread (in async code, `spawn_blocking`).
pub fn replay(opts: &ReplayOptions) -> Result<ReplayReport, ReplayError> {
    if opts.connections < 1 {
        return Err(ReplayError::NoConnections);
    }
    check_connections(opts.connections, open_file_limit())?;
    if opts.threads < 1 {
        return Err(ReplayError::NoThreads);
    }
    if opts.timeout.is_zero() {
        return Err(ReplayError::ZeroTimeout);
    }
    if opts.timeout > MAX_TIMEOUT {
        return Err(ReplayError::Timeout {
            timeout: opts.timeout,
        });
    }
    if let Pacing::Saturation { duration } = opts.pacing
        && duration > MAX_RUN
    {
        return Err(ReplayError::Duration { duration });
    }
    let trace = opts.trace.shard(opts.shard);
    let base = opts
        .server
        .as_deref()
        .unwrap_or(&trace.header.server)
        .trim_end_matches('/')
        .to_string();
    let requests = trace
        .requests
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let url = format!("{base}{}", r.target);
            let url = reqwest::Url::parse(&url).map_err(|source| ReplayError::Url {
                number: i + 1,
                url: url.clone(),
                source,
            })?;
            // A longer one was counted as a `connect` error per request: the client
            // refuses to send it, so no server ever answers it (not even 414).
            if url.as_str().len() > MAX_URL_BYTES {
                return Err(ReplayError::UrlTooLong {
                    number: i + 1,
                    start: url.as_str().chars().take(60).collect(),
                    len: url.as_str().len(),
                });
            }
            Ok(Prepared {
                url,
                expect: r.expect.clone(),
                frames: r.kind.is_frame_stream(),
                one_tile: r.kind == RequestKind::Tile
                    && r.expect.as_ref().is_some_and(|e| e.status == 200),
            })
        })
        .collect::<Result<Vec<_>, ReplayError>>()?;
    let times: Vec<f64> = trace.requests.iter().map(|r| r.t_ms).collect();
    let schedule = Schedule::new(&opts.pacing, &times, opts.shard.count()).map_err(|source| {
        ReplayError::Schedule {
            shard: opts.shard,
            source,
        }
    })?;
    let clients = clients(opts, &base)?;
    let rt = if opts.threads == 1 {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()?
    } else {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(opts.threads)
            .enable_all()
            .build()?
    };
    let report = rt.block_on(run(opts, requests, clients, schedule));
    // Requests still in flight (counted as timeouts) are dropped with the runtime.
    rt.shutdown_background();
    report
}

async fn run(
    opts: &ReplayOptions,
    requests: Vec<Prepared>,
    clients: Vec<reqwest::Client>,
    schedule: Option<Schedule>,
) -> Result<ReplayReport, ReplayError> {
    let shared = Arc::new(Shared {
        requests,
        idle: (!opts.http2).then(|| Mutex::new((0..clients.len()).collect())),
        clients,
        next_client: AtomicUsize::new(0),
        start: Instant::now(),
        sent: AtomicU64::new(0),
        completed: AtomicU64::new(0),
        errors: AtomicU64::new(0),
        tiles: AtomicU64::new(0),
        tally: Mutex::new(Tally::new()),
    });
    let progress = opts
        .progress
        .then(|| tokio::spawn(progress_line(shared.clone())));
    let (scheduled_per_s, sent_per_s, backlog) = if let Some(s) = &schedule {
        let (sent_per_s, backlog) = open_loop(opts, &shared, s).await;
        (s.per_second(), sent_per_s, backlog)
    } else {
        let Pacing::Saturation { duration } = opts.pacing else {
            unreachable!("only saturation has no schedule")
        };
        closed_loop(opts, &shared, duration).await
    };
    if let Some(p) = progress {
        p.abort();
        if shared.start.elapsed() >= Duration::from_secs(1)
            && std::io::IsTerminal::is_terminal(&std::io::stderr())
        {
            // End the progress line.
            crate::output::progress('\n');
        }
    }
    let end = Instant::now();
    let seconds = (end - shared.start).as_secs_f64();
    let mut r = {
        let mut rec = shared.tally.lock().expect("tally lock");
        rec.closed = true;
        // Sent but never finished: the wait for them ran out.
        let unfinished = shared.sent.load(Relaxed).saturating_sub(rec.finished);
        rec.errors.add(ErrorKind::Timeout, unfinished);
        let last = seconds.ceil() as u64;
        // Close the second in progress too.
        let current = rec.current;
        rec.roll_to(last.max(current + 1));
        let mut timeline = std::mem::take(&mut rec.seconds);
        let len = timeline
            .len()
            .max(scheduled_per_s.len())
            .max(sent_per_s.len());
        while timeline.len() < len {
            let s = timeline.len() as u64;
            timeline.push(Second::new(s, &Latency::new(), &Latency::new()));
        }
        for (i, s) in timeline.iter_mut().enumerate() {
            s.scheduled = scheduled_per_s.get(i).copied().unwrap_or(0);
            s.sent = sent_per_s.get(i).copied().unwrap_or(0);
        }
        let (mode, from) = match opts.pacing {
            Pacing::Recorded => (Mode::Recorded, LatencyFrom::Scheduled),
            Pacing::Constant { .. } => (Mode::Rate, LatencyFrom::Scheduled),
            Pacing::Ramp { .. } => (Mode::Ramp, LatencyFrom::Scheduled),
            Pacing::Saturation { .. } => (Mode::Saturation, LatencyFrom::Sent),
        };
        let http = if opts.http2 { Http::Http2 } else { Http::Http1 };
        let sent = shared.sent.load(Relaxed);
        let scheduled = schedule.as_ref().map_or(sent, Schedule::scheduled);
        ReplayReport {
            target_rate: schedule.as_ref().map(Schedule::mean_rate),
            shard: opts.shard.to_string(),
            connections: opts.connections,
            seconds,
            scheduled,
            sent,
            // Not sent when the deadline came: not errors, the server never saw them.
            unsent: scheduled.saturating_sub(sent),
            completed: rec.completed,
            tiles: rec.tiles,
            bytes: rec.bytes,
            backlog,
            errors: rec.errors,
            http_statuses: std::mem::take(&mut rec.statuses),
            latency_ms: rec.corrected.percentiles(),
            uncorrected_latency_ms: rec.uncorrected.percentiles(),
            histograms: Histograms::of(&rec.corrected, &rec.uncorrected),
            timeline,
            ..ReplayReport::empty(mode, http, from)
        }
    };
    r.set_rates();
    r.rate_held = r
        .target_rate
        .map(|t| rate_held(t, r.completed, r.seconds, r.backlog, r.scheduled));
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::loadtest::trace::{
        RequestKind, Shard, TRACE_VERSION, Trace, TraceHeader, TraceRequest,
    };

    fn trace(server: &str) -> Trace {
        Trace {
            header: TraceHeader {
                tessera_trace: TRACE_VERSION,
                server: server.into(),
                dataset: "moon".into(),
                clients: 2,
                seconds: 0.05,
                mode: "ranges".into(),
            },
            requests: (0..4)
                .map(|i| TraceRequest {
                    client: i % 2,
                    t_ms: f64::from(i) * 10.0,
                    kind: RequestKind::Tiles,
                    target: format!("/v1/datasets/moon/levels/1/tiles?ranges=0-{i}"),
                    level: Some(1),
                    expect: None,
                })
                .collect(),
        }
    }

    #[test]
    fn nobody_listening_is_a_connect_error_per_request() {
        // A port just freed: connections are refused (a real socket, no server).
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let mut opts = ReplayOptions::new(trace(&format!("http://127.0.0.1:{port}")));
        opts.shard = Shard::new(1, 2).unwrap();
        opts.connections = 2;
        let r = replay(&opts).unwrap();
        assert_eq!(r.mode, Mode::Recorded);
        assert_eq!((r.scheduled, r.sent, r.completed), (2, 2, 0));
        assert_eq!(r.errors.connect, 2);
        assert_eq!(r.errors.total(), 2);
        assert_eq!(r.shard, "1/2");
        assert!(r.timeline.iter().map(|s| s.scheduled).sum::<u64>() == 2);
    }

    /// `rate` requests/s for `ms` milliseconds on `connections` connections, each
    /// request given `timeout_ms`, to a listening socket that never accepts:
    /// connections open (the kernel's backlog) and requests go out, but no answer
    /// ever comes.
    fn replay_silently(rate: f64, ms: u64, connections: u32, timeout_ms: u64) -> ReplayReport {
        let silent = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let port = silent.local_addr().unwrap().port();
        let mut opts = ReplayOptions::new(trace(&format!("http://127.0.0.1:{port}")));
        opts.pacing = Pacing::Constant {
            rate: super::super::pacing::Rate::new(rate).unwrap(),
            duration: Duration::from_millis(ms),
        };
        opts.connections = connections;
        opts.timeout = Duration::from_millis(timeout_ms);
        let r = replay(&opts).unwrap();
        drop(silent);
        r
    }

    /// 10 requests over 0.5 s (20/s), each given 300 ms.
    fn replay_to_a_silent_server(connections: u32) -> ReplayReport {
        replay_silently(20.0, 500, connections, 300)
    }

    #[test]
    fn a_server_that_never_answers_falls_behind_and_times_out() {
        let r = replay_to_a_silent_server(1);
        assert_eq!(r.mode, Mode::Rate);
        assert_eq!((r.scheduled, r.completed), (10, 0));
        // One connection held 300 ms per request, and the run ends at its deadline,
        // 0.5 s + 300 ms: a request can only have gone out at 0, 0.3 and 0.6 s (each
        // frees the connection no sooner than its timeout). The rest were never sent
        // (they used to be, one every 300 ms, for 3 s).
        assert!(r.sent <= 3, "sent {}", r.sent);
        assert_eq!(r.sent + r.unsent, 10);
        // Those sent timed out; those never sent are not errors.
        assert_eq!(r.errors.timeout, r.sent);
        assert_eq!(r.errors.total(), r.sent);
        // When the schedule ended (0.5 s) at most two had been sent.
        assert!(r.backlog >= 8, "backlog {}", r.backlog);
        assert!(r.backlog >= r.unsent);
        assert_eq!(r.rate_held, Some(false));
        assert_eq!(r.target_rate, Some(20.0));
        assert_eq!(
            r.latency_ms,
            super::super::replay_report::Percentiles::default()
        );
        // Every scheduled request is in the timeline, sent or not.
        assert_eq!(r.timeline.iter().map(|s| s.scheduled).sum::<u64>(), 10);
        assert_eq!(r.timeline.iter().map(|s| s.sent).sum::<u64>(), r.sent);
        assert!(r.to_string().contains("never sent"), "{r}");
    }

    #[test]
    fn a_rate_the_connections_cannot_hold_stops_at_the_deadline() {
        // 400/s for 0.5 s (200 requests) on 2 connections that each hold a request
        // 200 ms: the run ends 0.5 s + 200 ms after its start, having sent at most
        // 2 × ⌈0.7 / 0.2⌉ = 8. It used to send all 200, 100 rounds of 200 ms (20 s):
        // `--rate 30000 --duration 2s` sent for 17.7 s.
        let r = replay_silently(400.0, 500, 2, 200);
        assert_eq!(r.scheduled, 200);
        assert!(r.sent <= 8, "sent {}", r.sent);
        assert_eq!(r.unsent, 200 - r.sent);
        assert_eq!(r.errors.total(), r.sent);
        assert_eq!(r.rate_held, Some(false));
    }

    #[test]
    fn requests_start_on_schedule_whether_or_not_earlier_ones_finished() {
        // The same silent server, but connections to spare: the open model sends
        // every request at its instant although none is ever answered.
        let r = replay_to_a_silent_server(16);
        assert_eq!((r.scheduled, r.sent + r.unsent, r.completed), (10, 10, 0));
        assert_eq!(r.errors.timeout, r.sent);
        // Waiting for answers, only 2 could have gone out by the end of the schedule
        // (0.5 s) and the run would last 10 × 300 ms; on schedule, all are out by
        // 0.45 s (a little slack for a loaded machine) and the run ends one timeout
        // after the last send.
        assert!(r.backlog <= 3, "backlog {}", r.backlog);
        assert!(r.timeline[0].sent >= 7, "{:?}", r.timeline[0]);
        assert!(r.seconds < 2.5, "{}", r.seconds);
        // Nothing was answered: the rate was not held even though nothing fell behind.
        assert_eq!(r.rate_held, Some(false));
    }

    #[test]
    fn runs_no_clock_can_hold_are_refused() {
        // A trace built in code (Trace::read refuses it first) with a time of 1e300 ms
        // used to panic converting it to a Duration.
        let mut t = trace("http://127.0.0.1:1");
        t.requests[3].t_ms = 1e300;
        let e = crate::errors::Chain(&replay(&ReplayOptions::new(t)).unwrap_err()).to_string();
        assert!(e.contains("1e300") && e.contains("7 days"), "{e}");
        let mut opts = ReplayOptions::new(trace("http://127.0.0.1:1"));
        opts.timeout = Duration::from_secs(7200);
        let e = crate::errors::Chain(&replay(&opts).unwrap_err()).to_string();
        assert!(e.contains("--timeout"), "{e}");
        opts.timeout = Duration::from_secs(1);
        opts.pacing = Pacing::Saturation {
            duration: MAX_RUN * 2,
        };
        let e = crate::errors::Chain(&replay(&opts).unwrap_err()).to_string();
        assert!(e.contains("--duration") && e.contains("7 days"), "{e}");
        opts.pacing = Pacing::Constant {
            rate: super::super::pacing::Rate::new(1e18).unwrap(),
            duration: Duration::from_secs(1),
        };
        let e = crate::errors::Chain(&replay(&opts).unwrap_err()).to_string();
        assert!(e.contains("1000000 requests/s"), "{e}");
    }

    /// A stand-in server that reads each request's head and answers it with the
    /// status `status_of(target)` and a small JSON body, then closes the
    /// connection. Returns its base URL.
    fn answering(status_of: fn(&str) -> u16) -> String {
        use std::io::{BufRead, Write};
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let url = format!("http://{}", listener.local_addr().unwrap());
        std::thread::spawn(move || {
            for stream in listener.incoming() {
                let Ok(mut stream) = stream else { return };
                std::thread::spawn(move || {
                    let mut reader = std::io::BufReader::new(stream.try_clone().unwrap());
                    let mut request = String::new();
                    let _ = reader.read_line(&mut request);
                    let mut line = String::new();
                    while reader.read_line(&mut line).unwrap_or(0) > 2 {
                        line.clear();
                    }
                    let target = request.split(' ').nth(1).unwrap_or_default();
                    let status = status_of(target);
                    let _ = write!(
                        stream,
                        "HTTP/1.1 {status} Status\r\ncontent-type: application/json\r\ncontent-length: 2\r\nconnection: close\r\n\r\n{{}}"
                    );
                });
            }
        });
        url
    }

    #[test]
    fn an_http_status_is_counted_by_status_never_as_connect() {
        // Requests 0 and 2 answered 414 (URI Too Long), 1 and 3 503.
        let url = answering(|target| {
            if target.ends_with("0-0") || target.ends_with("0-2") {
                414
            } else {
                503
            }
        });
        let r = replay(&ReplayOptions::new(trace(&url))).unwrap();
        assert_eq!((r.sent, r.completed), (4, 4));
        assert_eq!(r.errors.connect, 0, "{:?}", r.errors);
        assert_eq!(r.errors.http_status, 4, "{:?}", r.errors);
        assert_eq!(r.errors.total(), 4);
        assert_eq!(
            r.http_statuses,
            std::collections::BTreeMap::from([(414, 2), (503, 2)])
        );
        let summary = r.to_string();
        assert!(
            summary.contains("http_status 4 (414: 2, 503: 2)"),
            "{summary}"
        );
        // And through the JSON, as `"http_statuses": {"414": 2, "503": 2}`.
        let v = serde_json::to_value(&r).unwrap();
        assert_eq!(v["http_statuses"]["414"], 2);
    }

    #[test]
    fn a_url_too_long_to_send_is_refused_not_counted_as_connect() {
        // A query of 100 000 bytes: a server would answer 414, but the HTTP client
        // cannot even send it, and each such request used to count as `connect`.
        let url = answering(|_| 414);
        let mut t = trace(&url);
        t.requests[2].target = format!(
            "/v1/datasets/moon/levels/1/tiles?ranges={}",
            "0".repeat(100_000)
        );
        let e =
            crate::errors::Chain(&replay(&ReplayOptions::new(t.clone())).unwrap_err()).to_string();
        assert!(
            e.contains("request 3") && e.contains("65534") && e.contains("100"),
            "{e}"
        );
        // The longest URL that fits is sent, and answered by status.
        let room = MAX_URL_BYTES - url.len() - "/v1/x?q=".len();
        t.requests[2].target = format!("/v1/x?q={}", "0".repeat(room));
        let r = replay(&ReplayOptions::new(t)).unwrap();
        assert_eq!(r.errors.connect, 0, "{:?}", r.errors);
        assert_eq!(r.http_statuses.get(&414), Some(&4));
    }

    #[test]
    fn a_connection_closed_before_an_answer_is_a_connect_error() {
        // A server that accepts and hangs up at once: a socket failure, not an answer.
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let url = format!("http://{}", listener.local_addr().unwrap());
        std::thread::spawn(move || {
            for stream in listener.incoming() {
                drop(stream);
            }
        });
        let r = replay(&ReplayOptions::new(trace(&url))).unwrap();
        assert_eq!((r.sent, r.completed), (4, 0));
        assert_eq!(r.errors.connect, 4, "{:?}", r.errors);
        assert!(r.http_statuses.is_empty());
    }

    #[test]
    fn a_bad_server_url_names_the_request() {
        let mut opts = ReplayOptions::new(trace("http://127.0.0.1:1"));
        opts.server = Some("not a url".into());
        let e = crate::errors::Chain(&replay(&opts).unwrap_err()).to_string();
        assert!(e.contains("request 1") && e.contains("not a URL"), "{e}");
    }

    #[test]
    fn connections_the_open_file_limit_cannot_hold_are_refused_before_any_is_opened() {
        // `--connections 1000000` took 915 MB before sending anything.
        let mut opts = ReplayOptions::new(trace("http://127.0.0.1:1"));
        opts.connections = 1_000_000;
        let e = crate::errors::Chain(&replay(&opts).unwrap_err()).to_string();
        assert!(e.contains("--connections 1000000"), "{e}");
    }
}
