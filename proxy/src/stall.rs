//! A server that stops answering for a while: responses held through a time window.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};
use tokio::time::Instant;

/// A stall: from `after` past the proxy's start, for `for_`, the upstream's bytes do
/// not reach the client; those that arrive during the window go on when it ends, and
/// everything before and after it passes straight through.
///
/// To a client the server stops answering for `for_` and then answers everything at
/// once, on every connection. That is the fault that tells a load generator's latency
/// with coordinated omission from one without: with one HTTP/1.1 connection and an
/// open-model load, every request scheduled during the stall queues behind the one on
/// the wire, so latency from the scheduled start rises by about the stall, while
/// latency from the actual send rises for that one request only.
///
/// Like [`Delay`](crate::Delay), the proxy does not parse HTTP: it holds bytes, not
/// responses. A response whose first byte would go on during the window is held
/// whole; so is the rest of a response that was midway when the window began.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stall {
    /// How long after the proxy starts (`Proxy::start`) the stall begins.
    pub after: Duration,
    /// How long it lasts.
    pub for_: Duration,
}

/// A [`Stall`] placed in time: the instants it begins and ends.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Window {
    begins: Instant,
    ends: Instant,
}

impl Window {
    /// The stall's window for a proxy started at `started`.
    pub(crate) fn new(stall: Stall, started: Instant) -> Self {
        let begins = started + stall.after;
        Self {
            begins,
            ends: begins + stall.for_,
        }
    }

    fn contains(&self, t: Instant) -> bool {
        self.begins <= t && t < self.ends
    }
}

/// Carries the upstream's bytes to the client, holding those that arrive during
/// `window` until it ends; counts in `held` each hold as it begins (once per
/// connection that had bytes to send during the stall), before any of them go on.
pub(crate) async fn relay_stalled(
    mut sr: OwnedReadHalf,
    mut cw: OwnedWriteHalf,
    window: Window,
    held: &AtomicU64,
) {
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = match sr.read(&mut buf).await {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        if window.contains(Instant::now()) {
            held.fetch_add(1, Ordering::SeqCst);
            tokio::time::sleep_until(window.ends).await;
        }
        if cw.write_all(&buf[..n]).await.is_err() {
            break;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stalling;
    use crate::testing::{
        assert_held_back, get, http_upstream, pattern, read_response, response, until_held,
    };
    use tokio::io::BufReader;
    use tokio::net::TcpStream;

    const DAY: Duration = Duration::from_secs(24 * 3600);

    /// A request during the stall: its response has reached the proxy (the hold has
    /// begun, the upstream has seen the request) and not one byte of it reaches the
    /// client.
    #[tokio::test]
    async fn nothing_reaches_the_client_during_the_stall() {
        let upstream = http_upstream(vec![response("text/plain", b"hello")]).await;
        let stall = Stall {
            after: Duration::ZERO,
            for_: DAY,
        };
        let proxy = stalling(upstream.addr, stall).await.unwrap();
        assert_held_back(&proxy, &upstream).await;
    }

    /// Before a stall (a day away) responses pass unchanged and unheld: a mebibyte and
    /// a small one on one connection, each exactly as the upstream sent it.
    #[tokio::test]
    async fn before_the_stall_responses_pass_straight_through() {
        let big = response("application/octet-stream", &pattern(1 << 20));
        let small = response("text/plain", b"second");
        let upstream = http_upstream(vec![big.clone(), small.clone()]).await;
        let stall = Stall {
            after: DAY,
            for_: DAY,
        };
        let proxy = stalling(upstream.addr, stall).await.unwrap();
        let (r, mut w) = TcpStream::connect(proxy.addr()).await.unwrap().into_split();
        let mut r = BufReader::new(r);
        for (path, expected) in [("/big", &big), ("/small", &small)] {
            w.write_all(&get(path)).await.unwrap();
            let (head, body) = tokio::time::timeout(Duration::from_secs(60), read_response(&mut r))
                .await
                .expect("a response before the stall was held");
            assert!(
                [head.as_bytes(), &body].concat() == *expected,
                "{path} changed"
            );
        }
        assert_eq!(proxy.stats().held, 0);
    }

    /// A short stall from the start: the response asked for during it arrives whole,
    /// and not before the stall's end; a request after the stall is not held (the hold
    /// count stays at one).
    #[tokio::test]
    async fn a_held_response_goes_on_when_the_stall_ends_and_later_ones_pass() {
        let answer = response("text/plain", b"after the stall");
        let upstream = http_upstream(vec![answer.clone()]).await;
        let stall = Stall {
            after: Duration::ZERO,
            for_: Duration::from_secs(1),
        };
        let started = Instant::now();
        let proxy = stalling(upstream.addr, stall).await.unwrap();
        let (r, mut w) = TcpStream::connect(proxy.addr()).await.unwrap().into_split();
        let mut r = BufReader::new(r);
        w.write_all(&get("/during")).await.unwrap();
        let (head, body) = read_response(&mut r).await;
        // A lower bound: the stall ends a second after the proxy started, after `started`.
        let waited = started.elapsed();
        assert!(
            waited >= stall.for_,
            "the response came {waited:?} after the start"
        );
        assert_eq!([head.as_bytes(), &body].concat(), answer);
        assert_eq!(proxy.stats().held, 1);
        w.write_all(&get("/after")).await.unwrap();
        let (head, body) = read_response(&mut r).await;
        assert_eq!([head.as_bytes(), &body].concat(), answer);
        assert_eq!(proxy.stats().held, 1, "a response after the stall was held");
    }

    /// The stall is the proxy's, not a connection's: two connections opened during it
    /// are both held (a client cannot get around it by opening another connection).
    #[tokio::test]
    async fn every_connection_stalls() {
        let upstream = http_upstream(vec![response("text/plain", b"x")]).await;
        let stall = Stall {
            after: Duration::ZERO,
            for_: DAY,
        };
        let proxy = stalling(upstream.addr, stall).await.unwrap();
        let mut a = TcpStream::connect(proxy.addr()).await.unwrap();
        let mut b = TcpStream::connect(proxy.addr()).await.unwrap();
        a.write_all(&get("/a")).await.unwrap();
        b.write_all(&get("/b")).await.unwrap();
        until_held(&proxy, 2).await;
        assert_eq!(proxy.stats().connections, 2);
    }
}
