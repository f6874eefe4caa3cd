//! `--help` of `tessera-server` and of every command, as snapshots (`insta`): a
//! change to what users read is a reviewed change of `tests/snapshots/`.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

use std::process::Command;

fn help(args: &[&str]) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_tessera-server"))
        .args(args)
        .arg("--help")
        .env("COLUMNS", "100")
        .output()
        .unwrap();
    assert!(o.status.success(), "{args:?} --help failed");
    String::from_utf8(o.stdout).unwrap()
}

#[test]
fn help_texts_are_stable() {
    insta::assert_snapshot!("tessera-server", help(&[]));
    for command in ["build", "serve", "verify", "preview", "info"] {
        insta::assert_snapshot!(format!("tessera-server-{command}"), help(&[command]));
    }
}
