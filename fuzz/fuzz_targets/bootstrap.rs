#![no_main]
//! `tessera_shared::fuzzing::bootstrap` under libFuzzer (see `fuzz/src/lib.rs` for the limits).

libfuzzer_sys::fuzz_target!(init: tessera_fuzz::init(), |data: &[u8]| {
    let _ = tessera_shared::fuzzing::bootstrap(data);
});
