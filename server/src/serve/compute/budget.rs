//! The memory budget of computed responses: bytes reserved before work allocates,
//! waited on by blocking threads (a condvar) and by async tasks (a notify), and given
//! back when the [`Reservation`] drops.

use prometheus::IntGauge;
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use tokio::sync::Notify;

/// The memory budget: reserved in bytes, waited on by blocking threads (a condvar)
/// and by async tasks (a notify).
#[derive(Debug)]
pub(super) struct MemoryPool {
    pub(super) limit: u64,
    pub(super) used: Mutex<u64>,
    pub(super) freed: Condvar,
    pub(super) notify: Notify,
    pub(super) gauge: IntGauge,
}

impl MemoryPool {
    pub(super) fn try_take(&self, bytes: u64) -> bool {
        let mut used = self.used.lock().unwrap_or_else(PoisonError::into_inner);
        if *used + bytes > self.limit {
            return false;
        }
        *used += bytes;
        self.gauge.set(i64::try_from(*used).unwrap_or(i64::MAX));
        true
    }

    /// `bytes` (clamped) reserved if they fit now.
    pub(super) fn try_reserve(self: &Arc<Self>, bytes: u64) -> Option<Reservation> {
        let bytes = self.clamp(bytes);
        self.try_take(bytes).then(|| Reservation {
            pool: self.clone(),
            bytes,
        })
    }

    /// `bytes` (clamped) reserved now, over the limit if need be: for bytes that
    /// already exist (later work waits for them).
    pub(super) fn force(self: &Arc<Self>, bytes: u64) -> Reservation {
        let bytes = self.clamp(bytes);
        let mut used = self.used.lock().unwrap_or_else(PoisonError::into_inner);
        *used += bytes;
        self.gauge.set(i64::try_from(*used).unwrap_or(i64::MAX));
        Reservation {
            pool: self.clone(),
            bytes,
        }
    }

    pub(super) fn give(&self, bytes: u64) {
        let mut used = self.used.lock().unwrap_or_else(PoisonError::into_inner);
        *used = used.saturating_sub(bytes);
        self.gauge.set(i64::try_from(*used).unwrap_or(i64::MAX));
        drop(used);
        self.freed.notify_all();
        self.notify.notify_waiters();
    }

    /// Whatever one computation asks, it may have the whole budget, no more (then it
    /// runs alone).
    pub(super) fn clamp(&self, bytes: u64) -> u64 {
        bytes.clamp(1, self.limit)
    }
}

/// Bytes reserved on the memory budget, given back on drop.
#[derive(Debug)]
pub struct Reservation {
    pub(super) pool: Arc<MemoryPool>,
    pub(super) bytes: u64,
}

impl Drop for Reservation {
    fn drop(&mut self) {
        self.pool.give(self.bytes);
    }
}
