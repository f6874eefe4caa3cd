//! SIGINT/SIGTERM during a build: stop at the next band or batch, remove the partial
//! file (by unwinding through the writer's `NamedTempFile`) and exit non-zero
//! (docs/ARCHITECTURE.md#nothing-partial). A second signal ends the process at once; the
//! next build then removes the partial file it left.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// The signal that asked the build to stop, or 0.
#[derive(Clone, Debug, Default)]
pub struct Interrupt(Arc<AtomicUsize>);

impl Interrupt {
    /// Watches SIGINT and SIGTERM (and ignores SIGXFSZ, so a file-size limit is a
    /// write error with a message rather than a silent kill).
    pub fn install() -> std::io::Result<Self> {
        use signal_hook::consts::{SIGINT, SIGTERM, SIGXFSZ};
        let which = Arc::new(AtomicUsize::new(0));
        let seen = Arc::new(AtomicBool::new(false));
        for sig in [SIGINT, SIGTERM] {
            // Registered first, so it runs first: on a second signal (`seen` already
            // set) it restores the default action and re-raises, ending the process.
            signal_hook::flag::register_conditional_default(sig, seen.clone())?;
            signal_hook::flag::register(sig, seen.clone())?;
            signal_hook::flag::register_usize(sig, which.clone(), sig as usize)?;
        }
        signal_hook::flag::register(SIGXFSZ, Arc::new(AtomicBool::new(false)))?;
        Ok(Self(which))
    }

    /// An error naming the signal once one arrived.
    pub fn check(&self) -> anyhow::Result<()> {
        match self.0.load(Ordering::Relaxed) {
            0 => Ok(()),
            sig => Err(anyhow::Error::new(Interrupted(sig as i32))),
        }
    }
}

/// What `check` returns once a signal arrived; `main` maps it to exit status 128 + N.
#[derive(Debug, thiserror::Error)]
#[error("interrupted by {}; the partial output was removed", signal_name(*.0))]
pub struct Interrupted(pub i32);

fn signal_name(sig: i32) -> &'static str {
    match sig {
        signal_hook::consts::SIGINT => "SIGINT",
        signal_hook::consts::SIGTERM => "SIGTERM",
        _ => "a signal",
    }
}
