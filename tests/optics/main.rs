//! The optics half's integration tests, one module per subject, in one test crate (one build and
//! link of the library's test dependencies instead of a dozen; the Zemax tests are their own
//! crate, `tests/zemax/`, so that the two compile side by side on two cores): `cargo test
//! --release --test optics`, or one subject with a filter, e.g. `cargo test --release --test
//! optics wave::`.

mod aberrations;
mod constraints;
mod criterion;
#[path = "../common/double_double.rs"]
mod double_double;
mod gradient;
mod grating;
mod grin;
mod json;
mod psf;
mod reference;
mod tolerance;
mod tracer;
mod training;
mod wave;
mod wave_reference;
