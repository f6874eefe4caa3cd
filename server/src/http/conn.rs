//! Connections: our own accept loop around hyper's connection driver (HTTP/1.1 and
//! HTTP/2 on one port: h2c with prior knowledge in the clear, h2 or http/1.1 by ALPN
//! under TLS), so that no client can hold the server's resources for free
//! (docs/ARCHITECTURE.md#the-service-stays-up).
//!
//! - **Header timeout**: a connection must deliver a complete request head within
//!   this time of opening, or of its previous response ending; otherwise it is
//!   closed. This closes slowloris clients (who dribble a header byte at a time) and
//!   idle keep-alive connections alike. For HTTP/1.1 hyper's `header_read_timeout`
//!   does it; for every protocol (HTTP/2, and a connection that has not yet said
//!   which it speaks) so does our loop: a connection with no request in progress
//!   whose last request started or ended this long ago is closed (HTTP/2: with a
//!   GOAWAY, so the client knows no request was lost; a second period later, hard).
//!   A TLS handshake must also finish within it.
//! - **Idle timeout**: a connection on which no byte has moved either way for this
//!   long, while no handler is working on one of its requests, is closed (e.g. a
//!   client that stopped reading a large response).
//! - **Connection cap**, below the open-file limit: at the cap, the least recently
//!   active connection that has no request in progress is closed to make room; if
//!   every connection is busy, the newcomer gets a `503` and is closed.
//! - **Accept errors** (out of descriptors above all) never end the loop: it backs off
//!   (10 ms doubling to 1 s), frees an idle connection when descriptors ran out, and
//!   tries again.
//! - **Graceful shutdown**: the listener is closed, idle connections are closed,
//!   responses in progress are finished, then [`serve`] returns.
//! - **The HTTP layer's own errors**: hyper answers a request head it cannot parse
//!   itself, before any of our code runs — 414 for a request target over 65 534 bytes
//!   (a limit fixed in hyper and in the `http` crate's `Uri`), 431 for a head over
//!   its read buffer, 400 for a malformed one — with an empty body. Each connection
//!   is wrapped in `own_errors::OwnErrors`, which replaces those answers with the
//!   same status, a JSON reason and the CORS headers every other error carries.
//! - **HTTP/2 limits**: at most [`H2_MAX_STREAMS`] concurrent streams per connection
//!   and [`H2_MAX_HEADER_LIST`] bytes of request headers. No keep-alive PINGs: their
//!   answers would count as bytes moving and keep a stalled connection from ever
//!   reaching the idle timeout; idle HTTP/2 connections are closed by the header
//!   timeout rule above instead, like idle HTTP/1.1 ones.

use super::conventions::CorsOrigins;
use super::own_errors::{OwnCors, OwnErrors, own_response};
use axum::Router;
use axum::body::Body;
use hyper::body::{Frame, Incoming, SizeHint};
use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
use hyper_util::server::conn::auto;
use std::collections::HashMap;
use std::io;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{Notify, mpsc, watch};
use tower::ServiceExt;

/// Concurrent streams one HTTP/2 connection may open.
pub const H2_MAX_STREAMS: u32 = 256;
/// Bytes of request headers (decoded, as HTTP/2 counts them) one HTTP/2 request may carry.
pub const H2_MAX_HEADER_LIST: u32 = 256 * 1024;

/// What the connection layer enforces.
#[derive(Debug, Clone, Copy)]
pub struct ConnLimits {
    pub header_timeout: Duration,
    pub idle_timeout: Duration,
    pub max_connections: usize,
    /// The CORS headers of the answers this layer writes itself.
    pub cors: OwnCors,
}

/// Descriptors kept free of connections: stdio, the listener, the runtime's own, the
/// dataset files (twice over while a reload opens the new ones beside the old), and
/// slack for the accept that finds the table full.
fn fd_reserve(datasets: usize) -> u64 {
    64 + 2 * datasets as u64
}

