//! Admission control for work computed per request: Cesium meshes, standard-grid and
//! PNG tiles, bootstrap bodies, and any derived output to come (RELIABILITY.md
//! "Expensive work").
//!
//! - **One computation per distinct result at a time.** Requests for a result that
//!   is being computed wait on that computation (single flight) instead of starting
//!   their own: 64 identical requests make one mesh.
//! - **Bounded.** At most [`ComputeLimits::max_compute`] computations run at once, and
//!   together they hold at most [`ComputeLimits::memory_bytes`] of working memory,
//!   each reserving its estimate before it allocates. Beyond that a computation waits
//!   in a short queue ([`ComputeLimits::queue`] computations, at most
//!   [`ComputeLimits::queue_wait`]); a full queue or a wait that runs out is a 503 with
//!   `Retry-After` and a JSON reason, never unbounded growth.
//! - **Cancelled with its last requester.** When every request waiting on a
//!   computation is gone (an HTTP/1 disconnect, an HTTP/2 `RST_STREAM`, the request
//!   timeout), a computation still queued never starts, and a running one stops at
//!   its next [`Ticket::check`]; its slot and memory are given back only when its
//!   thread has really stopped, so work in flight is bounded even under floods of
//!   cancelled requests.
//! - **Bodies that pin their memory.** A made body keeps its size reserved for as
//!   long as any response still holds it ([`Made::body`]), so clients that stop
//!   reading hold at most the budget, and later work waits or gets a 503.
//!
//! Cheap routes (stored tiles, Morton ranges, health, metrics) never come here and
//! keep their own concurrency (serve/mod.rs).

mod budget;
mod limits;
mod ticket;

pub use budget::Reservation;
pub use limits::ComputeLimits;
pub use ticket::Ticket;

use crate::http::error::ApiError;
use axum::body::Body;
use budget::MemoryPool;
use bytes::Bytes;
use futures_util::FutureExt;
use futures_util::future::{BoxFuture, WeakShared};
use prometheus::{IntCounterVec, IntGauge, IntGaugeVec, Opts, Registry};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use tokio::sync::{Notify, OwnedSemaphorePermit, Semaphore};

/// What kind of work a computation is (a label in `/metrics`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Kind {
    /// A Cesium quantized-mesh tile.
    Terrain,
    /// A standard-grid (WebMercatorQuad, WorldCRS84Quad) tile.
    GridTile,
    /// A pyramid tile as a Terrarium/Terrain-RGB PNG.
    PngTile,
    /// A bootstrap body.
    Bootstrap,
    /// A dataset's preview picture (the viewer's landing page).
    Preview,
    /// Heights of points and profiles (the elevation API).
    Elevation,
    /// A rendered terrain tile (hillshade, colour relief, slope).
    Rendered,
    /// A contour vector tile.
    Contours,
}

impl Kind {
    pub const ALL: [Kind; 8] = [
        Kind::Terrain,
        Kind::GridTile,
        Kind::PngTile,
        Kind::Bootstrap,
        Kind::Preview,
        Kind::Elevation,
        Kind::Rendered,
        Kind::Contours,
    ];

    pub fn label(self) -> &'static str {
        match self {
            Kind::Terrain => "terrain",
            Kind::GridTile => "grid_tile",
            Kind::PngTile => "png_tile",
            Kind::Bootstrap => "bootstrap",
            Kind::Preview => "preview",
            Kind::Elevation => "elevation",
            Kind::Rendered => "rendered",
            Kind::Contours => "contours",
        }
    }
}

/// Why a computation stopped before making anything.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Stop {
    /// Every request waiting on it is gone.
    Cancelled,
    /// No memory came free within the queue wait.
    Busy(String),
}

impl Stop {
    /// The answer for the requests still waiting (none, when cancelled).
    pub fn into_error(self) -> ApiError {
        match self {
            Stop::Cancelled => ApiError::unavailable("the request was cancelled"),
            Stop::Busy(why) => ApiError::busy(why, RETRY_AFTER_SECS),
        }
    }
}

/// `Retry-After` of a busy answer: a queue drains in about this long.
const RETRY_AFTER_SECS: u32 = 1;

