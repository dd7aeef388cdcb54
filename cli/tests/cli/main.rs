//! The `tolray` binary end to end: numbers against the reference values, files, exit codes.

#[path = "../common/mod.rs"]
mod common;

use common::tolray;
use std::path::PathBuf;

mod basics;
mod deep;
mod files;
mod wave;
#[allow(unused_imports)]
use basics::*;
#[allow(unused_imports)]
use deep::*;
#[allow(unused_imports)]
use files::*;
#[allow(unused_imports)]
use wave::*;

fn tmp(name: &str) -> PathBuf {
    common::scratch_dir("cli").join(name)
}
