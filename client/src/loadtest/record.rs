//! `tessera load --record TRACE` (DECISIONS.md "Load testing: replay"): the requests the
//! full clients send, collected as they go into a [`Trace`] for `--replay`.
//!
//! One [`Recorder`] is shared by every simulated client of a load run; each client's
//! streamer carries it in a [`RecordHook`] (its [`crate::stream::StreamConfig::record`],
//! with the client's index). The streaming code registers a request when it is about
//! to be sent ([`RecordHook::sent`]: client, time since the recording started, kind,
//! target, level) and completes it ([`Recording::complete`]) once the client has read
//! its answer in full and taken it as an answer:
//!
//! - a frame stream (`tiles`, `imagery`): a 2xx whose stream ended well-formed; its
//!   [`Expect`] counts the tile frames and digests them ([`StreamDigest`], fed every
//!   frame the client decoded);
//! - a single tile: a 200 whose record matched its checksum header, or the 404 of an
//!   absent tile; the bootstrap: a 2xx, or the 404 of a server without the route;
//!   the document: a 2xx. Their bodies are digested whole ([`body_digest`](super::trace::body_digest)).
//!
//! Anything else — cancelled, failed (no connection, timeout, an HTTP error the
//! client treats as a failure, a broken or corrupt stream), or still in flight when
//! the run ended — keeps `expect: None`: a replay only checks it for a 2xx and a
//! well-formed stream.
//!
//! Cost: a mutex push per request, a digest update per frame, nothing at all when no
//! recorder is set (`tessera fly`, `tessera load` without `--record`). The clients'
//! requests and their timing are the same with and without it.

use super::trace::{
    Expect, RequestKind, StreamDigest, TRACE_VERSION, Trace, TraceHeader, TraceRequest,
};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Instant;
use tessera_shared::Level;

/// The requests of one recording, from every client; shared (`Arc`) by their
/// streamers, safe to use from any thread.
pub struct Recorder {
    started: Instant,
    /// The server base URL, without a trailing `/`: targets are relative to it.
    base: String,
    requests: Mutex<Vec<TraceRequest>>,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("base", &self.base)
            .field("requests", &self.lock().len())
            .finish_non_exhaustive()
    }
}

impl Recorder {
    /// A recording of requests to the server at `base` (e.g. `http://127.0.0.1:8080`),
    /// starting now: request times are milliseconds after this.
    pub fn new(base: &str) -> Arc<Self> {
        Arc::new(Self {
            started: Instant::now(),
            base: base.trim_end_matches('/').to_string(),
            requests: Mutex::new(Vec::new()),
        })
    }