impl ConnLimits {
    /// The limits asked for (`max_connections`: `None` to derive it), the connection
    /// cap clamped below the process's open-file limit, which `datasets` open files
    /// share.
    pub fn new(
        header_timeout: Duration,
        idle_timeout: Duration,
        max_connections: Option<usize>,
        cors: &CorsOrigins,
        datasets: usize,
    ) -> anyhow::Result<Self> {
        let fd_limit = open_file_limit();
        let room = fd_limit.map(|l| usize::try_from(l.saturating_sub(fd_reserve(datasets))));
        let room = room.map(|r| r.unwrap_or(usize::MAX));
        let max_connections = match (max_connections, room) {
            (Some(n), Some(room)) if n > room => {
                tracing::warn!(
                    requested = n,
                    allowed = room,
                    "--max-connections is above what the open-file limit allows; using the lower value (raise `ulimit -n` for more)"
                );
                room
            }
            (Some(n), _) => n,
            (None, Some(room)) => room,
            (None, None) => 1024,
        };
        anyhow::ensure!(
            max_connections >= 1,
            "the open-file limit ({}) leaves no descriptors for connections after the {} the server needs; raise `ulimit -n`",
            fd_limit.unwrap_or(0),
            fd_reserve(datasets)
        );
        tracing::info!(
            max_connections,
            header_timeout_s = header_timeout.as_secs(),
            idle_timeout_s = idle_timeout.as_secs(),
            "connection limits"
        );
        Ok(Self {
            header_timeout,
            idle_timeout,
            max_connections,
            cors: OwnCors::of(cors),
        })
    }
}

/// The soft `RLIMIT_NOFILE`, read from `/proc/self/limits` (no `unsafe` needed);
/// `None` where it is unlimited or cannot be read.
fn open_file_limit() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/limits").ok()?;
    let line = text.lines().find(|l| l.starts_with("Max open files"))?;
    line["Max open files".len()..]
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// One open connection's bookkeeping.
#[derive(Debug)]
struct Conn {
    /// Milliseconds since [`Table::epoch`] when a byte last moved either way (or a
    /// response ended).
    last_active: AtomicU64,
    /// Requests from dispatch until their response body is finished or dropped.
    busy: AtomicUsize,
    /// Requests whose handler has not produced a response head yet.
    handling: AtomicUsize,
    /// Milliseconds since [`Table::epoch`] when a request last started or ended (or
    /// the connection opened): the header timeout counts from here.
    last_request: AtomicU64,
    /// Whether a request came over HTTP/2 (then an idle close sends a GOAWAY).
    h2: AtomicBool,
    /// Set once the connection has been told to close (so it is not picked twice).
    closing: AtomicBool,
    close: Notify,
    epoch: Instant,
}

impl Conn {
    fn touch(&self) {
        self.last_active
            .store(self.epoch.elapsed().as_millis() as u64, Ordering::Relaxed);
    }

    fn idle_for(&self) -> Duration {
        let now = self.epoch.elapsed().as_millis() as u64;
        Duration::from_millis(now.saturating_sub(self.last_active.load(Ordering::Relaxed)))
    }

    fn request_event(&self) {
        self.last_request
            .store(self.epoch.elapsed().as_millis() as u64, Ordering::Relaxed);
    }

    /// Time since a request last started or ended, or `None` while one is in progress.
    fn without_request_for(&self) -> Option<Duration> {
        if self.busy.load(Ordering::Relaxed) > 0 {
            return None;
        }
        let now = self.epoch.elapsed().as_millis() as u64;
        Some(Duration::from_millis(
            now.saturating_sub(self.last_request.load(Ordering::Relaxed)),
        ))
    }
}

/// Every open connection, by id.
#[derive(Debug)]
struct Table {
    conns: Mutex<HashMap<u64, Arc<Conn>>>,
    epoch: Instant,
}