/// A made result, shared by every request that waited on it.
#[derive(Clone, Debug)]
pub struct Made {
    pub bytes: Bytes,
    /// Tiles carried (for the request log and metrics).
    pub tiles: u64,
    /// Whether caches may keep it (not when it carries error frames).
    pub cacheable: bool,
    /// The body's size, reserved on the memory budget while anything holds it.
    hold: Option<Arc<Reservation>>,
}

impl Made {
    /// A result holding `hold` (its size on the budget) for as long as it lives.
    fn held(bytes: Bytes, tiles: u64, hold: Reservation) -> Self {
        Self {
            bytes,
            tiles,
            cacheable: true,
            hold: Some(Arc::new(hold)),
        }
    }

    /// The same, marked as not for caches.
    #[must_use]
    pub fn not_cacheable(self) -> Self {
        Self {
            cacheable: false,
            ..self
        }
    }

    /// A response body of these bytes that keeps their reservation until hyper
    /// drops it: a client that stops reading holds the budget, not more memory.
    /// Sent in 64 KiB slices (no copies), so hyper takes only what the connection's
    /// window lets through. Callers set `Content-Length`.
    pub fn body(&self) -> Body {
        const SLICE: usize = 64 << 10;
        let bytes = self.bytes.clone();
        let hold = self.hold.clone();
        let n = bytes.len();
        let slices = (0..n.div_ceil(SLICE)).map(move |i| {
            let _ = &hold;
            Ok::<_, std::convert::Infallible>(bytes.slice(i * SLICE..((i + 1) * SLICE).min(n)))
        });
        Body::from_stream(futures_util::stream::iter(slices))
    }
}

type Outcome = Result<Made, ApiError>;

/// The flights in progress, by kind and key, held weakly: a flight lives as long as
/// a request awaits it.
type Flights = HashMap<(Kind, String), WeakShared<BoxFuture<'static, Outcome>>>;

/// Sets the cancellation flag when the computation's future is dropped unfinished.
struct CancelOnDrop {
    flag: Arc<AtomicBool>,
    armed: bool,
    kind: Kind,
    cancelled: IntCounterVec,
}

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        if self.armed {
            self.flag.store(true, Ordering::Relaxed);
            self.cancelled
                .with_label_values(&[self.kind.label(), "cancelled"])
                .inc();
        }
    }
}

/// Counts a computation as queued for as long as it waits.
struct Queued<'a>(&'a AtomicUsize, &'a IntGauge);

impl Drop for Queued<'_> {
    fn drop(&mut self) {
        let n = self.0.fetch_sub(1, Ordering::SeqCst) - 1;
        self.1.set(n as i64);
    }
}

/// The computations of one server: slots, memory, the flights in progress.
pub struct Compute {
    pub limits: ComputeLimits,
    slots: Arc<Semaphore>,
    pool: Arc<MemoryPool>,
    waiting: AtomicUsize,
    flights: Mutex<Flights>,
    /// `tessera_compute_total{kind, outcome=started|joined|busy|cancelled}`.
    outcomes: IntCounterVec,
    /// `tessera_compute_running{kind}`.
    running: IntGaugeVec,
    /// `tessera_compute_queued`.
    queued: IntGauge,
}

impl std::fmt::Debug for Compute {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Compute")
            .field("limits", &self.limits)
            .field("waiting", &self.waiting)
            .finish_non_exhaustive()
    }
}

