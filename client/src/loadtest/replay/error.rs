//! Why a replay could not run ([`ReplayError`]).

use super::options::MAX_URL_BYTES;
use crate::loadtest::connections::ConnectionsError;
use crate::loadtest::pacing::{MAX_RUN, MAX_TIMEOUT, ScheduleError};
use crate::loadtest::trace::Shard;
use std::time::Duration;

/// Why a replay could not run: its settings, the trace's requests, or the
/// process's resources.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error("--connections must be at least 1")]
    NoConnections,
    #[error(transparent)]
    Connections(#[from] ConnectionsError),
    #[error("--threads must be at least 1")]
    NoThreads,
    #[error("--timeout must be above 0")]
    ZeroTimeout,
    #[error(
        "--timeout {timeout:?} is longer than {} s, the longest latency the report's histograms hold",
        MAX_TIMEOUT.as_secs()
    )]
    Timeout { timeout: Duration },
    #[error(
        "--duration {duration:?} is longer than the {} s (7 days) a replay runs",
        MAX_RUN.as_secs()
    )]
    Duration { duration: Duration },
    #[error("request {number} of the shard: {url:?} is not a URL")]
    Url {
        number: usize,
        url: String,
        #[source]
        source: <reqwest::Url as std::str::FromStr>::Err,
    },
    #[error(
        "request {number} of the shard: its URL ({start}…) is {len} bytes, more than the {MAX_URL_BYTES} an HTTP request can carry here; shorten its target"
    )]
    UrlTooLong {
        number: usize,
        start: String,
        len: usize,
    },
    #[error("shard {shard} of the trace")]
    Schedule {
        shard: Shard,
        #[source]
        source: ScheduleError,
    },
    #[error("cannot build the HTTP client")]
    Client(#[source] reqwest::Error),
    #[error(transparent)]
    Runtime(#[from] std::io::Error),
}