impl Table {
    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<u64, Arc<Conn>>> {
        self.conns.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Open connections not already told to close.
    fn open(&self) -> usize {
        self.lock()
            .values()
            .filter(|c| !c.closing.load(Ordering::Relaxed))
            .count()
    }

    /// Tells the least recently active connection without a request in progress to
    /// close; `false` if every connection is busy.
    fn evict_oldest_idle(&self) -> bool {
        let conns = self.lock();
        let victim = conns
            .values()
            .filter(|c| !c.closing.load(Ordering::Relaxed) && c.busy.load(Ordering::Relaxed) == 0)
            .min_by_key(|c| c.last_active.load(Ordering::Relaxed));
        match victim {
            Some(c) => {
                c.closing.store(true, Ordering::Relaxed);
                c.close.notify_one();
                true
            }
            None => false,
        }
    }
}

/// Counts one request as in progress on its connection until dropped (when hyper has
/// finished with the response body, or the request was abandoned).
struct Busy {
    conn: Arc<Conn>,
    handling: bool,
}

impl Busy {
    fn new(conn: Arc<Conn>) -> Self {
        conn.busy.fetch_add(1, Ordering::Relaxed);
        conn.handling.fetch_add(1, Ordering::Relaxed);
        conn.request_event();
        Self {
            conn,
            handling: true,
        }
    }

