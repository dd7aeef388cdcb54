//! The Embree cross-check of [`tolray`]'s analytic tracer: every surface, nominal or perturbed,
//! is tessellated into a triangle mesh within a chosen chord error, traced with Intel Embree 4,
//! and the hits are compared with the analytic tracer's within the tessellation's own error.
//! The `tolray` command runs it as `tolray validate --embree` when built with its `embree`
//! feature (`cargo run --release --features embree -- validate lens2 --embree`).
//!
//! - [`device`]: a thin safe wrapper over `embree4-sys` (RAII device and scenes, a padded
//!   ray-hit structure proved by a sentinel test, Embree errors as [`tolray::Error`]).
//! - [`mesh`]: polar tessellation of a compiled surface with a derived chord bound.
//! - [`check`]: the Embree-driven sequential trace, its comparison with the analytic one, and
//!   the serializable report of `tolray validate --embree`.

#![warn(missing_docs)]
// `!(x > 0.0)` is written on purpose: unlike `x <= 0.0` it is true for NaN, so one comparison
// refuses both (as in the library).
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod check;
pub mod device;
pub mod mesh;

pub use check::{
    check_rays, check_system, validate, CaseReport, CheckOptions, Cover, FieldCheck, NormalMode,
    SurfaceCheck, Timing, ValidateOptions, ValidationReport, ValidationSummary,
};
pub use device::{Device, Hit, RayHit, Scene, SceneOptions};
pub use mesh::{Frame, Mesh};
