//! Build script.
//!
//! - Passes the target triple to the tests (`TOLRAY_TARGET`), which compile C and C++ programs
//!   against the C ABI with the `cc` crate outside a build script.

use std::env;

/// The C ABI version (must equal `tolray::ffi::TOLRAY_ABI_VERSION`).
const ABI_VERSION: u32 = 3;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    let target = env::var("TARGET").unwrap_or_default();
    println!("cargo:rustc-env=TOLRAY_TARGET={target}");
    // The shared library's SONAME carries the ABI version (`TOLRAY_ABI_VERSION` in
    // src/ffi/mod.rs; tests/capi/ checks that they agree): programs linked against
    // libtolray.so record `libtolray.so.3` and keep working across compatible updates, and an
    // incompatible library (ABI 4) is a different file. scripts/install-c.sh installs
    // libtolray.so.3 with the libtolray.so link for the linker.
    if target.contains("linux") {
        println!("cargo:rustc-cdylib-link-arg=-Wl,-soname,libtolray.so.{ABI_VERSION}");
    }
}