    fn head_ready(&mut self) {
        if std::mem::take(&mut self.handling) {
            self.conn.handling.fetch_sub(1, Ordering::Relaxed);
        }
    }
}

impl Drop for Busy {
    fn drop(&mut self) {
        self.head_ready();
        self.conn.busy.fetch_sub(1, Ordering::Relaxed);
        // Idle time and the header timeout count from the end of the response.
        self.conn.touch();
        self.conn.request_event();
    }
}

/// A response body that holds its request's [`Busy`] until it is done.
struct TrackedBody {
    inner: Body,
    _busy: Busy,
}

impl hyper::body::Body for TrackedBody {
    type Data = bytes::Bytes;
    type Error = axum::Error;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Self::Data>, Self::Error>>> {
        Pin::new(&mut self.get_mut().inner).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}

/// A socket that notes on its [`Conn`] every time bytes move.
struct Tracked<S> {
    inner: S,
    conn: Arc<Conn>,
}

impl<S: AsyncRead + Unpin> AsyncRead for Tracked<S> {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let before = buf.filled().len();
        let r = Pin::new(&mut this.inner).poll_read(cx, buf);
        if matches!(r, Poll::Ready(Ok(()))) && buf.filled().len() > before {
            this.conn.touch();
        }
        r
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Tracked<S> {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let r = Pin::new(&mut this.inner).poll_write(cx, buf);
        if matches!(r, Poll::Ready(Ok(n)) if n > 0) {
            this.conn.touch();
        }
        r
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let r = Pin::new(&mut this.inner).poll_write_vectored(cx, bufs);
        if matches!(r, Poll::Ready(Ok(n)) if n > 0) {
            this.conn.touch();
        }
        r
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_shutdown(cx)
    }
}

/// Whether an accept error means the process (or system) is out of descriptors.
fn out_of_descriptors(e: &io::Error) -> bool {
    // EMFILE (24) and ENFILE (23) on Linux and the BSDs.
    matches!(e.raw_os_error(), Some(23 | 24))
}

/// Answers a connection we have no room for with a 503 and closes it. A best-effort,
/// non-blocking write: a client that is not reading just sees the close.
fn refuse(stream: &TcpStream, cors: OwnCors) {
    let msg = own_response(
        "503 Service Unavailable",
        "too many open connections; try again later",
        &format!("retry-after: 1\r\n{}", cors.header_lines()),
    );
    let _ = stream.try_write(&msg);
}

/// Accepts connections on `listener` and serves `router` on them (over TLS with `tls`)
/// until `shutdown` resolves, then closes the listener and waits for the responses in
/// progress.
pub async fn serve(
    listener: TcpListener,
    router: Router,
    limits: ConnLimits,
    tls: Option<Arc<rustls::ServerConfig>>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) {
    let tls = tls.map(tokio_rustls::TlsAcceptor::from);
    let table = Arc::new(Table {
        conns: Mutex::new(HashMap::new()),
        epoch: Instant::now(),
    });
    let (stop_tx, stop_rx) = watch::channel(false);
    // Each connection task holds a sender; `recv` returns `None` once all are gone.
    let (done_tx, mut done_rx) = mpsc::channel::<()>(1);
    let mut next_id = 0u64;
    let mut backoff = Duration::ZERO;
    tokio::pin!(shutdown);
    loop {
        let accepted = tokio::select! {
            () = &mut shutdown => break,
            r = listener.accept() => r,
        };
        let stream = match accepted {
            Ok((stream, _peer)) => {
                backoff = Duration::ZERO;
                // Responses go out as hyper writes them: with Nagle's algorithm on, a
                // response's last small segment waits for the client's delayed ACK
                // (~40 ms on Linux) whenever an earlier segment is unacknowledged,
                // which `tessera load --replay` saw as a 40 ms p99 on busy
                // connections (and HTTP/2 answers, which interleave small frames, at
                // every percentile).
                if let Err(e) = stream.set_nodelay(true) {
                    tracing::debug!(error = %e, "cannot set TCP_NODELAY");
                }
                stream
            }
            Err(e) => {
                let fds = out_of_descriptors(&e);
                if fds {
                    table.evict_oldest_idle();
                }
                backoff = (backoff * 2).clamp(Duration::from_millis(10), Duration::from_secs(1));
                tracing::warn!(error = %e, retry_ms = backoff.as_millis() as u64, out_of_descriptors = fds, "accept failed; backing off");
                tokio::select! {
                    () = &mut shutdown => break,
                    () = tokio::time::sleep(backoff) => continue,
                }
            }
        };
        if table.open() >= limits.max_connections && !table.evict_oldest_idle() {
            tracing::warn!(
                max_connections = limits.max_connections,
                "connection cap reached and every connection is busy; refusing a new one"
            );
            // A TLS client would read a plain-text answer as garbage: just close.
            if tls.is_none() {
                refuse(&stream, limits.cors);
            }
            continue;
        }
        let conn = Arc::new(Conn {
            last_active: AtomicU64::new(0),
            last_request: AtomicU64::new(0),
            h2: AtomicBool::new(false),
            busy: AtomicUsize::new(0),
            handling: AtomicUsize::new(0),
            closing: AtomicBool::new(false),
            close: Notify::new(),
            epoch: table.epoch,
        });
        conn.touch();
        conn.request_event();
        let id = next_id;
        next_id += 1;
        table.lock().insert(id, conn.clone());
        let task = ConnTask {
            conn,
            router: router.clone(),
            limits,
            tls: tls.clone(),
            stop: stop_rx.clone(),
            _done: done_tx.clone(),
        };
        let table = table.clone();
        tokio::spawn(async move {
            task.run(stream).await;
            table.lock().remove(&id);
        });
    }
    // New connections are refused from here on.
    drop(listener);
    let _ = stop_tx.send(true);
    drop(done_tx);
    let _ = done_rx.recv().await;
}

struct ConnTask {
    conn: Arc<Conn>,
    router: Router,
    limits: ConnLimits,
    tls: Option<tokio_rustls::TlsAcceptor>,
    stop: watch::Receiver<bool>,
    _done: mpsc::Sender<()>,
}

impl ConnTask {
    async fn run(self, stream: TcpStream) {
        let tracked = Tracked {
            inner: stream,
            conn: self.conn.clone(),
        };
        let Some(acceptor) = self.tls.clone() else {
            return self.drive(tracked).await;
        };
        // The handshake counts against the header timeout: a client that stalls in it
        // holds the connection no longer than one that stalls in its request head.
        let handshake = tokio::time::timeout(self.limits.header_timeout, acceptor.accept(tracked));
        let tls = tokio::select! {
            r = handshake => r,
            () = self.conn.close.notified() => return,
        };
        match tls {
            Ok(Ok(tls)) => self.drive(tls).await,
            Ok(Err(e)) => tracing::debug!(error = %e, "TLS handshake failed"),
            Err(_) => {
                tracing::debug!("TLS handshake not finished within the header timeout; closing");
            }
        }
    }

