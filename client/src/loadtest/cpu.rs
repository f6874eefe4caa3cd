//! The load process's own CPU time, to tell when a load test measured the load
//! generator rather than the server, so that the full-client mode's figures are labelled
//! as client-bound where they are (DECISIONS.md "Load testing: replay").
//!
//! Read from `/proc/self/stat` (fields 14 and 15, `utime` and `stime`: the whole
//! process, every thread, in clock ticks; proc(5)), so Linux only: elsewhere the
//! time is unknown and nothing is labelled. The ticks are `USER_HZ`, which the
//! kernel fixes at 100 for user space on every architecture it exposes `/proc` on
//! (`sysconf(_SC_CLK_TCK)` says 100; asking it would take `unsafe` FFI, which the
//! workspace denies). A tick is 10 ms: over a load run of seconds that is noise.

use std::time::Instant;

/// Clock ticks per second of `/proc/self/stat`'s times (`USER_HZ`).
const USER_HZ: f64 = 100.0;

/// The process's CPU seconds (user + system, all threads) so far; `None` where
/// `/proc/self/stat` cannot be read (not Linux).
pub fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    parse_stat(&stat)
}

/// `utime + stime` of a `/proc/{pid}/stat` line, in seconds. The command name
/// (field 2) is in parentheses and may hold spaces or parentheses itself, so the
/// fields are counted from the last `)`.
fn parse_stat(stat: &str) -> Option<f64> {
    let rest = &stat[stat.rfind(')')? + 1..];
    let mut fields = rest.split_whitespace();
    // After the name: field 3 (state) is the first; utime is field 14, stime 15.
    let utime: u64 = fields.nth(14 - 3)?.parse().ok()?;
    let stime: u64 = fields.next()?.parse().ok()?;
    Some((utime + stime) as f64 / USER_HZ)
}

/// Cores this process may run on.
pub fn available_cores() -> u32 {
    std::thread::available_parallelism().map_or(1, |n| u32::try_from(n.get()).unwrap_or(u32::MAX))
}

/// What the generator used of the machine over a run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CpuUse {
    /// CPU seconds per wall second: cores' worth of work.
    pub cores_used: f64,
    pub cores_available: u32,
}

/// The share of the available cores at or above which a run is client-bound.
pub const CLIENT_BOUND_SHARE: f64 = 0.8;

impl CpuUse {
    /// Client-bound: the generator used most of the machine (at least
    /// [`CLIENT_BOUND_SHARE`] of its cores), so it was not waiting on the server
    /// but working itself, and its tiles/s measure the generator: the server could
    /// have answered more. Below that the clients were mostly waiting on answers,
    /// and the figures are the server's (or the network's) — unless other
    /// processes held the cores (a server on the same machine, a build): a
    /// generator starved of CPU uses less than its share and is not labelled, so
    /// on a shared machine the label is a lower bound.
    pub fn client_bound(&self) -> bool {
        self.cores_used >= CLIENT_BOUND_SHARE * f64::from(self.cores_available)
    }
}

/// Measures the process's CPU use from its creation to [`CpuMeter::finish`].
#[derive(Clone, Copy, Debug)]
pub struct CpuMeter {
    wall: Instant,
    cpu: Option<f64>,
}

impl CpuMeter {
    pub fn start() -> Self {
        Self {
            wall: Instant::now(),
            cpu: process_cpu_seconds(),
        }
    }

    /// The use since the start; `None` where the CPU time is unknown.
    pub fn finish(&self) -> Option<CpuUse> {
        let cpu = process_cpu_seconds()? - self.cpu?;
        let wall = self.wall.elapsed().as_secs_f64();
        (wall > 0.0).then(|| CpuUse {
            cores_used: cpu.max(0.0) / wall,
            cores_available: available_cores(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stat_fields_are_counted_after_the_name() {
        // A real line's layout (proc(5)), with a name holding spaces and parentheses.
        let line = "4242 (tessera (load) x) R 1 4242 4242 0 -1 4194304 1200 0 0 0 \
                    250 75 0 0 20 0 9 0 123456 100000 2000 18446744073709551615";
        assert_eq!(parse_stat(line), Some(3.25));
        assert_eq!(parse_stat("4242 (x) R 1 2"), None);
        assert_eq!(parse_stat("no name here"), None);
    }

    #[test]
    fn busy_work_shows_as_cpu_time() {
        let Some(before) = process_cpu_seconds() else {
            return; // not Linux: nothing to measure (the report says unknown)
        };
        // Spin until the process has used 50 ms of CPU more: the clock advances
        // with work, whatever else the machine does (no speed is asserted).
        let mut x = 0u64;
        let started = Instant::now();
        while process_cpu_seconds().unwrap() < before + 0.05 {
            for i in 0..100_000u64 {
                x = x.wrapping_mul(31).wrapping_add(i);
            }
            assert!(
                started.elapsed().as_secs() < 60,
                "no CPU time counted after 60 s of spinning"
            );
        }
        std::hint::black_box(x);
    }

    #[test]
    fn client_bound_is_most_of_the_cores() {
        let u = |cores_used, cores_available| CpuUse {
            cores_used,
            cores_available,
        };
        assert!(u(1.7, 2).client_bound());
        assert!(u(1.61, 2).client_bound());
        assert!(!u(1.5, 2).client_bound());
        assert!(!u(3.0, 16).client_bound());
        assert!(u(15.0, 16).client_bound());
    }
}
