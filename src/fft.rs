//! FFTs: `rustfft` plans cached per thread and length, and the one 2-D transform the PSF,
//! wave-optics, rendering and Wiener code share.

use rustfft::num_complex::Complex;
use rustfft::{Fft, FftNum, FftPlanner};
use std::cell::RefCell;
use std::collections::HashMap;
use std::sync::Arc;

/// Forward and inverse plans of one length.
pub type Plans<T> = (Arc<dyn Fft<T>>, Arc<dyn Fft<T>>);

/// A number type whose plans are cached per thread.
pub trait Cached: FftNum {
    /// The forward and inverse plans of length `n`, planned once per thread.
    fn plans(n: usize) -> Plans<Self>;
}

macro_rules! cached {
    ($t:ty) => {
        impl Cached for $t {
            fn plans(n: usize) -> Plans<$t> {
                thread_local! {
                    static PLANS: RefCell<(FftPlanner<$t>, HashMap<usize, Plans<$t>>)> =
                        RefCell::new((FftPlanner::new(), HashMap::new()));
                }
                PLANS.with(|p| {
                    let mut p = p.borrow_mut();
                    let (planner, cache) = &mut *p;
                    cache
                        .entry(n)
                        .or_insert_with(|| {
                            (planner.plan_fft_forward(n), planner.plan_fft_inverse(n))
                        })
                        .clone()
                })
            }
        }
    };
}
cached!(f32);
cached!(f64);

/// The smallest `2^a 3^b 5^c >= n` (at least 1): a length rustfft transforms fast.
///
/// # Examples
/// ```
/// assert_eq!(tolray::fft::fast_size(97), 100);
/// assert_eq!(tolray::fft::fast_size(0), 1);
/// ```
pub fn fast_size(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut k = m;
        for p in [2, 3, 5] {
            while k % p == 0 {
                k /= p;
            }
        }
        if k == 1 {
            return m;
        }
        m += 1;
    }
}

/// In-place unnormalised 2-D DFT of an `nx x ny` row-major array (`inverse`: the conjugate
/// kernel, no 1/N): every row in one call, then every column the same way through a transpose,
/// so that both passes run over contiguous memory.
///
/// # Examples
/// ```
/// use rustfft::num_complex::Complex;
/// // A unit impulse at the origin transforms to all ones.
/// let mut a = vec![Complex::new(0.0f64, 0.0); 8 * 4];
/// a[0] = Complex::new(1.0, 0.0);
/// tolray::fft::fft2(&mut a, 8, 4, false);
/// assert!(a.iter().all(|v| (v.re - 1.0).abs() < 1e-15 && v.im.abs() < 1e-15));
/// ```
pub fn fft2<T: Cached>(a: &mut [Complex<T>], nx: usize, ny: usize, inverse: bool) {
    assert_eq!(a.len(), nx * ny, "fft2: {} values for {nx} x {ny}", a.len());
    let (fx, ix) = T::plans(nx);
    let (fy, iy) = T::plans(ny);
    let (px, py) = if inverse { (ix, iy) } else { (fx, fy) };
    px.process(a);
    let mut t = a.to_vec();
    transpose(a, &mut t, nx, ny);
    py.process(&mut t);
    transpose(&t, a, ny, nx);
}

/// `dst` = the `ny x nx` transpose of the `nx x ny` (row length `nx`) array `src`, in
/// cache-sized tiles.
fn transpose<T: Copy>(src: &[T], dst: &mut [T], nx: usize, ny: usize) {
    const B: usize = 32;
    for y0 in (0..ny).step_by(B) {
        for x0 in (0..nx).step_by(B) {
            for y in y0..(y0 + B).min(ny) {
                for x in x0..(x0 + B).min(nx) {
                    dst[x * ny + y] = src[y * nx + x];
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against the direct DFT of a random rectangular array, forward and inverse.
    #[test]
    fn matches_the_direct_dft() {
        let (nx, ny) = (6, 5);
        let a: Vec<Complex<f64>> = (0..nx * ny)
            .map(|k| Complex::new((k * 37 % 11) as f64 - 5.0, (k * 17 % 7) as f64 - 3.0))
            .collect();
        for inverse in [false, true] {
            let mut f = a.clone();
            fft2(&mut f, nx, ny, inverse);
            let s = if inverse { 1.0 } else { -1.0 };
            for v in 0..ny {
                for u in 0..nx {
                    let mut d = Complex::new(0.0, 0.0);
                    for y in 0..ny {
                        for x in 0..nx {
                            let ph = s
                                * std::f64::consts::TAU
                                * ((u * x) as f64 / nx as f64 + (v * y) as f64 / ny as f64);
                            d += a[y * nx + x] * Complex::from_polar(1.0, ph);
                        }
                    }
                    assert!((d - f[v * nx + u]).norm() < 1e-12);
                }
            }
        }
    }
}
