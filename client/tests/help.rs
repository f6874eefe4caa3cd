//! `--help` of `tessera` (the client) and of every command, and of `tessera-load`, as snapshots (`insta`): a
//! change to what users read is a reviewed change of `tests/snapshots/`.

use std::path::Path;
use tessera_shared::cli_help::help_text;

#[test]
fn help_texts_are_stable() {
    let bin = Path::new(env!("CARGO_BIN_EXE_tessera"));
    insta::assert_snapshot!("tessera", help_text(bin, &[]));
    for command in ["load", "fly", "bench-select", "report", "inspect"] {
        insta::assert_snapshot!(format!("tessera-{command}"), help_text(bin, &[command]));
    }
    insta::assert_snapshot!("tessera-load-merge", help_text(bin, &["load", "merge"]));
}

/// `tessera-load`, the load tester alone: `tessera load`'s arguments under a name
/// of its own.
#[test]
fn load_tester_help_texts_are_stable() {
    let bin = Path::new(env!("CARGO_BIN_EXE_tessera-load"));
    insta::assert_snapshot!("tessera-load-bin", help_text(bin, &[]));
    insta::assert_snapshot!("tessera-load-bin-merge", help_text(bin, &["merge"]));
}
