//! Holds no code. The package's test target `unit` compiles the library's sources
//! (`../src/lib.rs`) with their `#[cfg(test)]` modules, unoptimised; a test target rather than
//! the package's library so that `cargo run` and `cargo build` never compile it.
