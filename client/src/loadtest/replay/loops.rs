//! The arrival loops: the open model (each arrival at its scheduled instant, waiting
//! for a free connection when all are busy) and saturation (a closed loop per
//! connection), and the live progress line.

use super::options::{ReplayOptions, STREAMS_PER_CONNECTION};
use super::sender::Shared;
use crate::loadtest::schedule::Schedule;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};
use std::time::Duration;
use tokio::sync::Semaphore;
use tokio::time::Instant;

/// Arrivals the scheduling thread may hand out ahead of the sends (the channel
/// between them). Bounded, so that a schedule the connections cannot keep up with
/// waits in the schedule (computed when needed) instead of piling up in memory: an
/// unbounded queue held every arrival of `--rate 1e18` (2.9 GB after 25 s).
const ARRIVALS_AHEAD: usize = 1024;

/// The open model: each arrival at its instant, waiting for a free connection when
/// all are busy, until the schedule has been sent or the run's deadline (the
/// schedule's end + `--timeout`) has come; arrivals not sent by then are not sent.
/// Returns the requests sent per second and the backlog when the schedule ended.
pub(super) async fn open_loop(
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
    let (tx, mut rx) =
        tokio::sync::mpsc::channel::<crate::loadtest::schedule::Arrival>(ARRIVALS_AHEAD);
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
pub(super) async fn closed_loop(
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
pub(super) async fn progress_line(shared: Arc<Shared>) {
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

fn bump(per_second: &mut Vec<u64>, second: u64) {
    let i = second as usize;
    if per_second.len() <= i {
        per_second.resize(i + 1, 0);
    }
    per_second[i] += 1;
}
