//! `--help` of `tessera-server` and of every command, as snapshots (`insta`): a
//! change to what users read is a reviewed change of `tests/snapshots/`.

use std::path::Path;
use tessera_shared::cli_help::help_text;

#[test]
fn help_texts_are_stable() {
    let bin = Path::new(env!("CARGO_BIN_EXE_tessera-server"));
    insta::assert_snapshot!("tessera-server", help_text(bin, &[]));
    for command in [
        "build", "serve", "verify", "preview", "query", "export", "info",
    ] {
        insta::assert_snapshot!(
            format!("tessera-server-{command}"),
            help_text(bin, &[command])
        );
    }
}
