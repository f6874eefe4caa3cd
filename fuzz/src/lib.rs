//! What every fuzz target shares: an allocation limit that works without a sanitizer.
//!
//! The targets are built with `cargo fuzz build -s none` (stable Rust: no ASan), and
//! libFuzzer's own `-malloc_limit_mb` needs a sanitizer's allocator hooks, so without
//! one it never fires; only `-rss_limit_mb` (a thread polling the resident size once a
//! second) does, and it misses a huge allocation that is never touched. This crate's
//! global allocator enforces the limit instead: any single allocation (or reallocation)
//! larger than `-malloc_limit_mb` (else `-rss_limit_mb`, else libFuzzer's default 2048)
//! prints its size and a backtrace and aborts, which libFuzzer records as a crash with
//! its input under `fuzz/artifacts/TARGET/`.

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Write;
use std::sync::atomic::{AtomicUsize, Ordering};

/// libFuzzer's default for `-rss_limit_mb`, which `-malloc_limit_mb` defaults to.
const DEFAULT_LIMIT_MB: usize = 2048;

static LIMIT: AtomicUsize = AtomicUsize::new(DEFAULT_LIMIT_MB << 20);

/// Reads the limit from the fuzzer's command line; call once before fuzzing
/// (`fuzz_target!(init: tessera_fuzz::init(), ...)`).
pub fn init() {
    let flag = |name: &str| {
        std::env::args()
            .filter_map(|a| a.strip_prefix(name)?.parse::<usize>().ok())
            .last()
            .filter(|&mb| mb > 0)
    };
    let mb = flag("-malloc_limit_mb=")
        .or_else(|| flag("-rss_limit_mb="))
        .unwrap_or(DEFAULT_LIMIT_MB);
    LIMIT.store(mb << 20, Ordering::Relaxed);
}

/// The system allocator, refusing any single allocation over the limit.
#[derive(Debug)]
pub struct Limited;

#[global_allocator]
static ALLOCATOR: Limited = Limited;

fn check(size: usize) {
    let limit = LIMIT.load(Ordering::Relaxed);
    if size > limit {
        // Small allocations from here on (the message, the backtrace) are under the limit.
        let _ = writeln!(
            std::io::stderr(),
            "==tessera-fuzz== malloc limit: an allocation of {size} bytes ({} MiB) exceeds \
             the limit of {} MiB\n{}",
            size >> 20,
            limit >> 20,
            std::backtrace::Backtrace::force_capture()
        );
        std::process::abort();
    }
}

// SAFETY: every call is forwarded unchanged to `System`; `check` only reads the size.
unsafe impl GlobalAlloc for Limited {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        check(layout.size());
        // SAFETY: the caller's contract is passed on to `System`.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        check(layout.size());
        // SAFETY: as above.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as above.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        check(new_size);
        // SAFETY: as above.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}
