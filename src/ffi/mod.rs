//! The C ABI: `extern "C"` functions over opaque handles, declared in `include/tolray.h`.
//!
//! Rules (the header repeats them for C users):
//! - Names are `tolray_<noun>_<verb>`. Handles come from `_new`/`_load`/`_from_json`/`_sample`
//!   functions and go back through the matching `_free`; `_free(NULL)` does nothing.
//! - Every function returns a [`tolray_status`]; outputs are the last parameters and are written
//!   only when the status is [`tolray_status::TOLRAY_OK`]. On failure a message naming what was
//!   wrong is kept per thread and read with [`tolray_last_error`].
//! - Every body runs inside a panic boundary; a panic becomes `TOLRAY_ERROR_PANIC`, never an
//!   unwind into C. Every pointer is checked for NULL and every buffer for its size.
//! - Handles are immutable after creation, so one handle may be used from many threads at once.
//!
//! The header is generated from this module by cbindgen (`cbindgen.toml`); `tests/capi/`
//! regenerates it and fails if the committed header differs.

#![allow(non_camel_case_types)]
#![allow(clippy::missing_safety_doc)]
// every function has a `# Safety` section in the header text

// Every unsafe block says why it is sound (enforced: CI denies clippy warnings).
#![warn(clippy::undocumented_unsafe_blocks)]

mod geometric;
mod handles;
mod train;
mod wave;

pub use geometric::*;
pub use handles::*;
pub use train::*;
pub use wave::*;

use crate::error::{Error, ErrorKind};
use std::cell::RefCell;
use std::ffi::{c_char, CStr};
use std::panic::{catch_unwind, AssertUnwindSafe};

/// Major version of the library (the `x` of `x.y.z` in Cargo.toml).
pub const TOLRAY_VERSION_MAJOR: u32 = 0;
/// Minor version of the library.
pub const TOLRAY_VERSION_MINOR: u32 = 1;
/// Patch version of the library.
pub const TOLRAY_VERSION_PATCH: u32 = 0;
/// Version of the C ABI: raised whenever a declaration in `tolray.h` changes incompatibly.
pub const TOLRAY_ABI_VERSION: u32 = 3;

/// Outcome of a C ABI call. The numeric values are fixed and will never be reused.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum tolray_status {
    /// Success; outputs were written.
    TOLRAY_OK = 0,
    /// A required pointer argument was NULL.
    TOLRAY_ERROR_NULL_ARGUMENT = 1,
    /// A buffer length or count does not match what the call needs.
    TOLRAY_ERROR_BUFFER_SIZE = 2,
    /// A file could not be read.
    TOLRAY_ERROR_IO = 3,
    /// Input text is malformed (JSON syntax, not UTF-8).
    TOLRAY_ERROR_PARSE = 4,
    /// Input is well-formed but invalid (an impossible lens, an unknown glass or built-in name).
    TOLRAY_ERROR_INVALID_INPUT = 5,
    /// The computation failed (no ray reached the image, an entrance pupil at infinity).
    TOLRAY_ERROR_NUMERICAL = 6,
    /// An argument is out of its domain (an unknown enum value, a surface that does not exist).
    TOLRAY_ERROR_ARGUMENT = 7,
    /// An internal error (a Rust panic) was caught at the boundary. Please report it.
    TOLRAY_ERROR_PANIC = 8,
}

impl tolray_status {
    fn from_kind(kind: ErrorKind) -> tolray_status {
        match kind {
            ErrorKind::Io => tolray_status::TOLRAY_ERROR_IO,
            ErrorKind::Parse => tolray_status::TOLRAY_ERROR_PARSE,
            ErrorKind::Numerical => tolray_status::TOLRAY_ERROR_NUMERICAL,
            ErrorKind::Argument => tolray_status::TOLRAY_ERROR_ARGUMENT,
            _ => tolray_status::TOLRAY_ERROR_INVALID_INPUT,
        }
    }

