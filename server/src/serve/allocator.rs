//! Freed large buffers go back to the system, so the server's resident memory
//! follows the memory its computations hold (the `--max-compute-mib` budget), not
//! the history of its threads.
//!
//! glibc's `malloc` serves a large request with its own `mmap` (unmapped on `free`)
//! until the first such block is freed; it then raises the threshold, up to 32 MiB,
//! and later large buffers come from per-thread arenas that keep the memory after
//! it is freed. A burst of 100 000-point elevation answers (25 MB of JSON each, made
//! on many blocking threads) then left hundreds of MiB resident after the budget had
//! let at most 64 MiB live at once (`tests/abuse_elevation.rs` measured +535 MiB,
//! +77 MiB with the threshold fixed). Fixing the threshold turns that adjustment off.
//!
//! This is the crate's second audited `unsafe` module (crs/proj.rs is the first):
//! one call of `mallopt`, which takes two integers and only changes a tunable.

#![allow(unsafe_code)]

/// Blocks of at least this many bytes are mapped on their own and unmapped when freed.
pub const MMAP_THRESHOLD: i32 = 1 << 20;

/// Fixes glibc's mmap threshold at [`MMAP_THRESHOLD`] (nothing elsewhere).
pub fn return_large_buffers() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: `mallopt` reads its two integer arguments and sets a tunable of the
    // allocator; it touches no memory of ours and is documented as callable at any
    // time (it takes the allocator's own lock).
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD);
    }
}