impl Compute {
    /// Empty, with its metrics registered in `registry`.
    pub fn new(limits: ComputeLimits, registry: &Registry) -> Self {
        let outcomes = IntCounterVec::new(
            Opts::new(
                "tessera_compute_total",
                "Computed responses (Cesium meshes, grid and PNG tiles, bootstrap bodies, previews) by kind and outcome: started (a computation admitted), joined (a request that waited on one already in flight), busy (503: queue full or memory not freed in time), cancelled (every requester gone before it ended)",
            ),
            &["kind", "outcome"],
        )
        .expect("valid metric");
        let running = IntGaugeVec::new(
            Opts::new(
                "tessera_compute_running",
                "Computations holding a slot now, by kind",
            ),
            &["kind"],
        )
        .expect("valid metric");
        let queued = IntGauge::new(
            "tessera_compute_queued",
            "Computations waiting for a slot now",
        )
        .expect("valid metric");
        let memory = IntGauge::new(
            "tessera_compute_memory_bytes",
            "Bytes reserved by running computations and by computed bodies responses still hold",
        )
        .expect("valid metric");
        let memory_limit = IntGauge::new(
            "tessera_compute_memory_limit_bytes",
            "The memory budget of computed responses (--max-compute-mib)",
        )
        .expect("valid metric");
        memory_limit.set(i64::try_from(limits.memory_bytes).unwrap_or(i64::MAX));
        for m in [
            Box::new(outcomes.clone()) as Box<dyn prometheus::core::Collector>,
            Box::new(running.clone()),
            Box::new(queued.clone()),
            Box::new(memory.clone()),
            Box::new(memory_limit),
        ] {
            registry.register(m).expect("metric names are unique");
        }
        for kind in Kind::ALL {
            running.with_label_values(&[kind.label()]).set(0);
            for outcome in ["started", "joined", "busy", "cancelled"] {
                outcomes
                    .with_label_values(&[kind.label(), outcome])
                    .inc_by(0);
            }
        }
        Self {
            slots: Arc::new(Semaphore::new(limits.max_compute)),
            pool: Arc::new(MemoryPool {
                limit: limits.memory_bytes.max(1),
                used: Mutex::new(0),
                freed: Condvar::new(),
                notify: Notify::new(),
                gauge: memory,
            }),
            limits,
            waiting: AtomicUsize::new(0),
            flights: Mutex::new(HashMap::new()),
            outcomes,
            running,
            queued,
        }
    }

    fn count(&self, kind: Kind, outcome: &str) {
        self.outcomes
            .with_label_values(&[kind.label(), outcome])
            .inc();
    }

    /// The result `key` of `kind`: the one being computed now if there is one, else
    /// made by `work` once admitted. `key` must name everything the result depends
    /// on (dataset version, tile, options).
    pub async fn run<F, Fut>(self: &Arc<Self>, kind: Kind, key: String, work: F) -> Outcome
    where
        F: FnOnce(Ticket) -> Fut + Send + 'static,
        Fut: Future<Output = Outcome> + Send + 'static,
    {
        let id = (kind, key);
        let flight = {
            let mut flights = self.flights.lock().unwrap_or_else(PoisonError::into_inner);
            if let Some(f) = flights.get(&id).and_then(WeakShared::upgrade) {
                self.count(kind, "joined");
                f
            } else {
                let f = self.clone().start(kind, work).boxed().shared();
                if flights.len() >= 4 * self.limits.queue + 64 {
                    // Flights whose requesters all left stay as dead entries until
                    // their key comes back; sweep them before the map grows.
                    flights.retain(|_, w| w.upgrade().is_some());
                }
                flights.insert(id.clone(), f.downgrade().expect("not yet polled"));
                f
            }
        };
        let out = flight.clone().await;
        let mut flights = self.flights.lock().unwrap_or_else(PoisonError::into_inner);
        if flights
            .get(&id)
            .and_then(WeakShared::upgrade)
            .is_some_and(|f| f.ptr_eq(&flight))
        {
            flights.remove(&id);
        }
        out
    }

    /// [`Compute::run`] for CPU-bound work, done on a blocking thread that holds the
    /// ticket (so the slot comes back only when the thread is done).
    pub async fn run_blocking<F>(self: &Arc<Self>, kind: Kind, key: String, work: F) -> Outcome
    where
        F: FnOnce(&Ticket) -> Outcome + Send + 'static,
    {
        self.run(kind, key, move |ticket| async move {
            ticket.blocking(work).await?
        })
        .await
    }

    /// Waits for admission, then runs `work`; dropped unfinished, it cancels.
    async fn start<F, Fut>(self: Arc<Self>, kind: Kind, work: F) -> Outcome
    where
        F: FnOnce(Ticket) -> Fut + Send + 'static,
        Fut: Future<Output = Outcome> + Send + 'static,
    {
        let flag = Arc::new(AtomicBool::new(false));
        let mut guard = CancelOnDrop {
            flag: flag.clone(),
            armed: true,
            kind,
            cancelled: self.outcomes.clone(),
        };
        let slot = match self.slots.clone().try_acquire_owned() {
            Ok(slot) => slot,
            Err(_) => self.queue(kind).await?,
        };
        self.count(kind, "started");
        self.running.with_label_values(&[kind.label()]).inc();
        let ticket = Ticket {
            _slot: slot,
            cancelled: flag,
            pool: self.pool.clone(),
            wait: self.limits.queue_wait,
            kind,
            running: self.running.clone(),
        };
        let out = work(ticket).await;
        guard.armed = false;
        if let Err(e) = &out
            && e.retry_after.is_some()
        {
            self.count(kind, "busy");
        }
        out
    }

