//! The bounds on computed responses, from the flags or sized from this machine.

use std::time::Duration;

/// The bounds on expensive work (`serve --max-compute`, `--max-compute-mib`,
/// `--compute-queue`, `--compute-queue-secs`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ComputeLimits {
    /// Computations running at once.
    pub max_compute: usize,
    /// Working memory of the computations running at once, and of the made bodies
    /// responses still hold, in bytes.
    pub memory_bytes: u64,
    /// Computations waiting for a slot or memory; more get a 503 at once.
    pub queue: usize,
    /// Longest wait for a slot or memory before a 503.
    pub queue_wait: Duration,
}

impl ComputeLimits {
    /// Sized from this machine: one computation per core (they are CPU-bound; more
    /// would only hold more memory), a sixteenth of the memory the process may use
    /// (the smaller of physical memory and a cgroup limit) clamped to 256 MiB–1 GiB, a
    /// queue of 256 per slot (at least 512: a waiting computation costs a few hundred
    /// bytes, and a map or globe client asks for up to ~20–100 tiles at once, so a
    /// burst of a few clients waits rather than fails), and 10 s of waiting (which is
    /// what keeps the queue short in time).
    pub fn for_this_machine() -> Self {
        let cores = std::thread::available_parallelism().map_or(2, std::num::NonZero::get);
        let max_compute = cores.max(2);
        let memory = usable_memory().map_or(512 << 20, |m| (m / 16).clamp(256 << 20, 1 << 30));
        Self {
            max_compute,
            memory_bytes: memory,
            queue: (256 * max_compute).max(512),
            queue_wait: Duration::from_secs(10),
        }
    }
}

/// The memory this process may use: physical memory, or a smaller cgroup (v2 or v1)
/// limit (a container's).
fn usable_memory() -> Option<u64> {
    let physical = std::fs::read_to_string("/proc/meminfo").ok().and_then(|s| {
        s.lines()
            .find_map(|l| l.strip_prefix("MemTotal:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
            .map(|kib| kib * 1024)
    });
    let cgroup = [
        "/sys/fs/cgroup/memory.max",
        "/sys/fs/cgroup/memory/memory.limit_in_bytes",
    ]
    .iter()
    .find_map(|p| std::fs::read_to_string(p).ok()?.trim().parse::<u64>().ok());
    match (physical, cgroup) {
        (Some(p), Some(c)) => Some(p.min(c)),
        (p, c) => p.or(c),
    }
}