    /// The server base URL targets are relative to.
    pub fn base(&self) -> &str {
        &self.base
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<TraceRequest>> {
        // A client that panicked mid-push cannot leave a half-written request (the
        // push is one call), so a poisoned lock still holds a consistent list.
        self.requests.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The path and query of `url`, relative to the server base: what a replay
    /// appends to its `--server`. A URL outside the base (none the streamer makes)
    /// keeps its path and query.
    pub fn target(&self, url: &str) -> String {
        if let Some(rest) = url.strip_prefix(&self.base)
            && rest.starts_with('/')
        {
            return rest.to_string();
        }
        match reqwest::Url::parse(url) {
            Ok(u) => match u.query() {
                Some(q) => format!("{}?{q}", u.path()),
                None => u.path().to_string(),
            },
            Err(_) => url.to_string(),
        }
    }

    /// Registers a request `client` is sending now; complete it with the handle.
    pub fn sent(
        self: &Arc<Self>,
        client: u32,
        kind: RequestKind,
        url: &str,
        level: Option<Level>,
    ) -> Recording {
        let request = TraceRequest {
            client,
            t_ms: self.started.elapsed().as_secs_f64() * 1e3,
            kind,
            target: self.target(url),
            level: level.map(Level::get),
            expect: None,
        };
        let mut requests = self.lock();
        requests.push(request);
        Recording {
            recorder: self.clone(),
            index: requests.len() - 1,
        }
    }

    /// The trace so far, in the order the requests were sent (stable: requests
    /// registered at the same millisecond keep their order). The time stamps are
    /// taken before the lock, so two clients can push out of time order; the sort
    /// puts them back.
    pub fn trace(&self, dataset: &str, clients: u32, seconds: f64, mode: &str) -> Trace {
        let mut requests = self.lock().clone();
        requests.sort_by(|a, b| a.t_ms.total_cmp(&b.t_ms));
        Trace {
            header: TraceHeader {
                tessera_trace: TRACE_VERSION,
                server: self.base.clone(),
                dataset: dataset.to_string(),
                clients,
                seconds,
                mode: mode.to_string(),
            },
            requests,
        }
    }
}

/// A registered request, to complete when its answer has been read in full.
/// Dropped without completing, the request keeps `expect: None`.
#[derive(Debug)]
pub struct Recording {
    recorder: Arc<Recorder>,
    index: usize,
}

impl Recording {
    /// The answer: `status`, body `bytes`, and its digest.
    pub fn complete(self, expect: Expect) {
        if let Some(r) = self.recorder.lock().get_mut(self.index) {
            r.expect = Some(expect);
        }
    }

    /// Completes a frame stream's request from the digest of its frames.
    pub fn complete_stream(self, status: u16, bytes: u64, digest: &StreamDigest) {
        self.complete(Expect {
            status,
            tiles: digest.tiles(),
            bytes,
            digest: digest.hex(),
        });
    }

    /// Completes a request whose body is not a frame stream.
    pub fn complete_body(self, status: u16, body: &[u8]) {
        self.complete(Expect {
            status,
            tiles: 0,
            bytes: body.len() as u64,
            digest: super::trace::body_digest(body),
        });
    }
}

/// What a client's streamer records with: the shared recorder and the client's index.
#[derive(Clone, Debug)]
pub struct RecordHook {
    pub recorder: Arc<Recorder>,
    pub client: u32,
}

impl RecordHook {
    pub fn new(recorder: Arc<Recorder>, client: u32) -> Self {
        Self { recorder, client }
    }

    /// Registers a request this client is sending now to `url`.
    pub fn sent(&self, kind: RequestKind, url: &str, level: Option<Level>) -> Recording {
        self.recorder.sent(self.client, kind, url, level)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::Morton;
    use tessera_shared::wire::Frame;

    fn level(l: u8) -> Level {
        Level::new(l).unwrap()
    }

    #[test]
    fn the_trace_is_sorted_by_send_time_stably() {
        let rec = Recorder::new("http://h:1/");
        // Registered out of time order, as two clients can be (time taken before the
        // lock): pushed directly with chosen times.
        for (client, t, n) in [(0, 5.0, 0), (1, 2.0, 1), (2, 5.0, 2), (0, 1.0, 3)] {
            rec.lock().push(TraceRequest {
                client,
                t_ms: t,
                kind: RequestKind::Tiles,
                target: format!("/t?n={n}"),
                level: Some(3),
                expect: None,
            });
        }
        let t = rec.trace("moon", 3, 1.0, "ranges");
        let order: Vec<&str> = t.requests.iter().map(|r| r.target.as_str()).collect();
        assert_eq!(order, ["/t?n=3", "/t?n=1", "/t?n=0", "/t?n=2"]);
        assert_eq!(t.header.server, "http://h:1");
        assert_eq!((t.header.dataset.as_str(), t.header.clients), ("moon", 3));
        // What the recorder writes, a trace reads back.
        let mut buf = Vec::new();
        t.write_to(&mut buf).unwrap();
        assert_eq!(Trace::from_reader(&buf[..]).unwrap(), t);
    }

    #[test]
    fn requests_register_in_time_and_incomplete_ones_keep_no_expectation() {
        let rec = Recorder::new("http://127.0.0.1:8080");
        let a = RecordHook::new(rec.clone(), 0);
        let b = RecordHook::new(rec.clone(), 1);
        let first = a.sent(
            RequestKind::Bootstrap,
            "http://127.0.0.1:8080/v1/datasets/moon/bootstrap",
            None,
        );
        std::thread::sleep(std::time::Duration::from_millis(3));
        let dropped = b.sent(
            RequestKind::Tiles,
            "http://127.0.0.1:8080/v1/datasets/moon/levels/2/tiles?ranges=0-3",
            Some(level(2)),
        );
        first.complete_body(200, b"boot");
        drop(dropped); // cancelled: never completed
        let t = rec.trace("moon", 2, 0.1, "ranges");
        assert_eq!(t.requests.len(), 2);
        let (r0, r1) = (&t.requests[0], &t.requests[1]);
        assert_eq!((r0.client, r0.kind), (0, RequestKind::Bootstrap));
        assert_eq!(r0.target, "/v1/datasets/moon/bootstrap");
        assert_eq!(r0.level, None);
        let e = r0.expect.as_ref().unwrap();
        assert_eq!((e.status, e.tiles, e.bytes), (200, 0, 4));
        assert_eq!(e.digest, crate::loadtest::trace::body_digest(b"boot"));
        assert_eq!((r1.client, r1.level), (1, Some(2)));
        assert_eq!(r1.target, "/v1/datasets/moon/levels/2/tiles?ranges=0-3");
        assert!(r1.t_ms >= r0.t_ms + 3.0, "{} then {}", r0.t_ms, r1.t_ms);
        assert_eq!(r1.expect, None);
    }

    #[test]
    fn a_completed_stream_carries_the_digest_of_its_frames() {
        let rec = Recorder::new("http://h:1");
        let hook = RecordHook::new(rec.clone(), 0);
        let frames: Vec<Frame> = (0..5u64)
            .map(|m| Frame::Tile {
                level: level(4),
                morton: Morton::from_raw(m * 3),
                checksum: 0x9e37_79b9 ^ m,
                min: 0,
                max: 0,
                record: vec![m as u8; 10],
            })
            .chain([Frame::Trailer {
                tiles: 5,
                errors: 0,
                outside: Vec::new(),
            }])
            .collect();
        let r = hook.sent(
            RequestKind::Tiles,
            "http://h:1/v1/datasets/moon/levels/4/tiles?ranges=0-12",
            Some(level(4)),
        );
        let mut digest = StreamDigest::new();
        for f in &frames {
            digest.push(f);
        }
        r.complete_stream(200, 1234, &digest);
        // Independently: a digest of the same frames, and one of other frames.
        let mut same = StreamDigest::new();
        for f in &frames {
            same.push(f);
        }
        let mut fewer = StreamDigest::new();
        for f in &frames[1..] {
            fewer.push(f);
        }
        let e = rec.trace("moon", 1, 0.0, "ranges").requests[0]
            .expect
            .clone()
            .unwrap();
        assert_eq!(e.digest, same.hex());
        assert_ne!(e.digest, fewer.hex());
        assert_eq!((e.status, e.tiles, e.bytes), (200, 5, 1234));
    }

    #[test]
    fn targets_are_relative_to_the_base() {
        let rec = Recorder::new("http://h:1/prefix/");
        assert_eq!(
            rec.target("http://h:1/prefix/v1/datasets/a"),
            "/v1/datasets/a"
        );
        assert_eq!(
            rec.target("http://other:2/v1/datasets/a/levels/1/tiles?ranges=0-3"),
            "/v1/datasets/a/levels/1/tiles?ranges=0-3"
        );
        // Not a prefix match on a path segment: /prefixed is not under /prefix.
        assert_eq!(rec.target("http://h:1/prefixed/x"), "/prefixed/x");
    }

    #[test]
    fn the_recorder_is_shared_across_threads() {
        let rec = Recorder::new("http://h:1");
        let threads: Vec<_> = (0..4u32)
            .map(|c| {
                let hook = RecordHook::new(rec.clone(), c);
                std::thread::spawn(move || {
                    for i in 0..100 {
                        hook.sent(RequestKind::Tile, &format!("http://h:1/t/{c}/{i}"), None)
                            .complete_body(404, b"");
                    }
                })
            })
            .collect();
        for t in threads {
            t.join().unwrap();
        }
        let t = rec.trace("x", 4, 0.0, "single");
        assert_eq!(t.requests.len(), 400);
        assert!(t.requests.iter().all(|r| r.expect.is_some()));
        assert!(t.requests.windows(2).all(|w| w[0].t_ms <= w[1].t_ms));
        // Each client's requests in the order it sent them.
        for c in 0..4 {
            let mine: Vec<&str> = t
                .requests
                .iter()
                .filter(|r| r.client == c)
                .map(|r| r.target.as_str())
                .collect();
            let want: Vec<String> = (0..100).map(|i| format!("/t/{c}/{i}")).collect();
            assert_eq!(mine, want);
        }
    }
}
