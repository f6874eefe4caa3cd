//! Errors shared across the client: an error shown with its causes, `outer: cause:
//! cause`, as the command line shows the errors it ends with (`anyhow`'s `{:#}`), for
//! log lines and messages of the library, whose errors are typed ([`Chain`]); and a
//! PNG that the charts crate could not read or write ([`PngError`]).

use std::error::Error;
use std::fmt;

/// A PNG file that could not be read or written (`tessera_charts::png`), with its
/// causes.
#[derive(Debug, thiserror::Error)]
#[error(transparent)]
pub struct PngError(Box<dyn Error + Send + Sync>);

impl From<anyhow::Error> for PngError {
    fn from(e: anyhow::Error) -> Self {
        Self(e.into())
    }
}

/// Displays `0` and every error in its [`Error::source`] chain, separated by `: `.
#[derive(Clone, Copy, Debug)]
pub struct Chain<'a>(pub &'a (dyn Error + 'static));

impl fmt::Display for Chain<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)?;
        let mut cause = self.0.source();
        while let Some(c) = cause {
            write!(f, ": {c}")?;
            cause = c.source();
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    #[error("outer")]
    struct Outer(#[source] std::io::Error);

    #[test]
    fn a_chain_reads_as_the_command_line_shows_it() {
        let e = Outer(std::io::Error::other("inner"));
        assert_eq!(Chain(&e).to_string(), "outer: inner");
        assert_eq!(
            Chain(&e).to_string(),
            format!(
                "{:#}",
                anyhow::Error::from(Outer(std::io::Error::other("inner")))
            )
        );
    }
}
