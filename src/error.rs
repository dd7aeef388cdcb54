//! The library's one error type.

use std::path::Path;
use std::sync::Arc;

/// What kind of failure an [`Error`] is. New kinds may be added.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum ErrorKind {
    /// A file or directory could not be read or written.
    Io,
    /// Input text is not well-formed (JSON syntax, CSV fields, numbers).
    Parse,
    /// Input is well-formed but describes something invalid (negative gap, unknown glass, ...).
    Invalid,
    /// A computation could not produce a result (no rays reached the image, singular system, ...).
    Numerical,
    /// An argument to a library function is out of its domain.
    Argument,
}

/// An error with a message that says what was wrong and where (file, line, surface index).
///
/// Its parts are read through [`Error::kind`] and [`Error::message`]; an I/O error keeps the
/// operating system's error as its [`std::error::Error::source`] (the message names the path),
/// so that error reporters print the whole chain, as `tolray`'s CLI does: `lens.json: No such
/// file or directory (os error 2)`.
///
/// # Examples
/// ```
/// use tolray::ErrorKind;
/// let path = std::path::Path::new("no-such-dir/spec.json");
/// let e = tolray::files::read_json::<serde_json::Value>(path).unwrap_err();
/// assert_eq!(e.kind(), ErrorKind::Io);
/// assert_eq!(e.message(), "no-such-dir/spec.json");
/// let os = std::error::Error::source(&e).unwrap().to_string();
/// assert!(e.full_message().ends_with(&os));
/// ```
#[derive(Clone, Debug, thiserror::Error)]
#[error("{message}")]
pub struct Error {
    kind: ErrorKind,
    message: String,
    #[source]
    source: Option<Arc<std::io::Error>>,
}

/// Errors are equal when their kinds and messages are (an I/O source compares by its text).
impl PartialEq for Error {
    fn eq(&self, other: &Self) -> bool {
        self.kind == other.kind
            && self.message == other.message
            && self.source.as_ref().map(|e| e.to_string())
                == other.source.as_ref().map(|e| e.to_string())
    }
}

impl Eq for Error {}

/// `Result` with the library's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// A new error of `kind` with `message`.
    pub fn new(kind: ErrorKind, message: impl Into<String>) -> Self {
        Error {
            kind,
            message: message.into(),
            source: None,
        }
    }
    /// Shorthand for an [`ErrorKind::Invalid`] error.
    pub fn invalid(message: impl Into<String>) -> Self {
        Error::new(ErrorKind::Invalid, message)
    }
    /// Shorthand for an [`ErrorKind::Argument`] error.
    pub fn argument(message: impl Into<String>) -> Self {
        Error::new(ErrorKind::Argument, message)
    }
    /// Shorthand for an [`ErrorKind::Numerical`] error.
    pub fn numerical(message: impl Into<String>) -> Self {
        Error::new(ErrorKind::Numerical, message)
    }
    /// An I/O error on `path`: the message names the path, `e` is kept as the source.
    pub fn io(path: &Path, e: std::io::Error) -> Self {
        Error {
            kind: ErrorKind::Io,
            message: path.display().to_string(),
            source: Some(Arc::new(e)),
        }
    }
    /// The kind of failure.
    pub fn kind(&self) -> ErrorKind {
        self.kind
    }
    /// The message: what was wrong and where (without the source of an I/O error).
    pub fn message(&self) -> &str {
        &self.message
    }
    /// The message followed by the source's, `message: source` (what the CLI prints, and the C
    /// ABI's last-error text).
    pub fn full_message(&self) -> String {
        match &self.source {
            Some(e) => format!("{}: {e}", self.message),
            None => self.message.clone(),
        }
    }
    /// Prefixes the message with a location such as a file name.
    pub fn context(mut self, place: impl std::fmt::Display) -> Self {
        self.message = format!("{place}: {}", self.message);
        self
    }
}
