//! Standard output for the `load` and `report` commands, which are often piped into
//! another program (`tessera load … --json | head -1`, `| jq`). Rust ignores
//! SIGPIPE, so writing to a pipe whose reader has gone away is an `EPIPE` error, and
//! `println!` turns that into a panic. Here it is [`StdoutClosed`], which `main`
//! turns into a quiet exit with status [`STDOUT_CLOSED_EXIT`], as a shell reports a
//! process that SIGPIPE ended. Progress lines on stderr are best-effort.

use std::fmt::Display;
use std::io::Write;

/// The exit status when standard output was closed under the command: 128 + SIGPIPE
/// (13), what a shell reports for `yes | head -1`'s `yes`.
pub const STDOUT_CLOSED_EXIT: u8 = 141;

/// Standard output's reader went away (a broken pipe): not a failure of the command,
/// which stops writing and ends quietly.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("standard output was closed (its reader, such as `head`, went away)")]
pub struct StdoutClosed;

/// Standard output could not take a line: its reader went away ([`StdoutClosed`]),
/// or writing failed otherwise.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error(transparent)]
    Closed(#[from] StdoutClosed),
    #[error("cannot write to standard output")]
    Write(#[source] std::io::Error),
}

/// Writes `text` and a newline to `out` and flushes it: a broken pipe is
/// [`StdoutClosed`], any other failure an error saying what could not be written.
pub fn write_line(mut out: impl Write, text: impl Display) -> Result<(), OutputError> {
    match writeln!(out, "{text}").and_then(|()| out.flush()) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Err(StdoutClosed.into()),
        Err(e) => Err(OutputError::Write(e)),
    }
}

/// [`write_line`] to standard output (locked for the whole line).
pub fn print_line(text: impl Display) -> Result<(), OutputError> {
    write_line(std::io::stdout().lock(), text)
}

/// Whether `e`, or an error it was caused by, is standard output closing under the
/// command (the command should end quietly with [`STDOUT_CLOSED_EXIT`]).
pub fn is_stdout_closed(e: &(dyn std::error::Error + 'static)) -> bool {
    let mut cause = Some(e);
    while let Some(c) = cause {
        if c.is::<StdoutClosed>() || matches!(c.downcast_ref(), Some(OutputError::Closed(_))) {
            return true;
        }
        cause = c.source();
    }
    false
}

/// Writes a progress or diagnostic text to stderr, ignoring failure: a closed or full
/// stderr must not end (or panic) a run whose results go elsewhere.
pub fn progress(text: impl Display) {
    let mut err = std::io::stderr().lock();
    let _ = write!(err, "{text}");
    let _ = err.flush();
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A writer whose reader has gone away.
    struct Closed;

    impl Write for Closed {
        fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
            Err(std::io::ErrorKind::BrokenPipe.into())
        }

        fn flush(&mut self) -> std::io::Result<()> {
            Err(std::io::ErrorKind::BrokenPipe.into())
        }
    }

    /// A writer that fails for another reason.
    struct Full;

    impl Write for Full {
        fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
            Err(std::io::Error::from_raw_os_error(28)) // ENOSPC
        }

        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_broken_pipe_is_stdout_closed_and_other_failures_are_errors() {
        let mut buf = Vec::new();
        write_line(&mut buf, "a line").unwrap();
        assert_eq!(buf, b"a line\n");
        let e = write_line(Closed, "a line").unwrap_err();
        assert!(is_stdout_closed(&e));
        // Through the callers' context too.
        let e = anyhow::Error::from(e).context("printing the report");
        assert!(is_stdout_closed(e.as_ref()));
        let e = anyhow::Error::from(write_line(Full, "a line").unwrap_err());
        assert!(!is_stdout_closed(e.as_ref()));
        assert!(
            format!("{e:#}").contains("cannot write to standard output"),
            "{e:#}"
        );
    }
}
