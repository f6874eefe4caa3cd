//! `tessera`: the Tessera client's command line ([`tessera_client::cli`]).

use clap::Parser;
use tessera_client::cli::{self, Cli};

/// Mesa's Vulkan device-select layer looks for a display to pick the GPU that
/// drives it, and without one prints "error: XDG_RUNTIME_DIR is invalid or not set"
/// at every device enumeration. Headless there is nothing to pick; `NODEVICE_SELECT`
/// turns the layer off (what `./run` exports too, for the server's and tests' sake),
/// unless the user set it either way.
fn quiet_headless_vulkan() {
    let headless =
        std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none();
    if headless && std::env::var_os("NODEVICE_SELECT").is_none() {
        // SAFETY: called first in `main`, before any thread exists, so nothing can
        // read or write the environment at the same time.
        #[allow(unsafe_code)]
        unsafe {
            std::env::set_var("NODEVICE_SELECT", "1");
        }
    }
}

fn main() -> std::process::ExitCode {
    quiet_headless_vulkan();
    cli::exit_code(cli::run(Cli::parse()))
}
