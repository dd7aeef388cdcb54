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