    /// Waits in the queue for a slot, or refuses when the queue is full or the wait
    /// runs out.
    async fn queue(&self, kind: Kind) -> Result<OwnedSemaphorePermit, ApiError> {
        let busy = |why: String| {
            self.count(kind, "busy");
            Err(ApiError::busy(why, RETRY_AFTER_SECS))
        };
        let n = self.waiting.fetch_add(1, Ordering::SeqCst) + 1;
        self.queued.set(n as i64);
        let _queued = Queued(&self.waiting, &self.queued);
        if n > self.limits.queue {
            return busy(format!(
                "the server is computing {} responses and {} more are waiting (--max-compute, --compute-queue); retry shortly",
                self.limits.max_compute, self.limits.queue
            ));
        }
        match tokio::time::timeout(self.limits.queue_wait, self.slots.clone().acquire_owned()).await
        {
            Ok(Ok(slot)) => Ok(slot),
            Ok(Err(_)) => Err(ApiError::internal("the compute slots are closed")),
            Err(_) => busy(format!(
                "waited {} s for one of {} compute slots (--compute-queue-secs); retry shortly",
                self.limits.queue_wait.as_secs_f64(),
                self.limits.max_compute
            )),
        }
    }

    /// A result found in a cache, its size reserved (without waiting) for as long as
    /// a response holds it, as a made result's is: clients that stop reading pin at
    /// most the budget, cached or not. A full budget is a 503 with `Retry-After`.
    pub fn hit(&self, kind: Kind, bytes: Bytes, tiles: u64) -> Outcome {
        let Some(hold) = self.pool.try_reserve(bytes.len() as u64) else {
            self.count(kind, "busy");
            return Err(ApiError::busy(
                format!(
                    "the server is at its memory limit for computed responses ({} MiB), held by responses not yet read; retry shortly",
                    self.pool.limit >> 20
                ),
                RETRY_AFTER_SECS,
            ));
        };
        Ok(Made::held(bytes, tiles, hold))
    }

