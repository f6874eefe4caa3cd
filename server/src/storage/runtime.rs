//! The runtime every object-store request runs on.
//!
//! Every store request runs on one small dedicated runtime ([`io_runtime`]), so the
//! synchronous callers (the pyramid reader, the web-tile and terrain makers on
//! blocking threads, `build`) can wait for a result without holding up, or needing,
//! the runtime of whoever called them ([`block_on`]).

use std::future::Future;
use std::sync::OnceLock;

/// The runtime every store request runs on: two I/O threads of its own, so that a
/// synchronous caller can block on a request wherever it is (a runtime worker, a
/// blocking thread, a current-thread runtime in a test, or no runtime at all)
/// without deadlocking the runtime that would have to drive it.
pub fn io_runtime() -> &'static tokio::runtime::Runtime {
    static RT: OnceLock<tokio::runtime::Runtime> = OnceLock::new();
    RT.get_or_init(|| {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("tessera-store")
            .enable_all()
            .build()
            .expect("cannot start the object-store I/O runtime")
    })
}

/// Runs `fut` on the I/O runtime and awaits it from any async context.
pub async fn run<F>(fut: F) -> F::Output
where
    F: Future + Send + 'static,
    F::Output: Send + 'static,
{
    match io_runtime().spawn(fut).await {
        Ok(v) => v,
        Err(e) => std::panic::resume_unwind(e.into_panic()),
    }
}

/// Runs `fut` on the I/O runtime and waits for it on this thread. On a worker of a
/// multi-threaded runtime the wait is announced (`block_in_place`) so that the
/// worker's other tasks move elsewhere meanwhile.
pub fn block_on<F>(fut: F) -> F::Output
where
    F: Future + Send + 'static,
    F::Output: Send + 'static,
{
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    io_runtime().spawn(async move {
        let _ = tx.send(fut.await);
    });
    let wait = move || rx.recv().expect("the store I/O runtime dropped a request");
    match tokio::runtime::Handle::try_current().map(|h| h.runtime_flavor()) {
        Ok(tokio::runtime::RuntimeFlavor::MultiThread) => tokio::task::block_in_place(wait),
        _ => wait(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocking_works_from_a_current_thread_runtime_and_from_none() {
        assert_eq!(block_on(async { 7 }), 7);
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        assert_eq!(rt.block_on(async { block_on(async { 8 }) }), 8);
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .unwrap();
        assert_eq!(rt.block_on(async { block_on(async { 9 }) }), 9);
        assert_eq!(rt.block_on(run(async { 10 })), 10);
    }
}
