//! # tolray
//!
//! Tolerance-aware lens design: a fast, exact, differentiable CPU ray tracer for refractive
//! lenses that models manufacturing and assembly tolerances.
//!
//! - [`lens`]: prescriptions ([`lens::Lens`]), DeepLens JSON, materials, paraxial analysis, and
//!   the compiled flat table ([`lens::System`]) the tracer runs on.
//! - [`trace`]: ray batches, the generic kernel (f32, f64, dual numbers), ray generation, and a
//!   scalar reference tracer.
//! - [`analysis`]: spot diagrams and statistics.
//! - `embree` (feature `embree`): the Embree 4 cross-check of every intersection.
//!
//! Units: millimetres for lengths, micrometres for spot sizes, nanometres for wavelengths,
//! degrees for angles in files. Surfaces are counted from 0. Frame: z is the optical axis, light
//! travels toward +z, the first vertex is at z = 0, y is the meridional axis.

#![warn(missing_docs)]
// `!(x > 0.0)` is written on purpose throughout: unlike `x <= 0.0` it is true for NaN, so one
// comparison refuses both (clippy would have `partial_cmp`, which reads worse for floats).
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Numerical loops index several arrays in step (dual-number lanes, channels, levels); the index
// form is the one the kernels are written and vectorized in.
#![allow(clippy::needless_range_loop)]

pub mod analysis;
pub mod decoder;
pub mod deep;
#[cfg(feature = "embree")]
pub mod embree;
pub mod error;
pub mod ffi;
pub mod figures;
pub mod image;
pub mod lens;
pub mod math;
pub mod optim;
pub mod plot;
pub mod psf;
pub mod real;
pub mod tolerance;
pub mod trace;

pub use error::{Error, ErrorKind, Result};
pub use lens::{Lens, Object};
