//! The replay engine of `tessera load --replay` (issue 18): sends a trace's requests
//! on an arrival schedule, checks each answer as it streams in, and reports latency
//! in HDR histograms.
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

use super::check::{Check, ErrorKind, Outcome};
use super::connections::{check_connections, open_file_limit};
use super::report::{
    ErrorCounts, Histograms, Http, Latency, LatencyFrom, Mode, ReplayReport, Second, rate_held,
};
use super::schedule::{MAX_RUN, MAX_TIMEOUT, Pacing, Schedule};
use super::trace::{Expect, RequestKind, Shard, Trace};
use anyhow::Context;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering::Relaxed};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::Semaphore;
use tokio::time::Instant;

/// HTTP/2: requests in flight per connection (streams). Servers commonly allow 100–250
/// concurrent streams; 100 stays under all of them.
pub const STREAMS_PER_CONNECTION: u32 = 100;

/// HTTP/2 flow-control window per stream (bytes); the connection's is four times it.
const H2_STREAM_WINDOW: u32 = 8 << 20;

/// The longest URL a request may have: the `http` crate's URI limit (`u16::MAX - 1`
/// bytes), under reqwest and hyper. A longer one cannot be sent at all.
const MAX_URL_BYTES: usize = u16::MAX as usize - 1;

/// What to replay and how.
#[derive(Clone, Debug)]
pub struct ReplayOptions {
    /// The whole trace; the engine takes `shard`'s part of it.
    pub trace: Trace,
    /// Base URL to send to (`http://host:port`); `None`: the trace header's server.
    pub server: Option<String>,
    pub pacing: Pacing,
    /// HTTP/1.1: at most this many requests in flight, on at most this many keep-alive
    /// connections. HTTP/2: this many connections, each carrying up to
    /// [`STREAMS_PER_CONNECTION`] requests. At saturation: this many workers.
    pub connections: u32,
    /// HTTP/2 (h2c with prior knowledge on `http://`; negotiated on `https://`).
    pub http2: bool,
    pub shard: Shard,
    /// A request's limit, and the wait for requests still in flight when the schedule
    /// has ended; those still unanswered then count as `timeout` errors.
    pub timeout: Duration,
    /// Runtime threads: 1 (the default) is a current-thread runtime.
    pub threads: usize,
    /// A live progress line on stderr every second.
    pub progress: bool,
}

impl ReplayOptions {
    /// The trace as recorded, on 64 HTTP/1.1 connections, 10 s timeout, one thread, no
    /// progress line.
    pub fn new(trace: Trace) -> Self {
        Self {
            trace,
            server: None,
            pacing: Pacing::Recorded,
            connections: 64,
            http2: false,
            shard: Shard::ALL,
            timeout: Duration::from_secs(10),
            threads: 1,
            progress: false,
        }
    }
}

/// A request ready to send.
#[derive(Debug)]
struct Prepared {
    url: reqwest::Url,
    expect: Option<Expect>,
    frames: bool,
    /// A single tile's record recorded as a 200 (`--mode single`): one tile when it
    /// comes back as recorded (its body is not a frame stream, so the check counts
    /// no frames).
    one_tile: bool,
}

/// State shared by the scheduler, the request tasks and the progress line.
#[derive(Debug)]
struct Shared {
    requests: Vec<Prepared>,
    /// One per connection (see [`clients`]).
    clients: Vec<reqwest::Client>,
    /// HTTP/1.1: the connections not carrying a request, least recently used first.
    /// `None` for HTTP/2, whose connections are used in turn (`next_client`).
    idle: Option<Mutex<std::collections::VecDeque<usize>>>,
    next_client: AtomicUsize,
    start: Instant,
    sent: AtomicU64,
    completed: AtomicU64,
    errors: AtomicU64,
    tiles: AtomicU64,
    tally: Mutex<Tally>,
}

/// The histograms and counts, behind one lock (uncontended on one thread).
#[derive(Debug)]
struct Tally {
    /// Set when the run ends: answers arriving later are not counted.
    closed: bool,
    /// Requests that finished (answered or failed).
    finished: u64,
    completed: u64,
    tiles: u64,
    bytes: u64,
    errors: ErrorCounts,
    /// The `http_status` errors by status.
    statuses: std::collections::BTreeMap<u16, u64>,
    corrected: Latency,
    uncorrected: Latency,
    /// Finished seconds.
    seconds: Vec<Second>,
    /// The second being filled, its histograms and counts.
    current: u64,
    cur_corrected: Latency,
    cur_uncorrected: Latency,
    cur: Second,
}

