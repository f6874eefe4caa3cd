//! How many connections one load process may open: its open-file limit
//! (`RLIMIT_NOFILE`) less what it keeps for itself, and at most [`MAX_CONNECTIONS`];
//! `--connections` and `--clients` beyond it are refused before any is opened.

/// The most connections one load process opens, whatever its open-file limit: one
/// client's ephemeral ports to one server address run out near there (Linux offers
/// 28 232 by default), and so would the runtime's patience; more load is more
/// processes (`--shard K/N`).
pub const MAX_CONNECTIONS: u32 = 65_536;

/// Open files the load process keeps for itself besides its connections: standard
/// streams, the runtime's epoll and wakers, the trace and report files, the
/// resolver's sockets, with room to spare.
const FD_RESERVE: u64 = 64;

/// Why a `--connections` count is refused.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ConnectionsError {
    #[error(
        "--connections {requested}: this process may open {limit} files (RLIMIT_NOFILE, `ulimit -n`), which leaves room for {max} connections besides the {FD_RESERVE} it keeps for itself; raise the limit (`ulimit -n {needed}`, up to the hard limit `ulimit -Hn`) or use at most {max} connections"
    )]
    OpenFiles {
        requested: u32,
        limit: u64,
        max: u32,
        needed: u64,
    },
    #[error(
        "--connections {requested} is above {MAX_CONNECTIONS}, the most one load process opens; split the load over processes with --shard K/N"
    )]
    TooMany { requested: u32 },
}

/// The connections a process with the open-file limit `fd_limit` (`None`: unlimited
/// or unknown) may open: the limit less `FD_RESERVE`, at most [`MAX_CONNECTIONS`].
pub fn max_connections(fd_limit: Option<u64>) -> u32 {
    let by_fds = fd_limit.map_or(u64::MAX, |l| l.saturating_sub(FD_RESERVE));
    u32::try_from(by_fds.min(u64::from(MAX_CONNECTIONS))).unwrap_or(MAX_CONNECTIONS)
}

/// Refuses `requested` connections (or full clients, each of which holds one at
/// least) that the open-file limit `fd_limit` cannot hold, before any is opened: a
/// run past it fails its connections one by one as `connect` errors, and
/// `--connections 1000000` took 915 MB before sending anything.
pub fn check_connections(requested: u32, fd_limit: Option<u64>) -> Result<(), ConnectionsError> {
    let max = max_connections(fd_limit);
    if requested <= max {
        return Ok(());
    }
    match fd_limit {
        Some(limit) if max < MAX_CONNECTIONS => Err(ConnectionsError::OpenFiles {
            requested,
            limit,
            max,
            needed: u64::from(requested) + FD_RESERVE,
        }),
        _ => Err(ConnectionsError::TooMany { requested }),
    }
}

/// The soft `RLIMIT_NOFILE`, read from `/proc/self/limits` (as the server reads it;
/// no `unsafe` needed); `None` where it is unlimited or cannot be read.
pub fn open_file_limit() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/limits").ok()?;
    let line = text.lines().find(|l| l.starts_with("Max open files"))?;
    line.get("Max open files".len()..)?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn connection_counts_the_open_file_limit_cannot_hold_are_refused() {
        // The default soft limit of many systems: 1024 files, 960 connections.
        assert_eq!(max_connections(Some(1024)), 960);
        assert_eq!(check_connections(960, Some(1024)), Ok(()));
        let e = check_connections(1_000_000, Some(1024)).unwrap_err();
        assert_eq!(
            e,
            ConnectionsError::OpenFiles {
                requested: 1_000_000,
                limit: 1024,
                max: 960,
                needed: 1_000_064
            }
        );
        let text = e.to_string();
        assert!(
            text.contains("RLIMIT_NOFILE") && text.contains("ulimit -n 1000064"),
            "{text}"
        );
        // A limit below the reserve leaves no connection at all.
        assert_eq!(max_connections(Some(10)), 0);
        assert!(check_connections(1, Some(10)).is_err());
        // Unlimited or unknown, or a limit above it: the fixed bound.
        for limit in [None, Some(10_000_000)] {
            assert_eq!(max_connections(limit), MAX_CONNECTIONS);
            assert_eq!(
                check_connections(1_000_000, limit),
                Err(ConnectionsError::TooMany {
                    requested: 1_000_000
                })
            );
        }
    }
}
