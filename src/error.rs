//! The library's one error type.

use std::path::Path;

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
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{message}")]
pub struct Error {
    /// The kind of failure.
    pub kind: ErrorKind,
    /// Human-readable message naming the place and the problem.
    pub message: String,
}

/// `Result` with the library's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// A new error of `kind` with `message`.
    pub fn new(kind: ErrorKind, message: impl Into<String>) -> Self {
        Error {
            kind,
            message: message.into(),
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
    /// An I/O error on `path`.
    pub fn io(path: &Path, e: std::io::Error) -> Self {
        Error::new(ErrorKind::Io, format!("{}: {e}", path.display()))
    }
    /// Prefixes the message with a location such as a file name.
    pub fn context(mut self, place: impl std::fmt::Display) -> Self {
        self.message = format!("{place}: {}", self.message);
        self
    }
}
