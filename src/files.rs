//! Files: reading JSON with the path, line and column in its errors, and atomic writes (a
//! temporary file beside the target, renamed over it) that an interrupted program can clean up.

use crate::error::{Error, ErrorKind, Result};
use std::path::Path;

/// Reads a JSON file into `T`.
///
/// # Errors
/// [`ErrorKind::Io`] naming the path, or [`ErrorKind::Parse`] naming the path, line and column.
pub fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    serde_json::from_str(&text).map_err(|e| {
        Error::new(
            ErrorKind::Parse,
            format!(
                "{}: line {}, column {}: {e}",
                path.display(),
                e.line(),
                e.column()
            ),
        )
    })
}

/// Temporary files of atomic writes in progress (see [`remove_partial_files`]).
static PARTIAL: std::sync::Mutex<Vec<std::path::PathBuf>> = std::sync::Mutex::new(Vec::new());

/// A hidden temporary path beside `path`, unique in this process (two writers of one path never
/// share it), registered until [`release_temp`] so that an interrupted process can delete it.
///
/// # Errors
/// [`ErrorKind::Argument`] when `path` has no file name.
pub(crate) fn temp_beside(path: &Path) -> Result<std::path::PathBuf> {
    static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let name = path
        .file_name()
        .ok_or_else(|| Error::argument(format!("{}: not a file path", path.display())))?;
    let n = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let tmp = path.with_file_name(format!(
        ".{}.{}.{n}.tmp",
        name.to_string_lossy(),
        std::process::id()
    ));
    if let Ok(mut v) = PARTIAL.lock() {
        v.push(tmp.clone());
    }
    Ok(tmp)
}

/// Unregisters a temporary path of [`temp_beside`] (renamed or removed).
pub(crate) fn release_temp(tmp: &Path) {
    if let Ok(mut v) = PARTIAL.lock() {
        v.retain(|p| p != tmp);
    }
}

/// Deletes the temporary files of every atomic write still in progress. A program interrupted
/// mid-write (the CLI's Ctrl-C handler) calls it before exiting so that no hidden partial file
/// is left beside its outputs.
///
/// ```
/// tolray::files::remove_partial_files(); // nothing in progress: nothing to do
/// ```
pub fn remove_partial_files() {
    remove_partial(|_| true);
}

/// Deletes the registered temporary files that `select` picks and unregisters them.
fn remove_partial(select: impl Fn(&Path) -> bool) {
    // try_lock: a handler must not wait for a writer it interrupted.
    if let Ok(mut v) = PARTIAL.try_lock() {
        v.retain(|p| {
            let picked = select(p);
            if picked {
                let _ = std::fs::remove_file(p);
            }
            !picked
        });
    }
}

/// Writes through a temporary file beside `path` (`write` fills it), then renames it over
/// `path`; on any error the temporary file is removed and nothing is left at `path`.
///
/// # Errors
/// [`ErrorKind::Io`] naming the path.
pub(crate) fn write_via_temp(
    path: &Path,
    write: impl FnOnce(&Path) -> std::io::Result<()>,
) -> Result<()> {
    let tmp = temp_beside(path)?;
    let result = write(&tmp).and_then(|()| std::fs::rename(&tmp, path));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    release_temp(&tmp);
    result.map_err(|e| Error::io(path, e))
}

/// Writes `bytes` to `path` atomically: a temporary file in the same directory, synced, then a
/// rename, so a reader never sees a half-written file.
///
/// # Errors
/// [`ErrorKind::Io`] naming the path when the file cannot be written or renamed.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    write_via_temp(path, |tmp| {
        let mut f = std::fs::File::create(tmp)?;
        f.write_all(bytes)?;
        f.sync_all()
    })
}

/// Writes `path` atomically as [`write_atomic`] does, `fill` writing the contents as it goes
/// through a buffered writer: on an error of `fill` (returned as is) or of the file, nothing is
/// left at `path` and no temporary file beside it.
///
/// # Errors
/// `fill`'s error; [`ErrorKind::Io`] naming the path when the file cannot be written or renamed.
///
/// ```
/// use std::io::Write;
/// let path = std::env::temp_dir().join(format!("tolray-doc-{}.txt", std::process::id()));
/// tolray::files::write_atomic_with(&path, |w| {
///     writeln!(w, "hello").map_err(|e| tolray::Error::io(&path, e))
/// })?;
/// assert_eq!(std::fs::read_to_string(&path).unwrap(), "hello\n");
/// let e = tolray::files::write_atomic_with(&path, |_| Err(tolray::Error::argument("no")));
/// assert_eq!(e.unwrap_err().message(), "no");
/// assert_eq!(std::fs::read_to_string(&path).unwrap(), "hello\n"); // untouched
/// # std::fs::remove_file(&path).unwrap();
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn write_atomic_with(
    path: &Path,
    fill: impl FnOnce(&mut dyn std::io::Write) -> Result<()>,
) -> Result<()> {
    let mut failed = None;
    let written = write_via_temp(path, |tmp| {
        let mut w = std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(tmp)?);
        if let Err(e) = fill(&mut w) {
            failed = Some(e);
            return Err(std::io::Error::other("the contents failed"));
        }
        w.into_inner().map_err(|e| e.into_error())?.sync_all()
    });
    match failed {
        Some(e) => Err(e),
        None => written,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_write_leaves_nothing_on_failure() {
        let dir = std::env::temp_dir().join(format!("tolray-aw-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let ok = dir.join("a.txt");
        write_atomic(&ok, b"hello").unwrap();
        assert_eq!(std::fs::read(&ok).unwrap(), b"hello");
        let bad = dir.join("missing").join("b.txt");
        let e = write_atomic(&bad, b"x").unwrap_err();
        assert_eq!(e.kind(), ErrorKind::Io);
        assert!(e.message().contains("b.txt"));
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        // An interrupted write: its registered temporary file is what the handler removes.
        let tmp = temp_beside(&dir.join("c.bin")).unwrap();
        std::fs::write(&tmp, b"partial").unwrap();
        assert_ne!(
            tmp,
            temp_beside(&dir.join("c.bin")).unwrap(),
            "unique per write"
        );
        // Only this test's files: other tests of this process may be writing (the real
        // handler removes everyone's, as the process is about to end).
        remove_partial(|p| p.starts_with(&dir));
        assert!(!tmp.exists());
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
