//! Build script of the `tolray` command: with the `embree` feature, puts the directory where
//! the Embree cross-check's build found Embree 4 on the command's rpath (a build script's link
//! arguments reach only its own package, so ../embree/build.rs passes it as metadata); gives
//! the tests the repository's root (`TOLRAY_ROOT`), where their data and the docs are.

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    let manifest = std::path::PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let root = manifest.parent().unwrap_or(&manifest);
    println!("cargo:rustc-env=TOLRAY_ROOT={}", root.display());
    if let Ok(rpath) = std::env::var("DEP_TOLRAY_EMBREE_RPATH") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{rpath}");
    }
}
