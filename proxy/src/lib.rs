//! TCP proxies that sit between a Tessera client and server on loopback and delay,
//! damage or log what they relay, so the client's streaming can be tested and
//! measured over real sockets against a real server.
//!
//! A [`Proxy`] listens on a port of its own and gives every connection it accepts its
//! own connection upstream. The client's bytes (requests) go upstream unchanged,
//! their request lines recorded in a [`RequestLog`] when the [`Config`] has one; the
//! upstream's bytes (responses) come back as [`Responses`] says: unchanged, held for a
//! [`Delay`] before each response's first byte, held through a [`Stall`] (the server
//! stops answering for a while), or with tile frames damaged as a [`Faults`] plan says.
//!
//! Why a crate of its own: the streaming tests (`tests/tests/streaming*.rs`) and the
//! latency benchmark (`bench/stream.sh`, through the `tessera-proxy` binary) need
//! the same proxies, and what a proxy does to the bytes must not depend on the code
//! under test. So this crate links neither `tessera-client` nor `tessera-server`
//! (nor `tessera-shared`): the fault plan knows the tile stream only by its
//! documented layout (API.md, "Frame stream"), and its tests pin that layout to
//! `tessera_shared::wire`.
//!
//! Modules: `delay` ([`Delay`]), `stall` ([`Stall`]), `faults` (the damage plan,
//! [`Faults`]), `log` ([`RequestLog`]), and the proxy itself here; `testing` holds the
//! unit tests' loopback servers.

mod delay;
mod faults;
mod log;
mod stall;
#[cfg(test)]
mod testing;

pub use delay::Delay;
pub use faults::{Damage, Faults, Recurrence, TILE_STREAM_CONTENT_TYPE};
pub use log::RequestLog;
pub use stall::Stall;

use std::io;
use std::net::{Ipv4Addr, SocketAddr};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::{JoinHandle, JoinSet};

/// What a proxy does to the responses it carries back to the client.
#[derive(Clone, Debug, Default)]
pub enum Responses {
    /// Pass them on unchanged.
    #[default]
    Relay,
    /// Hold each one before its first byte (added latency).
    Delay(Delay),
    /// Hold all of them through a time window (the server stops answering).
    Stall(Stall),
    /// Damage the tile frames of tile streams; the plan also records what it did.
    Damage(Arc<Faults>),
}

/// A proxy's settings: where it listens, whom it relays to, what it does on the way.
#[derive(Clone, Debug)]
pub struct Config {
    /// Where to listen; port 0 picks a free port ([`Proxy::addr`] says which).
    pub listen: SocketAddr,
    /// The server every accepted connection is relayed to (one upstream connection
    /// per client connection, so connection reuse and failures stay the client's).
    pub upstream: SocketAddr,
    /// What happens to the upstream's bytes on their way to the client.
    pub responses: Responses,
    /// Records the target of every `GET` request line the client sends, when set.
    pub requests: Option<RequestLog>,
}

impl Config {
    /// Relays to `upstream` unchanged, listening on a free loopback port.
    pub fn new(upstream: SocketAddr) -> Self {
        Self {
            listen: SocketAddr::from((Ipv4Addr::LOCALHOST, 0)),
            upstream,
            responses: Responses::Relay,
            requests: None,
        }
    }
}

/// What a running proxy has done so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Stats {
    /// Client connections accepted.
    pub connections: u64,
    /// Responses held by a [`Delay`] (or connections held by a [`Stall`]), each counted
    /// when its hold begins (before any of its bytes go on), so a test can tell a
    /// response is being held without timing it.
    pub held: u64,
}

#[derive(Debug, Default)]
struct Counters {
    connections: AtomicU64,
    held: AtomicU64,
}

/// A running proxy. It lives on the tokio runtime it was started on; dropping the
/// handle stops it: it stops accepting, and every connection it carries is closed.
#[derive(Debug)]
pub struct Proxy {
    addr: SocketAddr,
    counters: Arc<Counters>,
    accept: JoinHandle<()>,
}