    fn text(self) -> &'static CStr {
        match self {
            tolray_status::TOLRAY_OK => c"ok",
            tolray_status::TOLRAY_ERROR_NULL_ARGUMENT => c"a required pointer argument was NULL",
            tolray_status::TOLRAY_ERROR_BUFFER_SIZE => c"a buffer length or count is wrong",
            tolray_status::TOLRAY_ERROR_IO => c"a file could not be read",
            tolray_status::TOLRAY_ERROR_PARSE => c"malformed input text",
            tolray_status::TOLRAY_ERROR_INVALID_INPUT => c"invalid input",
            tolray_status::TOLRAY_ERROR_NUMERICAL => c"the computation failed",
            tolray_status::TOLRAY_ERROR_ARGUMENT => c"an argument is out of its domain",
            tolray_status::TOLRAY_ERROR_PANIC => c"internal error (caught panic)",
        }
    }
}

/// An error on its way out through the C boundary.
pub(crate) struct FfiError {
    status: tolray_status,
    message: String,
}

impl FfiError {
    pub(crate) fn new(status: tolray_status, message: impl Into<String>) -> Self {
        FfiError {
            status,
            message: message.into(),
        }
    }
    pub(crate) fn null(what: &str) -> Self {
        FfiError::new(
            tolray_status::TOLRAY_ERROR_NULL_ARGUMENT,
            format!("{what} is NULL"),
        )
    }
    pub(crate) fn size(message: impl Into<String>) -> Self {
        FfiError::new(tolray_status::TOLRAY_ERROR_BUFFER_SIZE, message)
    }
    pub(crate) fn argument(message: impl Into<String>) -> Self {
        FfiError::new(tolray_status::TOLRAY_ERROR_ARGUMENT, message)
    }
}

impl From<Error> for FfiError {
    fn from(e: Error) -> Self {
        FfiError::new(tolray_status::from_kind(e.kind()), e.full_message())
    }
}

pub(crate) type FfiResult<T> = std::result::Result<T, FfiError>;

thread_local! {
    static LAST_ERROR: RefCell<String> = const { RefCell::new(String::new()) };
}

fn set_last_error(message: String) {
    LAST_ERROR.with(|m| *m.borrow_mut() = message);
}

/// Runs `body` inside the panic boundary and turns its outcome into a status, recording the
/// message of a failure as this thread's last error.
pub(crate) fn boundary(name: &str, body: impl FnOnce() -> FfiResult<()>) -> tolray_status {
    match catch_unwind(AssertUnwindSafe(body)) {
        Ok(Ok(())) => tolray_status::TOLRAY_OK,
        Ok(Err(e)) => {
            set_last_error(format!("{name}: {}", e.message));
            e.status
        }
        Err(payload) => {
            let what = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            set_last_error(format!("{name}: internal error: {what}"));
            tolray_status::TOLRAY_ERROR_PANIC
        }
    }
}

/// A shared reference from a C pointer, or a NULL-argument error naming `what`.
pub(crate) unsafe fn nonnull<'a, T>(p: *const T, what: &str) -> FfiResult<&'a T> {
    // SAFETY: the caller promises that a non-NULL `p` points to a live, aligned `T`.
    unsafe { p.as_ref() }.ok_or_else(|| FfiError::null(what))
}

/// A UTF-8 string from a NUL-terminated C string.
pub(crate) unsafe fn c_str<'a>(p: *const c_char, what: &str) -> FfiResult<&'a str> {
    if p.is_null() {
        return Err(FfiError::null(what));
    }
    // SAFETY: the caller promises a NUL-terminated string.
    unsafe { CStr::from_ptr(p) }.to_str().map_err(|e| {
        FfiError::new(
            tolray_status::TOLRAY_ERROR_PARSE,
            format!("{what} is not UTF-8: {e}"),
        )
    })
}

/// A slice of `n` elements from a C pointer; NULL is allowed only when `n` is 0.
pub(crate) unsafe fn c_slice<'a, T>(p: *const T, n: usize, what: &str) -> FfiResult<&'a [T]> {
    if n == 0 {
        return Ok(&[]);
    }
    if p.is_null() {
        return Err(FfiError::null(what));
    }
    if n > isize::MAX as usize / std::mem::size_of::<T>().max(1) {
        return Err(FfiError::size(format!("{what}: count {n} is too large")));
    }
    // SAFETY: the caller promises `n` readable elements at `p`.
    Ok(unsafe { std::slice::from_raw_parts(p, n) })
}

