//! Sending replayed requests: the prepared requests and the connections the loops
//! share, and one request sent, its answer read and checked as it streams in, and
//! tallied.

use super::error::ReplayError;
use super::options::{H2_STREAM_WINDOW, ReplayOptions};
use super::tally::Tally;
use crate::loadtest::check::{Check, ErrorKind, Outcome};
use crate::loadtest::trace::Expect;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering::Relaxed};
use tokio::time::Instant;

/// A request ready to send.
#[derive(Debug)]
pub(super) struct Prepared {
    pub(super) url: reqwest::Url,
    pub(super) expect: Option<Expect>,
    pub(super) frames: bool,
    /// A single tile's record recorded as a 200 (`--mode single`): one tile when it
    /// comes back as recorded (its body is not a frame stream, so the check counts
    /// no frames).
    pub(super) one_tile: bool,
}

/// State shared by the scheduler, the request tasks and the progress line.
#[derive(Debug)]
pub(super) struct Shared {
    pub(super) requests: Vec<Prepared>,
    /// One per connection (see [`clients`]).
    pub(super) clients: Vec<reqwest::Client>,
    /// HTTP/1.1: the connections not carrying a request, least recently used first.
    /// `None` for HTTP/2, whose connections are used in turn (`next_client`).
    pub(super) idle: Option<Mutex<std::collections::VecDeque<usize>>>,
    pub(super) next_client: AtomicUsize,
    pub(super) start: Instant,
    pub(super) sent: AtomicU64,
    pub(super) completed: AtomicU64,
    pub(super) errors: AtomicU64,
    pub(super) tiles: AtomicU64,
    pub(super) tally: Mutex<Tally>,
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

impl Shared {
    pub(super) fn second(&self, at: Instant) -> u64 {
        at.saturating_duration_since(self.start).as_secs()
    }

    /// Sends request `i`, scheduled at `scheduled`, reads and checks its answer, and
    /// records it.
    pub(super) async fn request(&self, i: usize, scheduled: Instant) {
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
pub(super) fn clients(
    opts: &ReplayOptions,
    base: &str,
) -> Result<Vec<reqwest::Client>, ReplayError> {
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
            b.build().map_err(ReplayError::Client)
        })
        .collect()
}
