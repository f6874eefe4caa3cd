//! Links PROJ (the system's libproj, found through pkg-config): the `proj-sys` bindings
//! are used without their own build script, which would need libclang for bindgen
//! (DECISIONS.md "Projection library: PROJ").

/// PROJ 9.1 is what Debian 12 ships; older releases lack nothing we call, but are
/// untested.
const MINIMUM_PROJ: &str = "8.2";

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-env-changed=PKG_CONFIG_PATH");
    if let Err(e) = pkg_config::Config::new()
        .atleast_version(MINIMUM_PROJ)
        .probe("proj")
    {
        panic!(
            "tessera-server needs PROJ >= {MINIMUM_PROJ} and its development files: \
             `sudo apt-get install -y libproj-dev pkg-config` (Debian/Ubuntu). \
             pkg-config said: {e}"
        );
    }
}
