//! Build script.
//!
//! - Passes the target triple to the tests (`TOLRAY_TARGET`), which compile C and C++ programs
//!   against the C ABI with the `cc` crate outside a build script.
//! - With the `embree` feature, finds or provisions Intel Embree 4 (see the `embree` section).

use std::env;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    let target = env::var("TARGET").unwrap_or_default();
    println!("cargo:rustc-env=TOLRAY_TARGET={target}");
}