impl Tally {
    fn new() -> Self {
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
    fn roll_to(&mut self, second: u64) {
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
    fn record(
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

/// What a failed send was: only a socket failure is `connect`. A request the client
/// could not make was never sent; an error carrying a status (reqwest's
/// `error_for_status`, not used here, but classified all the same) is an answer.
fn send_error_kind(e: &reqwest::Error) -> ErrorKind {
    if e.is_timeout() {
        ErrorKind::Timeout
    } else if e.is_builder() {
        ErrorKind::Request
    } else if e.status().is_some() {
        ErrorKind::HttpStatus
    } else {
        // Refused, DNS, TLS, or reset or closed before an answer's head.
        ErrorKind::Connect
    }
}

fn bump(per_second: &mut Vec<u64>, second: u64) {
    let i = second as usize;
    if per_second.len() <= i {
        per_second.resize(i + 1, 0);
    }
    per_second[i] += 1;
}

impl Shared {
    fn second(&self, at: Instant) -> u64 {
        at.saturating_duration_since(self.start).as_secs()
    }

    /// Sends request `i`, scheduled at `scheduled`, reads and checks its answer, and
    /// records it.
    async fn request(&self, i: usize, scheduled: Instant) {
        let req = &self.requests[i];
        // HTTP/1.1: a free connection (the caller holds one of as many permits or
        // workers as there are connections, so there is one), the least recently
        // used, so that the load spreads over all of them as wrk's and oha's
        // connection-per-worker does; HTTP/2: the connections in turn.
        let slot = match &self.idle {
            Some(idle) => idle
                .lock()
                .expect("idle connections lock")
                .pop_front()
                .expect("a permit or worker per connection"),
            None => self.next_client.fetch_add(1, Relaxed) % self.clients.len(),
        };
        let client = &self.clients[slot];
        let sent = Instant::now();
        let mut status = None;
        let outcome = match client.get(req.url.clone()).send().await {
            Err(e) => Outcome {
                tiles: 0,
                bytes: 0,
                error: Some(send_error_kind(&e)),
            },
            Ok(mut resp) => {
                status = Some(resp.status().as_u16());
                let mut check = Check::new(req.expect.as_ref(), req.frames, resp.status().as_u16());
                loop {
                    match resp.chunk().await {
                        Ok(Some(chunk)) => check.push(&chunk),
                        Ok(None) => break check.finish(),
                        Err(e) => {
                            break check.broken(if e.is_timeout() {
                                ErrorKind::Timeout
                            } else {
                                ErrorKind::Truncated
                            });
                        }
                    }
                }
            }
        };
        let mut outcome = outcome;
        if req.one_tile && outcome.error.is_none() {
            outcome.tiles = 1;
        }
        let done = Instant::now();
        if let Some(idle) = &self.idle {
            idle.lock().expect("idle connections lock").push_back(slot);
        }
        if outcome.error.is_some() {
            self.errors.fetch_add(1, Relaxed);
        }
        if outcome.error.is_none_or(ErrorKind::answered) {
            self.completed.fetch_add(1, Relaxed);
            self.tiles.fetch_add(u64::from(outcome.tiles), Relaxed);
        }
        let mut r = self.tally.lock().expect("tally lock");
        // The second is taken under the lock, so seconds only ever move forward.
        let second = self.second(Instant::now());
        r.record(&outcome, status, second, done - scheduled, done - sent);
    }
}

/// The HTTP clients, one per connection (`connections` of them, each keeping one
/// connection alive). One client with a pool of `connections` would hand out its
/// most recently used idle connection, so that at a moderate rate a few hot
/// connections carried everything: against a server whose sockets delay small
/// segments (Nagle), a hot connection in delayed-ACK mode waits 40 ms for the last
/// segment of an answer now and then (p99 45 ms against oha's 5 ms on the same
/// requests and rate, where oha spreads them over all its connections).
fn clients(opts: &ReplayOptions, base: &str) -> anyhow::Result<Vec<reqwest::Client>> {
    static PROVIDER: std::sync::Once = std::sync::Once::new();
    PROVIDER.call_once(|| {
        // HTTPS servers: the client crate builds reqwest without a crypto provider of
        // its own (see Cargo.toml); a second install (already done elsewhere) fails
        // harmlessly.
        let _ = rustls::crypto::ring::default_provider().install_default();
    });
    let h2c = opts.http2 && base.starts_with("http://");
    (0..opts.connections)
        .map(|_| {
            let b = reqwest::Client::builder()
                .timeout(opts.timeout)
                .pool_max_idle_per_host(1)
                .tcp_nodelay(true);
            // HTTP/2's default 64 KiB stream window would hold a 300 KiB batch of tiles
            // to a window update per 64 KiB (round trips the server's Nagle makes up to
            // 40 ms each); the replay reads every body at once, so the windows are large.
            let b = b
                .http2_initial_stream_window_size(H2_STREAM_WINDOW)
                .http2_initial_connection_window_size(H2_STREAM_WINDOW * 4);
            let b = if h2c { b.http2_prior_knowledge() } else { b };
            b.build().context("cannot build the HTTP client")
        })
        .collect()
}

/// Replays `opts.trace` (its shard) and reports. Blocking: it runs its own tokio
/// runtime, so call it from a plain thread (in async code, `spawn_blocking`).
pub fn replay(opts: &ReplayOptions) -> anyhow::Result<ReplayReport> {
    anyhow::ensure!(opts.connections >= 1, "--connections must be at least 1");
    check_connections(opts.connections, open_file_limit())?;
    anyhow::ensure!(opts.threads >= 1, "--threads must be at least 1");
    anyhow::ensure!(!opts.timeout.is_zero(), "--timeout must be above 0");
    anyhow::ensure!(
        opts.timeout <= MAX_TIMEOUT,
        "--timeout {:?} is longer than {} s, the longest latency the report's histograms hold",
        opts.timeout,
        MAX_TIMEOUT.as_secs()
    );
    if let Pacing::Saturation { duration } = opts.pacing {
        anyhow::ensure!(
            duration <= MAX_RUN,
            "--duration {:?} is longer than the {} s (7 days) a replay runs",
            duration,
            MAX_RUN.as_secs()
        );
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
            let url = reqwest::Url::parse(&url).with_context(|| {
                format!("request {} of the shard: {url:?} is not a URL", i + 1)
            })?;
            // A longer one was counted as a `connect` error per request: the client
            // refuses to send it, so no server ever answers it (not even 414).
            anyhow::ensure!(
                url.as_str().len() <= MAX_URL_BYTES,
                "request {} of the shard: its URL ({}…) is {} bytes, more than the {MAX_URL_BYTES} an HTTP request can carry here; shorten its target",
                i + 1,
                url.as_str().chars().take(60).collect::<String>(),
                url.as_str().len()
            );
            Ok(Prepared {
                url,
                expect: r.expect.clone(),
                frames: r.kind.is_frame_stream(),
                one_tile: r.kind == RequestKind::Tile
                    && r.expect.as_ref().is_some_and(|e| e.status == 200),
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let times: Vec<f64> = trace.requests.iter().map(|r| r.t_ms).collect();
    let schedule = Schedule::new(&opts.pacing, &times, opts.shard.count())
        .with_context(|| format!("shard {} of the trace", opts.shard))?;
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
) -> anyhow::Result<ReplayReport> {
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

/// Arrivals the scheduling thread may hand out ahead of the sends (the channel
/// between them). Bounded, so that a schedule the connections cannot keep up with
/// waits in the schedule (computed when needed) instead of piling up in memory: an
/// unbounded queue held every arrival of `--rate 1e18` (2.9 GB after 25 s).
const ARRIVALS_AHEAD: usize = 1024;

/// The open model: each arrival at its instant, waiting for a free connection when
/// all are busy, until the schedule has been sent or the run's deadline (the
/// schedule's end + `--timeout`) has come; arrivals not sent by then are not sent.
/// Returns the requests sent per second and the backlog when the schedule ended.
async fn open_loop(
    opts: &ReplayOptions,
    shared: &Arc<Shared>,
    schedule: &Schedule,
) -> (Vec<u64>, u64) {
    let permits = if opts.http2 {
        opts.connections.saturating_mul(STREAMS_PER_CONNECTION)
    } else {
        opts.connections
    };
    let sem = Arc::new(Semaphore::new(permits as usize));
    let start = shared.start;
    let total = schedule.scheduled();
    // The hard end of the run, whatever the rate: a server that falls behind (or a
    // rate no connection count keeps up with) makes requests wait, and without it
    // `--rate 30000 --duration 2s` went on sending for 17.7 s.
    let deadline = start + schedule.span() + opts.timeout;
    // The backlog is read when the schedule's last instant has passed (plus a timer
    // tick), by a task of its own, since the scheduler may be waiting for a connection.
    let end_of_schedule = start + schedule.span() + Duration::from_millis(2);
    let watcher = {
        let shared = shared.clone();
        tokio::spawn(async move {
            tokio::time::sleep_until(end_of_schedule).await;
            total.saturating_sub(shared.sent.load(Relaxed))
        })
    };
    // The instants come from a thread of their own: tokio's timer has a resolution
    // of 1 ms and rounds up, which would add up to a millisecond to every corrected
    // latency; a thread's sleep is good to tens of microseconds. It only sleeps and
    // sends; the sends themselves happen on the runtime, in order.
    let (tx, mut rx) = tokio::sync::mpsc::channel::<super::schedule::Arrival>(ARRIVALS_AHEAD);
    let ticker = {
        let (schedule, start) = (schedule.clone(), start.into_std());
        std::thread::Builder::new()
            .name("replay-schedule".into())
            .spawn(move || {
                for k in 0..total {
                    let a = schedule.arrival(k);
                    let at = start + a.at;
                    let now = std::time::Instant::now();
                    if at > now {
                        std::thread::sleep(at - now);
                    }
                    // Fails once the sends have stopped (the deadline): so does this.
                    if tx.blocking_send(a).is_err() {
                        break;
                    }
                }
            })
    };
    let mut sent_per_s = Vec::new();
    // `None` when the deadline comes first.
    while let Ok(Some(a)) = tokio::time::timeout_at(deadline, rx.recv()).await {
        let at = start + a.at;
        let Ok(Ok(permit)) = tokio::time::timeout_at(deadline, sem.clone().acquire_owned()).await
        else {
            break;
        };
        // A connection freed just as the deadline passed (a late timer) sends
        // nothing either: the run is over.
        if Instant::now() >= deadline {
            break;
        }
        bump(&mut sent_per_s, shared.second(Instant::now()));
        shared.sent.fetch_add(1, Relaxed);
        let sh = shared.clone();
        tokio::spawn(async move {
            sh.request(a.request, at).await;
            drop(permit);
        });
    }
    // The scheduling thread's next hand-out fails, and it ends: it never sleeps past
    // the deadline, since every instant is within the schedule.
    drop(rx);
    if let Ok(t) = ticker {
        let _ = t.join();
    }
    let backlog = if Instant::now() < end_of_schedule {
        // Every arrival sent before the schedule ended (0), or a deadline before its
        // end (a `--timeout` under the watcher's tick): what was not sent.
        watcher.abort();
        total.saturating_sub(shared.sent.load(Relaxed))
    } else {
        watcher.await.unwrap_or(0)
    };
    // Wait for the requests in flight: all permits back, or the deadline.
    let _ = tokio::time::timeout_at(deadline, sem.acquire_many(permits)).await;
    (sent_per_s, backlog)
}

/// Saturation: `connections` workers, each sending the next request (in trace order,
/// cycling) as soon as its last one finished, until `duration` has passed.
async fn closed_loop(
    opts: &ReplayOptions,
    shared: &Arc<Shared>,
    duration: Duration,
) -> (Vec<u64>, Vec<u64>, u64) {
    let end = shared.start + duration;
    let next = Arc::new(AtomicUsize::new(0));
    let mut workers = tokio::task::JoinSet::new();
    for _ in 0..opts.connections {
        let (sh, next) = (shared.clone(), next.clone());
        workers.spawn(async move {
            let mut sent_per_s = Vec::new();
            loop {
                let now = Instant::now();
                if now >= end {
                    break;
                }
                let i = next.fetch_add(1, Relaxed) % sh.requests.len();
                bump(&mut sent_per_s, sh.second(now));
                sh.sent.fetch_add(1, Relaxed);
                sh.request(i, now).await;
            }
            sent_per_s
        });
    }
    let mut sent_per_s: Vec<u64> = Vec::new();
    let _ = tokio::time::timeout_at(end + opts.timeout, async {
        while let Some(Ok(v)) = workers.join_next().await {
            if sent_per_s.len() < v.len() {
                sent_per_s.resize(v.len(), 0);
            }
            for (a, b) in sent_per_s.iter_mut().zip(v) {
                *a += b;
            }
        }
    })
    .await;
    // Saturation has no schedule: what was sent is what was asked for.
    (sent_per_s.clone(), sent_per_s, 0)
}

/// Every second on stderr: elapsed, sent, completed, tiles/s, corrected p99 so far,
/// errors.
async fn progress_line(shared: Arc<Shared>) {
    let mut tick = tokio::time::interval_at(
        shared.start + Duration::from_secs(1),
        Duration::from_secs(1),
    );
    let mut last_tiles = 0u64;
    let mut last_at = shared.start;
    // On a terminal the line is rewritten in place; in a log, one line per second.
    let (start, end) = if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        ("\r", "   ")
    } else {
        ("", "\n")
    };
    loop {
        let now = tick.tick().await;
        let tiles = shared.tiles.load(Relaxed);
        let dt = (now - last_at).as_secs_f64().max(1e-3);
        let p99 = shared
            .tally
            .lock()
            .map_or(0.0, |r| r.corrected.quantile_ms(0.99));
        // Best-effort: a closed stderr must not end the run (eprint! would panic).
        crate::output::progress(format_args!(
            "{start}{:>5.0} s  sent {}  done {}  {:.0} tiles/s  p99 {:.2} ms  errors {}{end}",
            (now - shared.start).as_secs_f64(),
            shared.sent.load(Relaxed),
            shared.completed.load(Relaxed),
            (tiles - last_tiles) as f64 / dt,
            p99,
            shared.errors.load(Relaxed),
        ));
        last_tiles = tiles;
        last_at = now;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::loadtest::trace::{RequestKind, TRACE_VERSION, TraceHeader, TraceRequest};

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
            rate: super::super::schedule::Rate::new(rate).unwrap(),
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
        assert_eq!(r.latency_ms, super::super::report::Percentiles::default());
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
        let e = format!("{:#}", replay(&ReplayOptions::new(t)).unwrap_err());
        assert!(e.contains("1e300") && e.contains("7 days"), "{e}");
        let mut opts = ReplayOptions::new(trace("http://127.0.0.1:1"));
        opts.timeout = Duration::from_secs(7200);
        let e = format!("{:#}", replay(&opts).unwrap_err());
        assert!(e.contains("--timeout"), "{e}");
        opts.timeout = Duration::from_secs(1);
        opts.pacing = Pacing::Saturation {
            duration: MAX_RUN * 2,
        };
        let e = format!("{:#}", replay(&opts).unwrap_err());
        assert!(e.contains("--duration") && e.contains("7 days"), "{e}");
        opts.pacing = Pacing::Constant {
            rate: super::super::schedule::Rate::new(1e18).unwrap(),
            duration: Duration::from_secs(1),
        };
        let e = format!("{:#}", replay(&opts).unwrap_err());
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
        let e = format!("{:#}", replay(&ReplayOptions::new(t.clone())).unwrap_err());
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
        let e = format!("{:#}", replay(&opts).unwrap_err());
        assert!(e.contains("request 1") && e.contains("not a URL"), "{e}");
    }

    #[test]
    fn connections_the_open_file_limit_cannot_hold_are_refused_before_any_is_opened() {
        // `--connections 1000000` took 915 MB before sending anything.
        let mut opts = ReplayOptions::new(trace("http://127.0.0.1:1"));
        opts.connections = 1_000_000;
        let e = format!("{:#}", replay(&opts).unwrap_err());
        assert!(e.contains("--connections 1000000"), "{e}");
    }
}
