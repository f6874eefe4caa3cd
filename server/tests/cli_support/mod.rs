//! What the build's command-line tests share: the binary, a scratch directory, a
//! build, and the failure contract (one line naming the input and the problem, a
//! non-zero status, no output and no partial file).

use std::path::Path;
use std::process::{Command, Output};

pub fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tessera-server"))
}

/// A fresh directory for one test's files, removed when the test ends.
pub fn tmpdir(tag: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("tessera-cli-{tag}-"))
        .tempdir()
        .unwrap()
}

/// Runs `tessera-server build ARGS… --quiet`: its stdout, or its stderr as the error.
pub fn build_args(args: &[&str]) -> Result<String, String> {
    let o = bin()
        .arg("build")
        .args(args)
        .arg("--quiet")
        .output()
        .unwrap();
    if o.status.success() {
        Ok(String::from_utf8_lossy(&o.stdout).into_owned())
    } else {
        Err(String::from_utf8_lossy(&o.stderr).into_owned())
    }
}

/// A path as a `&str` argument.
pub fn text(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Asserts two files hold the same bytes.
pub fn assert_same_bytes(a: &Path, b: &Path) {
    let (x, y) = (std::fs::read(a).unwrap(), std::fs::read(b).unwrap());
    assert!(
        x == y,
        "{} and {} differ ({} and {} bytes)",
        a.display(),
        b.display(),
        x.len(),
        y.len()
    );
}

pub fn build(input: &Path, out: &Path, extra: &[&str]) -> Output {
    bin()
        .arg("build")
        .arg(input)
        .arg("-o")
        .arg(out)
        .arg("--quiet")
        .args(extra)
        .output()
        .unwrap()
}

/// Asserts the failure contract and returns the error line.
pub fn assert_clean_failure(o: &Output, names: &str, problem: &str, out: &Path) -> String {
    let stderr = String::from_utf8_lossy(&o.stderr).trim().to_string();
    assert!(
        !o.status.success(),
        "expected failure, got success; stderr: {stderr}"
    );
    let lines: Vec<&str> = stderr.lines().collect();
    assert_eq!(lines.len(), 1, "want exactly one line, got: {stderr}");
    let line = lines[0];
    assert!(line.starts_with("error: "), "{line}");
    assert!(line.contains(names), "error does not name {names}: {line}");
    assert!(
        line.to_lowercase().contains(&problem.to_lowercase()),
        "error does not say {problem:?}: {line}"
    );
    assert!(
        !out.exists(),
        "output {} exists after a failure",
        out.display()
    );
    if let Some(dir) = out.parent().filter(|d| d.is_dir()) {
        let leftovers: Vec<_> = std::fs::read_dir(dir)
            .map(|rd| rd.flatten().map(|e| e.file_name()).collect())
            .unwrap_or_default();
        assert!(
            leftovers
                .iter()
                .all(|n| !n.to_string_lossy().contains(".partial-")),
            "partial files left behind: {leftovers:?}"
        );
    }
    line.to_string()
}
