//! # tolray
//!
//! Tolerance-aware lens design: a fast, exact, differentiable CPU ray tracer for refractive
//! lenses that models manufacturing and assembly tolerances, and the deep-optics half of the
//! paper "Tolerance-Aware Deep Optics" (a lens designed together with its image decoder and
//! judged over randomly fabricated units).
//!
//! Modules:
//! - [`lens`]: prescriptions ([`lens::Lens`]), DeepLens JSON and Zemax .zmx, materials, paraxial
//!   analysis, and the compiled flat table ([`lens::System`]) the tracer runs on.
//! - [`trace`]: ray batches, the generic kernel (f32, f64, dual numbers), ray generation, the
//!   bundles of rays every analysis and loss traces ([`trace::Bundles`]), and a scalar reference
//!   tracer.
//! - [`real`]: the number types the kernel is generic over (dual numbers for exact gradients).
//! - [`analysis`]: spot diagrams and statistics, and the spot moments every spot size and
//!   refocus is computed from ([`analysis::SpotMoments`]).
//! - [`tolerance`]: tolerance specs, sampled patterns (fabricated units), Monte Carlo,
//!   sensitivity.
//! - [`psf`]: point spread functions and PSF maps, the PSF-similarity loss.
//! - [`optim`]: objectives and their gradients, Adam, the paper's two-stage optics training.
//! - [`image`]: images in linear light, the dead-leaves generator, spatially variant rendering.
//! - [`decoder`]: the jointly trained decoder (per-tile Wiener + U-Net) with exact backward
//!   passes.
//! - [`deep`]: deep-optics training (lens and decoder), the study and its yield evaluation.
//! - [`wave`]: wave optics: OPD against the reference sphere, RMS/PV wavefront error, Zernike
//!   fits (Standard and Fringe), Strehl ratios, FFT and Huygens diffraction PSFs, MTFs.
//! - [`figures`]: the pictures the CLI writes (plotters, PNG or SVG).
//! - [`ffi`]: the C ABI (`include/tolray.h`).
//! - [`error`], [`files`], [`math`]: errors with their kind and I/O source; JSON reading and atomic
//!   writes that an interrupted program cleans up; small vector algebra.
//!
//! ```
//! use tolray::analysis::{spot_diagram, SpotOptions};
//! use tolray::trace::{Field, Pupil, TraceOptions};
//! use tolray::Lens;
//!
//! # fn main() -> tolray::Result<()> {
//! let lens = Lens::load("cooke-triplet")?; // a built-in lens, a .json or a .zmx file
//! let p = lens.paraxial(587.5618)?;
//! assert!(p.efl_mm.is_some_and(f64::is_finite)); // None for an afocal lens
//! let opts = SpotOptions {
//!     fields: vec![Field::fraction(0.0), Field::fraction(1.0)],
//!     wavelengths_nm: vec![587.5618],
//!     pupil: Pupil::grid(32),
//!     trace: TraceOptions { apertures: true },
//! };
//! for r in spot_diagram(&lens, &lens.compile(), &opts)? {
//!     println!("field {:?}: RMS spot {:.2} µm", r.field, r.stats.rms_um);
//! }
//! # Ok(())
//! # }
//! ```
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
pub mod error;
pub mod ffi;
pub mod fft;
pub mod figures;
pub mod files;
pub mod image;
pub mod lens;
pub mod math;
pub mod optim;
pub mod psf;
pub mod real;
pub mod tolerance;
pub mod trace;
pub mod wave;

pub use error::{Error, ErrorKind, Result};
pub use lens::{Lens, Object};