impl Proxy {
    /// Binds `config.listen` and starts relaying in the background of the current
    /// tokio runtime. Fails only if the port cannot be bound; an upstream that cannot
    /// be reached closes each client connection as it arrives, as a dead server would.
    pub async fn start(config: Config) -> io::Result<Self> {
        let listener = TcpListener::bind(config.listen).await?;
        let addr = listener.local_addr()?;
        // A stall's window is placed from here: the proxy's start.
        let started = tokio::time::Instant::now();
        let counters = Arc::new(Counters::default());
        let accept = tokio::spawn(accept_loop(
            listener,
            Arc::new(config),
            started,
            counters.clone(),
        ));
        Ok(Self {
            addr,
            counters,
            accept,
        })
    }

    /// The address the proxy listens on: where clients should connect.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// What the proxy has done so far (counters, read at this moment).
    pub fn stats(&self) -> Stats {
        Stats {
            connections: self.counters.connections.load(Ordering::SeqCst),
            held: self.counters.held.load(Ordering::SeqCst),
        }
    }
}

impl Drop for Proxy {
    fn drop(&mut self) {
        self.accept.abort();
    }
}

/// A proxy in front of `upstream` that changes nothing.
pub async fn relay(upstream: SocketAddr) -> io::Result<Proxy> {
    Proxy::start(Config::new(upstream)).await
}

/// A proxy in front of `upstream` that holds every response for `delay` before its
/// first byte: added latency, on loopback.
pub async fn delaying(upstream: SocketAddr, delay: Delay) -> io::Result<Proxy> {
    Proxy::start(Config {
        responses: Responses::Delay(delay),
        ..Config::new(upstream)
    })
    .await
}

/// A proxy in front of `upstream` that stops answering for `stall.for_`, from
/// `stall.after` past now: whatever the upstream sends in that window reaches the client
/// when it ends.
pub async fn stalling(upstream: SocketAddr, stall: Stall) -> io::Result<Proxy> {
    Proxy::start(Config {
        responses: Responses::Stall(stall),
        ..Config::new(upstream)
    })
    .await
}

/// A proxy in front of `upstream` that damages tile frames in the responses it relays
/// as `faults` says (and records in it what it did).
pub async fn corrupting(upstream: SocketAddr, faults: Arc<Faults>) -> io::Result<Proxy> {
    Proxy::start(Config {
        responses: Responses::Damage(faults),
        ..Config::new(upstream)
    })
    .await
}

/// A proxy in front of `upstream` that passes everything through unchanged and
/// records the target of every request it carries, so a test can count what the
/// client asked for.
pub async fn logging(upstream: SocketAddr) -> io::Result<(Proxy, RequestLog)> {
    let log = RequestLog::default();
    let proxy = Proxy::start(Config {
        requests: Some(log.clone()),
        ..Config::new(upstream)
    })
    .await?;
    Ok((proxy, log))
}

/// Accepts connections until aborted. The connections are tasks of a set owned here,
/// so aborting this task (dropping the [`Proxy`]) closes them too.
async fn accept_loop(
    listener: TcpListener,
    config: Arc<Config>,
    started: tokio::time::Instant,
    counters: Arc<Counters>,
) {
    let mut connections = JoinSet::new();
    loop {
        tokio::select! {
            accepted = listener.accept() => {
                // A failed accept (out of file descriptors, say) drops that client only.
                let Ok((client, _)) = accepted else { continue };
                counters.connections.fetch_add(1, Ordering::SeqCst);
                connections.spawn(connection(client, config.clone(), started, counters.clone()));
            }
            // Reap finished connections, so a long-running proxy does not accumulate them.
            Some(_) = connections.join_next() => {}
        }
    }
}

