//! What every command shares besides its arguments: usage errors and exit codes, Ctrl-C, and the
//! check of output paths before any work.

use anyhow::bail;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

/// A bad flag value: exit code 2, as for what clap refuses.
#[derive(Debug)]
pub struct Usage(pub String);

impl std::fmt::Display for Usage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Usage {}

/// Returns a usage error (exit code 2) with a formatted message.
#[macro_export]
macro_rules! usage {
    ($($t:tt)*) => {
        return Err(anyhow::Error::new($crate::app::Usage(format!($($t)*))))
    };
}

/// Lets every option that takes a value take a negative number (`--fields -0.7`, `--noise
/// -0.01`): clap reads a leading `-` as a flag otherwise, and the user got "unexpected argument
/// '-0'" instead of a field below the axis or an error naming the flag.
pub fn negative_numbers(cmd: clap::Command) -> clap::Command {
    let allow = |a: clap::Arg| {
        if a.get_action().takes_values() && !a.is_positional() {
            a.allow_negative_numbers(true)
        } else {
            a
        }
    };
    cmd.mut_args(allow)
        .mut_subcommands(move |sc| sc.mut_args(allow))
}

/// The exit code of an error: 2 for usage errors (a bad flag value, or a library argument error,
/// which every command raises only for values given on the command line), else 1.
pub fn exit_code(e: &anyhow::Error) -> u8 {
    let usage = e.chain().any(|c| {
        c.is::<Usage>()
            || c.downcast_ref::<tolray::Error>()
                .is_some_and(|t| t.kind() == tolray::ErrorKind::Argument)
    });
    if usage {
        2
    } else {
        1
    }
}

/// Set by Ctrl-C when a command stops gracefully (`train`).
pub static STOP_REQUESTED: AtomicBool = AtomicBool::new(false);
/// Whether the running command stops gracefully on Ctrl-C.
pub static GRACEFUL_STOP: AtomicBool = AtomicBool::new(false);

/// Ctrl-C: a graceful command (`train`) is asked to stop; any other exits at once with code 130,
/// after deleting the temporary files of writes in progress (outputs are written through a
/// temporary file and a rename, so no half-written output exists, and now no hidden partial file
/// either).
pub fn install_interrupt_handler() {
    let _ = ctrlc::set_handler(|| {
        if GRACEFUL_STOP.load(Ordering::SeqCst) {
            STOP_REQUESTED.store(true, Ordering::SeqCst);
        } else {
            tolray::files::remove_partial_files();
            std::process::exit(130);
        }
    });
}

/// Checks the output paths of the command line before any work: a file's directory must exist
/// and the file must not be a directory; an output directory (`--out` of `train`, `deep`,
/// `demo`) must not be a file. Names the flag and the path.
pub fn check_outputs(m: &clap::ArgMatches) -> anyhow::Result<()> {
    let Some((name, sub)) = m.subcommand() else {
        return Ok(());
    };
    for id in ["png", "exr", "json", "html", "output", "out"] {
        let Ok(Some(p)) = sub.try_get_one::<PathBuf>(id) else {
            continue;
        };
        let flag = if id == "output" {
            "OUTPUT".to_string()
        } else {
            format!("--{id}")
        };
        // `--out` is a directory for these; a file for `trace` and `render`.
        if id == "out" && matches!(name, "train" | "deep" | "demo") {
            if p.exists() && !p.is_dir() {
                bail!("{flag} {}: exists and is not a directory", p.display());
            }
            continue;
        }
        let dir = p
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        if !dir.is_dir() {
            bail!(
                "{flag} {}: the directory {} does not exist",
                p.display(),
                dir.display()
            );
        }
        if p.is_dir() {
            bail!("{flag} {}: is a directory, not a file", p.display());
        }
    }
    Ok(())
}
