//! The `--help` text of a command, for the binaries' snapshot tests (enabled, like
//! [`crate::testdata`], by the `testdata` feature).

use std::path::Path;
use std::process::Command;

/// Runs `BIN ARGS… --help` (with a fixed terminal width) and returns what it
/// printed; panics, failing the test, if the command fails.
pub fn help_text(bin: &Path, args: &[&str]) -> String {
    let o = Command::new(bin)
        .args(args)
        .arg("--help")
        .env("COLUMNS", "100")
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", bin.display()));
    assert!(
        o.status.success(),
        "{} {args:?} --help failed: {}",
        bin.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8(o.stdout).expect("--help prints UTF-8")
}
