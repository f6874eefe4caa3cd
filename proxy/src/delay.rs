//! Added latency: responses held before their first byte.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};

/// Holds each response from upstream for `hold` before passing its first byte on; the
/// rest of the response follows as it arrives. This adds `hold` to every round trip a
/// client makes, which is what latency looks like to a client that sends a request and
/// waits for its answer (the Tessera client and `tessera load` do).
///
/// The proxy does not parse HTTP to find responses (so it delays any protocol): the
/// first bytes of a connection start a response, and so do the first bytes after the
/// upstream has been silent for `gap`. A response whose bytes pause for longer than
/// `gap` midway is held again there; a next response whose first byte comes within
/// `gap` of the previous one's last byte is not held (its request, its server time and
/// the way back all fit in `gap`). `bench/delay_proxy.py`, which this replaces, had the
/// same rule with the same 20 ms gap.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Delay {
    /// How long each response waits before its first byte goes on.
    pub hold: Duration,
    /// Upstream silence that ends a response.
    pub gap: Duration,
}

impl Delay {
    /// The gap of [`Delay::new`]: long against the bytes of one response arriving on
    /// loopback, short against a client's think time between requests.
    pub const DEFAULT_GAP: Duration = Duration::from_millis(20);

    /// Holds each response for `hold`, with the [`DEFAULT_GAP`](Self::DEFAULT_GAP).
    pub fn new(hold: Duration) -> Self {
        Self {
            hold,
            gap: Self::DEFAULT_GAP,
        }
    }
}

/// Carries the upstream's bytes to the client, holding each response (see [`Delay`]);
/// counts every hold in `held` as it begins, before any of that response goes on.
pub(crate) async fn relay_delayed(
    mut sr: OwnedReadHalf,
    mut cw: OwnedWriteHalf,
    delay: Delay,
    held: &AtomicU64,
) {
    let mut buf = vec![0u8; 1 << 16];
    let mut fresh = true;
    loop {
        let n = match tokio::time::timeout(delay.gap, sr.read(&mut buf)).await {
            Ok(Ok(0) | Err(_)) => break,
            Ok(Ok(n)) => n,
            // A pause in the stream: the next bytes start a new response.
            Err(_) => {
                fresh = true;
                continue;
            }
        };
        if fresh {
            held.fetch_add(1, Ordering::SeqCst);
            tokio::time::sleep(delay.hold).await;
            fresh = false;
        }
        if cw.write_all(&buf[..n]).await.is_err() {
            break;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{assert_held_back, get, http_upstream, pattern, read_response, response};
    use crate::{Stats, delaying};
    use tokio::net::TcpStream;

    /// The response has reached the proxy (its hold has begun, and the upstream has
    /// seen the request) and not one byte of it has reached the client.
    #[tokio::test]
    async fn a_held_response_sends_nothing_before_its_hold_ends() {
        let upstream = http_upstream(vec![response("text/plain", b"hello")]).await;
        let day = Duration::from_secs(24 * 3600);
        let proxy = delaying(upstream.addr, Delay::new(day)).await.unwrap();
        assert_held_back(&proxy, &upstream).await;
    }

    /// Two responses on one connection, the client pausing between them: each is held
    /// once (a mebibyte arriving in many reads is still one response), and both arrive
    /// exactly as the upstream sent them.
    #[tokio::test]
    async fn holds_each_response_once_and_relays_it_unchanged() {
        let big = pattern(1 << 20);
        let first = response("application/octet-stream", &big);
        let second = response("text/plain", b"second");
        let upstream = http_upstream(vec![first.clone(), second.clone()]).await;
        let delay = Delay {
            hold: Duration::from_millis(1),
            gap: Duration::from_millis(20),
        };
        let proxy = delaying(upstream.addr, delay).await.unwrap();
        let client = TcpStream::connect(proxy.addr()).await.unwrap();
        let (r, mut w) = client.into_split();
        let mut r = tokio::io::BufReader::new(r);
        w.write_all(&get("/big")).await.unwrap();
        let (head, body) = read_response(&mut r).await;
        assert!(
            [head.as_bytes(), &body].concat() == first,
            "the first response changed"
        );
        // Ten gaps of silence: whatever comes next is a new response.
        tokio::time::sleep(10 * delay.gap).await;
        w.write_all(&get("/small")).await.unwrap();
        let (head, body) = read_response(&mut r).await;
        assert_eq!([head.as_bytes(), &body].concat(), second);
        assert_eq!(
            proxy.stats(),
            Stats {
                connections: 1,
                held: 2
            }
        );
        assert_eq!(
            *upstream.received.lock().unwrap(),
            [get("/big"), get("/small")].concat()
        );
    }
}