    /// Serves HTTP on `io` (HTTP/1.1 or HTTP/2, whichever the client speaks) until the
    /// connection ends, is evicted, goes idle, or the server shuts down.
    async fn drive<I>(mut self, io: I)
    where
        I: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        let conn = self.conn.clone();
        let router = self.router.clone();
        let service = hyper::service::service_fn(move |req: hyper::Request<Incoming>| {
            let router = router.clone();
            if req.version() == hyper::Version::HTTP_2 {
                conn.h2.store(true, Ordering::Relaxed);
            }
            let mut busy = Busy::new(conn.clone());
            async move {
                let response = router.oneshot(req).await;
                busy.head_ready();
                response.map(|r| r.map(|inner| TrackedBody { inner, _busy: busy }))
            }
        });
        let io = TokioIo::new(OwnErrors::new(io, self.limits.cors));
        let mut builder = auto::Builder::new(TokioExecutor::new());
        builder
            .http1()
            .timer(TokioTimer::new())
            .header_read_timeout(self.limits.header_timeout);
        builder
            .http2()
            .timer(TokioTimer::new())
            .max_concurrent_streams(H2_MAX_STREAMS)
            .max_header_list_size(H2_MAX_HEADER_LIST)
            .keep_alive_interval(None);
        let http = builder.serve_connection(io, service);
        tokio::pin!(http);
        let mut draining = false;
        if *self.stop.borrow() {
            http.as_mut().graceful_shutdown();
            draining = true;
        }
        loop {
            let idle_left = self
                .limits
                .idle_timeout
                .saturating_sub(self.conn.idle_for());
            let header_left = self
                .conn
                .without_request_for()
                .map_or(self.limits.header_timeout, |quiet| {
                    self.limits.header_timeout.saturating_sub(quiet)
                });
            tokio::select! {
                r = http.as_mut() => {
                    if let Err(e) = r {
                        tracing::debug!(error = %e, "connection ended");
                    }
                    return;
                }
                // Evicted to make room: close now (it had no request in progress).
                () = self.conn.close.notified() => return,
                _ = self.stop.changed(), if !draining => {
                    draining = true;
                    http.as_mut().graceful_shutdown();
                }
                () = tokio::time::sleep(header_left), if header_left < idle_left => {
                    let quiet = self.conn.without_request_for();
                    if quiet.is_some_and(|q| q >= self.limits.header_timeout) {
                        if self.conn.h2.load(Ordering::Relaxed) && !draining {
                            tracing::debug!("closing an HTTP/2 connection with no request for the header timeout");
                            draining = true;
                            http.as_mut().graceful_shutdown();
                            // The GOAWAY's own grace period counts from now.
                            self.conn.request_event();
                        } else {
                            tracing::debug!("closing a connection with no request for the header timeout");
                            return;
                        }
                    }
                }
                () = tokio::time::sleep(idle_left), if idle_left <= header_left => {
                    let idle = self.conn.idle_for() >= self.limits.idle_timeout;
                    if idle && self.conn.handling.load(Ordering::Relaxed) == 0 {
                        tracing::debug!("closing a connection idle for the idle timeout");
                        return;
                    }
                    if idle {
                        // A handler is still working (bounded by --timeout-secs):
                        // look again after another idle period.
                        self.conn.touch();
                    }
                }
            }
        }
    }
}
