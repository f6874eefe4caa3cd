//! The right to run one admitted computation: its slot, its cancellation flag and
//! the memory budget it reserves from.

use super::budget::{MemoryPool, Reservation};
use super::{Kind, Made, Stop};
use crate::http::error::ApiError;
use bytes::Bytes;
use prometheus::IntGaugeVec;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, PoisonError};
use std::time::{Duration, Instant};
use tokio::sync::OwnedSemaphorePermit;

/// The right to run one admitted computation: its slot, its cancellation flag, the
/// memory budget. Dropped (slot given back) when the computation really ends.
#[derive(Debug)]
pub struct Ticket {
    pub(super) _slot: OwnedSemaphorePermit,
    pub(super) cancelled: Arc<AtomicBool>,
    pub(super) pool: Arc<MemoryPool>,
    pub(super) wait: Duration,
    pub(super) kind: Kind,
    pub(super) running: IntGaugeVec,
}

impl Drop for Ticket {
    fn drop(&mut self) {
        self.running.with_label_values(&[self.kind.label()]).dec();
    }
}

impl Ticket {
    /// `Err(Cancelled)` once every requester is gone: long loops call it at each step.
    pub fn check(&self) -> Result<(), Stop> {
        if self.cancelled.load(Ordering::Relaxed) {
            Err(Stop::Cancelled)
        } else {
            Ok(())
        }
    }

    /// Reserves `bytes` of working memory (a blocking thread waits for it, at most the
    /// queue wait, while checking for cancellation).
    pub fn reserve(&self, bytes: u64) -> Result<Reservation, Stop> {
        let bytes = self.pool.clamp(bytes);
        let deadline = Instant::now() + self.wait;
        let mut used = self
            .pool
            .used
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        loop {
            self.check()?;
            if *used + bytes <= self.pool.limit {
                *used += bytes;
                self.pool
                    .gauge
                    .set(i64::try_from(*used).unwrap_or(i64::MAX));
                return Ok(Reservation {
                    pool: self.pool.clone(),
                    bytes,
                });
            }
            let now = Instant::now();
            if now >= deadline {
                return Err(busy_memory(self.pool.limit, bytes));
            }
            // Woken by every release; a short timeout so that a cancellation is seen.
            let step = (deadline - now).min(Duration::from_millis(20));
            used = self
                .pool
                .freed
                .wait_timeout(used, step)
                .unwrap_or_else(PoisonError::into_inner)
                .0;
        }
    }

    /// [`Ticket::reserve`] for async work (its cancellation is its future's drop).
    pub async fn reserve_async(&self, bytes: u64) -> Result<Reservation, Stop> {
        let bytes = self.pool.clamp(bytes);
        let deadline = tokio::time::Instant::now() + self.wait;
        loop {
            let freed = self.pool.notify.notified();
            tokio::pin!(freed);
            freed.as_mut().enable();
            if let Some(r) = self.pool.try_reserve(bytes) {
                return Ok(r);
            }
            tokio::select! {
                () = freed => {}
                () = tokio::time::sleep_until(deadline) => {
                    return Err(busy_memory(self.pool.limit, bytes));
                }
            }
        }
    }

    /// Runs `work` on a blocking thread with this ticket (given back when it ends).
    pub async fn blocking<T: Send + 'static>(
        self,
        work: impl FnOnce(&Ticket) -> T + Send + 'static,
    ) -> Result<T, ApiError> {
        let kind = self.kind;
        tokio::task::spawn_blocking(move || work(&self))
            .await
            .map_err(|e| ApiError::internal(format!("{} task failed: {e}", kind.label())))
    }

    /// `made`, holding a reservation of its size from now on (taken without waiting:
    /// the working memory it came from is given back at the same time).
    pub fn made(&self, bytes: Bytes, tiles: u64) -> Made {
        let hold = self.pool.force(bytes.len() as u64);
        Made::held(bytes, tiles, hold)
    }
}

fn busy_memory(limit: u64, bytes: u64) -> Stop {
    Stop::Busy(format!(
        "the server is at its memory limit for computed responses ({} MiB; this one needs {} MiB); retry shortly",
        limit >> 20,
        bytes.div_ceil(1 << 20)
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::serve::compute::tests::{compute, limits};
    use crate::serve::compute::{Compute, ComputeLimits};

    #[test]
    fn memory_waits_for_reservations_and_refuses_after_the_wait() {
        let rt = tokio::runtime::Runtime::new().unwrap();
        let (c, _r) = compute(ComputeLimits {
            queue_wait: Duration::from_millis(200),
            ..limits(4, 1000, 8)
        });
        let ticket = |c: &Arc<Compute>| Ticket {
            _slot: c.slots.clone().try_acquire_owned().unwrap(),
            cancelled: Arc::new(AtomicBool::new(false)),
            pool: c.pool.clone(),
            wait: c.limits.queue_wait,
            kind: Kind::Bootstrap,
            running: c.running.clone(),
        };
        let (a, b) = (ticket(&c), ticket(&c));
        let first = a.reserve(600).unwrap();
        assert_eq!(c.memory_used(), 600);
        // Over the budget: waits, then is refused with a reason.
        let Err(Stop::Busy(why)) = b.reserve(600) else {
            panic!("reserved over the budget")
        };
        assert!(why.contains("memory limit"), "{why}");
        // More than the whole budget is clamped to it: it runs alone.
        drop(first);
        let all = b.reserve(10_000).unwrap();
        assert_eq!(c.memory_used(), 1000);
        drop(all);
        // A made body holds its size until the last holder lets go.
        let made = rt.block_on(async {
            a.reserve_async(100)
                .await
                .map(|_| a.made(Bytes::from(vec![0; 300]), 0))
        });
        let made = made.unwrap();
        assert_eq!(c.memory_used(), 300);
        let body = made.body();
        drop(made);
        assert_eq!(c.memory_used(), 300, "the body still holds it");
        drop(body);
        assert_eq!(c.memory_used(), 0);
    }
}