/// One client connection: its own connection upstream, requests one way, responses
/// the other. It ends when the response side ends (the upstream closed, or the client
/// stopped reading); when the client only stops sending, the responses still due go on.
async fn connection(
    client: TcpStream,
    config: Arc<Config>,
    started: tokio::time::Instant,
    counters: Arc<Counters>,
) {
    let Ok(server) = TcpStream::connect(config.upstream).await else {
        return; // dropping `client` closes it: to the client, the server is down
    };
    // No Nagle on either side: the relay writes each piece as it arrives, and Nagle
    // would hold a response's last small piece until the previous one is acknowledged,
    // which a client delaying its ACKs does after 40 ms: latency of the proxy's own
    // (seen as 30–50 ms per request replaying through a plain relay).
    let _ = client.set_nodelay(true);
    let _ = server.set_nodelay(true);
    let (cr, mut cw) = client.into_split();
    let (mut sr, sw) = server.into_split();
    let up = log::relay_requests(cr, sw, config.requests.clone());
    let down = async {
        match &config.responses {
            Responses::Relay => {
                let _ = tokio::io::copy(&mut sr, &mut cw).await;
            }
            Responses::Delay(delay) => delay::relay_delayed(sr, cw, *delay, &counters.held).await,
            Responses::Stall(stall) => {
                let window = stall::Window::new(*stall, started);
                stall::relay_stalled(sr, cw, window, &counters.held).await;
            }
            Responses::Damage(faults) => faults::relay_damaging(sr, cw, faults).await,
        }
    };
    tokio::pin!(up, down);
    tokio::select! {
        () = &mut down => {}
        // The client has sent everything (and the upstream has seen it end).
        () = &mut up => down.await,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{echo_upstream, pattern};
    use std::time::Duration;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    /// A mebibyte through a plain relay and back from an echoing upstream: every
    /// byte arrives, unchanged and in order, and the client's end of input reaches
    /// the upstream (the echo ends, so the client sees its end too).
    #[tokio::test]
    async fn relays_bytes_unchanged_both_ways() {
        let upstream = echo_upstream().await;
        let proxy = relay(upstream).await.unwrap();
        let sent = pattern(1 << 20);
        let stream = TcpStream::connect(proxy.addr()).await.unwrap();
        let (mut r, mut w) = stream.into_split();
        let writer = {
            let sent = sent.clone();
            tokio::spawn(async move {
                w.write_all(&sent).await.unwrap();
                w.shutdown().await.unwrap();
            })
        };
        let mut back = Vec::new();
        r.read_to_end(&mut back).await.unwrap();
        writer.await.unwrap();
        assert!(back == sent, "{} bytes came back, not the same", back.len());
        assert_eq!(
            proxy.stats(),
            Stats {
                connections: 1,
                held: 0
            }
        );
    }

    /// Each client connection gets a connection of its own upstream: two clients'
    /// bytes do not mix.
    #[tokio::test]
    async fn every_client_connection_has_its_own_upstream_connection() {
        let upstream = echo_upstream().await;
        let proxy = relay(upstream).await.unwrap();
        let mut a = TcpStream::connect(proxy.addr()).await.unwrap();
        let mut b = TcpStream::connect(proxy.addr()).await.unwrap();
        a.write_all(b"from a").await.unwrap();
        b.write_all(b"from b").await.unwrap();
        let (mut got_a, mut got_b) = ([0u8; 6], [0u8; 6]);
        a.read_exact(&mut got_a).await.unwrap();
        b.read_exact(&mut got_b).await.unwrap();
        assert_eq!((&got_a, &got_b), (b"from a", b"from b"));
        assert_eq!(proxy.stats().connections, 2);
    }

    /// An upstream that is not there: the proxy accepts and then closes the client's
    /// connection (end of stream, no bytes), as a dead server's port would look.
    #[tokio::test]
    async fn an_unreachable_upstream_closes_the_client_connection() {
        let gone = {
            let l = TcpListener::bind("127.0.0.1:0").await.unwrap();
            l.local_addr().unwrap()
        };
        let proxy = relay(gone).await.unwrap();
        let mut c = TcpStream::connect(proxy.addr()).await.unwrap();
        let mut buf = Vec::new();
        let n = tokio::time::timeout(Duration::from_secs(30), c.read_to_end(&mut buf))
            .await
            .expect("the connection was never closed")
            .unwrap_or(0);
        assert_eq!(n, 0);
    }

    /// Dropping the handle closes the connections the proxy carries and its port.
    #[tokio::test]
    async fn dropping_the_handle_stops_the_proxy() {
        let upstream = echo_upstream().await;
        let proxy = relay(upstream).await.unwrap();
        let addr = proxy.addr();
        let mut c = TcpStream::connect(addr).await.unwrap();
        c.write_all(b"ping").await.unwrap();
        let mut got = [0u8; 4];
        c.read_exact(&mut got).await.unwrap();
        drop(proxy);
        let mut rest = Vec::new();
        let closed = tokio::time::timeout(Duration::from_secs(30), c.read_to_end(&mut rest))
            .await
            .expect("the open connection was not closed");
        assert!(!matches!(closed, Ok(n) if n > 0), "{rest:?}");
        assert!(
            TcpStream::connect(addr).await.is_err(),
            "still accepting on {addr}"
        );
    }
}