/// Copies `text` and a NUL into `buf` of `cap` bytes; see [`tolray_lens_to_json`] for the
/// protocol (`buf` NULL and `cap` 0 asks for the length).
pub(crate) unsafe fn copy_text(
    text: &str,
    buf: *mut c_char,
    cap: usize,
    len_out: *mut usize,
) -> FfiResult<()> {
    if len_out.is_null() {
        return Err(FfiError::null("len_out"));
    }
    if buf.is_null() {
        if cap != 0 {
            return Err(FfiError::null("buf (with a nonzero capacity)"));
        }
    } else {
        if cap < text.len() + 1 {
            return Err(FfiError::size(format!(
                "buf holds {cap} bytes; the text needs {} (including the NUL)",
                text.len() + 1
            )));
        }
        // SAFETY: `buf` has `cap` >= len + 1 writable bytes (caller's promise, size checked).
        unsafe {
            std::ptr::copy_nonoverlapping(text.as_ptr(), buf.cast::<u8>(), text.len());
            *buf.add(text.len()) = 0;
        }
    }
    // SAFETY: checked non-NULL above.
    unsafe { *len_out = text.len() };
    Ok(())
}

/// The library version as a static NUL-terminated string, e.g. `"0.1.0"`. Never fails.
#[no_mangle]
pub extern "C" fn tolray_version() -> *const c_char {
    const V: &CStr =
        match CStr::from_bytes_with_nul(concat!(env!("CARGO_PKG_VERSION"), "\0").as_bytes()) {
            Ok(v) => v,
            Err(_) => c"?",
        };
    V.as_ptr()
}

/// The ABI version this library was built with (`TOLRAY_ABI_VERSION`). Programs compare it
/// with the header's macro at start-up.
#[no_mangle]
pub extern "C" fn tolray_abi_version() -> u32 {
    TOLRAY_ABI_VERSION
}

/// A static NUL-terminated description of a status value; unknown values give
/// `"unknown status"`. Never fails.
#[no_mangle]
pub extern "C" fn tolray_status_str(status: u32) -> *const c_char {
    let all = [
        tolray_status::TOLRAY_OK,
        tolray_status::TOLRAY_ERROR_NULL_ARGUMENT,
        tolray_status::TOLRAY_ERROR_BUFFER_SIZE,
        tolray_status::TOLRAY_ERROR_IO,
        tolray_status::TOLRAY_ERROR_PARSE,
        tolray_status::TOLRAY_ERROR_INVALID_INPUT,
        tolray_status::TOLRAY_ERROR_NUMERICAL,
        tolray_status::TOLRAY_ERROR_ARGUMENT,
        tolray_status::TOLRAY_ERROR_PANIC,
    ];
    all.iter()
        .find(|s| **s as u32 == status)
        .map_or(c"unknown status", |s| s.text())
        .as_ptr()
}

/// Copies the message of the last failed call on this thread into `buf` (`cap` bytes),
/// truncated if needed and always NUL-terminated when `cap` > 0, like `snprintf`. Returns the
/// message's full length in bytes, without the NUL (0 if no call has failed on this thread).
/// `buf` may be NULL when `cap` is 0. Successful calls leave the message unchanged.
///
/// # Safety
/// `buf` must point to `cap` writable bytes (or be NULL with `cap` 0).
#[no_mangle]
pub unsafe extern "C" fn tolray_last_error(buf: *mut c_char, cap: usize) -> usize {
    catch_unwind(|| {
        LAST_ERROR.with(|m| {
            let m = m.borrow();
            if !buf.is_null() && cap > 0 {
                let mut n = m.len().min(cap - 1);
                while !m.is_char_boundary(n) {
                    n -= 1;
                }
                // SAFETY: `buf` has `cap` > n writable bytes (caller's promise).
                unsafe {
                    std::ptr::copy_nonoverlapping(m.as_ptr(), buf.cast::<u8>(), n);
                    *buf.add(n) = 0;
                }
            }
            m.len()
        })
    })
    .unwrap_or(0)
}
