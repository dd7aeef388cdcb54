//! Standard normal draws by the Box–Muller transform: the one sampler behind the tolerance
//! sampler's normal distributions, the sensor noise and the U-Net's initial weights.
//!
//! Every draw takes two uniforms from the generator, `u1` in (0, 1] (so the logarithm is finite)
//! and `u2` in [0, 1), and forms `r = √(−2 ln u1)` and `a = 2π u2`; [`pair`] returns both normals
//! `r cos a` and `r sin a`, [`one`] and [`scaled_f32`] the first only. A stream's draw order is
//! therefore fixed: seeded generators give the same numbers whoever calls.
//!
//! ```
//! use rand::SeedableRng;
//! let mut a = rand_chacha::ChaCha8Rng::seed_from_u64(7);
//! let mut b = a.clone();
//! let (z0, _) = tolray::math::normal::pair(&mut a);
//! assert_eq!(tolray::math::normal::one(&mut b), z0);
//! ```

use rand::Rng;

/// `(r, a)` of one Box–Muller draw in f64.
#[inline]
fn polar<R: Rng + ?Sized>(rng: &mut R) -> (f64, f64) {
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random();
    ((-2.0 * u1.ln()).sqrt(), std::f64::consts::TAU * u2)
}

/// Two independent standard normals from two uniforms (f64).
pub fn pair<R: Rng + ?Sized>(rng: &mut R) -> (f64, f64) {
    let (r, a) = polar(rng);
    (r * a.cos(), r * a.sin())
}

/// One standard normal from two uniforms (f64): the first of [`pair`].
pub fn one<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    let (r, a) = polar(rng);
    r * a.cos()
}

/// `std` times one standard normal, computed in f32 from two f32 uniforms as
/// `std · √(−2 ln u1) · cos(2π u2)` (the order of the products is part of the result).
pub fn scaled_f32<R: Rng + ?Sized>(rng: &mut R, std: f32) -> f32 {
    let u1: f32 = 1.0 - rng.random::<f32>();
    let u2: f32 = rng.random();
    std * (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
}
