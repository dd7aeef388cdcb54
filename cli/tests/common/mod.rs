//! Helpers shared by the tests that run the `tolray` binary.

use std::path::PathBuf;
use std::process::Command;

/// Runs `tolray ARGS` to completion: (exit code, stdout, stderr). A process killed by a signal
/// gives -1.
pub fn tolray(args: &[&str]) -> (i32, String, String) {
    tolray_env(&[], args)
}

/// [`tolray`] with the environment variables `vars` set.
pub fn tolray_env(vars: &[(&str, &str)], args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_tolray"))
        .envs(vars.iter().copied())
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A fresh scratch directory of this test process, `prefix` naming the test file.
pub fn scratch_dir(prefix: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("tolray-{prefix}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}
