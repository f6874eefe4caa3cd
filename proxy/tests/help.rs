//! `--help` of `tessera-proxy`, as a snapshot (`insta`): a change to what users read
//! is a reviewed change of `tests/snapshots/`.

use std::path::Path;
use tessera_shared::cli_help::help_text;

#[test]
fn help_text_is_stable() {
    let bin = Path::new(env!("CARGO_BIN_EXE_tessera-proxy"));
    insta::assert_snapshot!("tessera-proxy", help_text(bin, &[]));
}