    /// Bytes reserved now (running work and held bodies).
    pub fn memory_used(&self) -> u64 {
        *self
            .pool
            .used
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use std::sync::atomic::AtomicU32;
    use std::time::Duration;

    pub(super) fn limits(max_compute: usize, memory: u64, queue: usize) -> ComputeLimits {
        ComputeLimits {
            max_compute,
            memory_bytes: memory,
            queue,
            queue_wait: Duration::from_secs(5),
        }
    }

    pub(super) fn compute(l: ComputeLimits) -> (Arc<Compute>, Registry) {
        let r = Registry::new();
        (Arc::new(Compute::new(l, &r)), r)
    }

    fn metric(r: &Registry, kind: &str, outcome: &str) -> u64 {
        r.gather()
            .iter()
            .filter(|f| f.name() == "tessera_compute_total")
            .flat_map(prometheus::proto::MetricFamily::get_metric)
            .find(|m| {
                let l = m.get_label();
                l.iter().any(|p| p.value() == kind) && l.iter().any(|p| p.value() == outcome)
            })
            .map_or(0, |m| m.get_counter().get_value() as u64)
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn identical_requests_share_one_computation() {
        let (c, r) = compute(limits(2, 1 << 20, 8));
        let runs = Arc::new(AtomicU32::new(0));
        let release = Arc::new(Notify::new());
        let mut tasks = Vec::new();
        for _ in 0..16 {
            let (c, runs, release) = (c.clone(), runs.clone(), release.clone());
            tasks.push(tokio::spawn(async move {
                c.run(Kind::Terrain, "a".into(), move |t| async move {
                    runs.fetch_add(1, Ordering::SeqCst);
                    release.notified().await;
                    Ok(t.made(Bytes::from_static(b"mesh"), 1))
                })
                .await
            }));
        }
        // Every request has joined before the one computation is let finish.
        while metric(&r, "terrain", "joined") < 15 {
            tokio::task::yield_now().await;
        }
        release.notify_waiters();
        for t in tasks {
            assert_eq!(&t.await.unwrap().unwrap().bytes[..], b"mesh");
        }
        assert_eq!(runs.load(Ordering::SeqCst), 1);
        assert_eq!(metric(&r, "terrain", "started"), 1);
        assert_eq!(metric(&r, "terrain", "joined"), 15);
        // The flight is gone: the next request computes again.
        let again = c
            .run(Kind::Terrain, "a".into(), |t| async move {
                Ok(t.made(Bytes::from_static(b"two"), 1))
            })
            .await
            .unwrap();
        assert_eq!(&again.bytes[..], b"two");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_full_queue_answers_busy_with_retry_after() {
        let (c, r) = compute(limits(1, 1 << 20, 2));
        let hold = Arc::new(Semaphore::new(0));
        let mut tasks = Vec::new();
        for i in 0..3 {
            let (c, hold) = (c.clone(), hold.clone());
            tasks.push(tokio::spawn(async move {
                c.run(Kind::GridTile, format!("t{i}"), move |t| async move {
                    let _p = hold.acquire().await;
                    Ok(t.made(Bytes::new(), 0))
                })
                .await
            }));
        }
        // One running, two queued: the queue is full.
        while c.waiting.load(Ordering::SeqCst) < 2 {
            tokio::task::yield_now().await;
        }
        let refused = c
            .run(Kind::GridTile, "t9".into(), |t| async move {
                Ok(t.made(Bytes::new(), 0))
            })
            .await
            .unwrap_err();
        assert_eq!(refused.status, axum::http::StatusCode::SERVICE_UNAVAILABLE);
        assert_eq!(refused.retry_after, Some(1));
        assert!(
            refused.message.contains("--compute-queue"),
            "{}",
            refused.message
        );
        assert_eq!(metric(&r, "grid_tile", "busy"), 1);
        hold.add_permits(3);
        for t in tasks {
            t.await.unwrap().unwrap();
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_dropped_request_stops_its_work_and_queued_work_never_starts() {
        let (c, r) = compute(limits(1, 1 << 20, 8));
        let steps = Arc::new(AtomicU32::new(0));
        let started = Arc::new(AtomicU32::new(0));
        // A running computation that checks for cancellation at every step.
        let running = {
            let (c, steps, started) = (c.clone(), steps.clone(), started.clone());
            tokio::spawn(async move {
                c.run(Kind::Terrain, "long".into(), move |t| async move {
                    started.fetch_add(1, Ordering::SeqCst);
                    t.blocking(move |t| {
                        for _ in 0..100_000 {
                            if let Err(s) = t.check() {
                                return Err(s.into_error());
                            }
                            steps.fetch_add(1, Ordering::SeqCst);
                            std::thread::sleep(Duration::from_millis(1));
                        }
                        Ok(t.made(Bytes::new(), 0))
                    })
                    .await?
                })
                .await
            })
        };
        while steps.load(Ordering::SeqCst) == 0 {
            tokio::task::yield_now().await;
        }
        // A second computation queued behind it.
        let queued = {
            let (c, started) = (c.clone(), started.clone());
            tokio::spawn(async move {
                c.run(Kind::Terrain, "next".into(), move |t| async move {
                    started.fetch_add(1, Ordering::SeqCst);
                    Ok(t.made(Bytes::new(), 0))
                })
                .await
            })
        };
        while c.waiting.load(Ordering::SeqCst) == 0 {
            tokio::task::yield_now().await;
        }
        queued.abort();
        running.abort();
        // The running one stops at its next check and gives its slot back.
        let _slot = tokio::time::timeout(Duration::from_secs(30), c.slots.clone().acquire_owned())
            .await
            .expect("the slot comes back")
            .unwrap();
        let at_stop = steps.load(Ordering::SeqCst);
        assert!(at_stop < 100_000, "it ran to the end");
        std::thread::sleep(Duration::from_millis(50));
        assert_eq!(
            steps.load(Ordering::SeqCst),
            at_stop,
            "it goes on after its slot came back"
        );
        assert_eq!(started.load(Ordering::SeqCst), 1, "the queued one started");
        assert_eq!(metric(&r, "terrain", "cancelled"), 2);
    }
}
