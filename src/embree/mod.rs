//! Embree cross-check (feature `embree`): every surface, nominal or perturbed, is tessellated
//! into a triangle mesh within a chosen chord error, traced with Intel Embree 4, and the hits
//! are compared with the analytic tracer's within the tessellation's own error.
//!
//! - [`device`]: a thin safe wrapper over `embree4-sys` (RAII device and scenes, a padded
//!   ray-hit structure proved by a sentinel test, Embree errors as [`crate::Error`]).
//! - [`mesh`]: polar tessellation of a compiled surface with a derived chord bound.
//! - [`check`]: the Embree-driven sequential trace, its comparison with the analytic one, and
//!   the serializable report of `tolray validate --embree`.

pub mod check;
pub mod device;
pub mod mesh;

pub use check::{
    check_rays, check_system, validate, CaseReport, CheckOptions, Cover, FieldCheck, NormalMode,
    SurfaceCheck, Timing, ValidateOptions, ValidationReport, ValidationSummary,
};
pub use device::{Device, Hit, RayHit, Scene, SceneOptions};
pub use mesh::{Frame, Mesh};
