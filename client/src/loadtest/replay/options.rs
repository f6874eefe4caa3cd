//! What to replay and how: the trace, the server, the pacing, the connections,
//! HTTP/2, the shard, the timeout and the runtime's threads.

use crate::loadtest::pacing::Pacing;
use crate::loadtest::trace::{Shard, Trace};
use std::time::Duration;

/// HTTP/2: requests in flight per connection (streams). Servers commonly allow 100–250
/// concurrent streams; 100 stays under all of them.
pub const STREAMS_PER_CONNECTION: u32 = 100;

/// HTTP/2 flow-control window per stream (bytes); the connection's is four times it.
pub(super) const H2_STREAM_WINDOW: u32 = 8 << 20;

/// The longest URL a request may have: the `http` crate's URI limit (`u16::MAX - 1`
/// bytes), under reqwest and hyper. A longer one cannot be sent at all.
pub(super) const MAX_URL_BYTES: usize = u16::MAX as usize - 1;

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
