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
            while k.is_multiple_of(p) {
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
/// kernel, no 1/N): every row, then every column, gathered a few at a time into a contiguous
/// scratch that stays in cache (a whole-array transpose with a power-of-two row length thrashes
/// the cache's sets: it was 10 % of a diffraction-PSF training profile).
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
    fft2_rows(a, nx, ny, 0..ny, inverse);
}

/// [`fft2`] of an array whose rows outside `rows` are zero (a padded pupil): their row
/// transforms, zero, are skipped. The result is that of [`fft2`], bit for bit.
///
/// # Examples
/// ```
/// use rustfft::num_complex::Complex;
/// let mut a = vec![Complex::new(0.0f64, 0.0); 8 * 8];
/// a[3 * 8 + 2] = Complex::new(1.0, 0.5);
/// a[4 * 8 + 5] = Complex::new(-0.25, 2.0);
/// let mut b = a.clone();
/// tolray::fft::fft2(&mut a, 8, 8, false);
/// tolray::fft::fft2_rows(&mut b, 8, 8, 3..5, false);
/// assert_eq!(a, b);
/// ```
pub fn fft2_rows<T: Cached>(
    a: &mut [Complex<T>],
    nx: usize,
    ny: usize,
    rows: std::ops::Range<usize>,
    inverse: bool,
) {
    fft2_some(a, (nx, ny), rows, std::slice::from_ref(&(0..nx)), inverse);
}

/// [`fft2`] where only the columns in `cols` of the result are wanted: those are the columns of
/// [`fft2`], bit for bit; the others hold their rows' transforms only (the column stage skips
/// them).
///
/// # Examples
/// ```
/// use rustfft::num_complex::Complex;
/// let mut a: Vec<Complex<f64>> = (0..12 * 6).map(|k| Complex::new(k as f64, 1.0)).collect();
/// let mut b = a.clone();
/// tolray::fft::fft2(&mut a, 12, 6, false);
/// tolray::fft::fft2_cols(&mut b, 12, 6, &[0..2, 10..12], false);
/// for y in 0..6 {
///     for x in [0, 1, 10, 11] {
///         assert_eq!(a[y * 12 + x], b[y * 12 + x]);
///     }
/// }
/// ```
pub fn fft2_cols<T: Cached>(
    a: &mut [Complex<T>],
    nx: usize,
    ny: usize,
    cols: &[std::ops::Range<usize>],
    inverse: bool,
) {
    fft2_some(a, (nx, ny), 0..ny, cols, inverse);
}

/// The row transforms of `rows` (the others zero), then the column transforms of `cols`.
fn fft2_some<T: Cached>(
    a: &mut [Complex<T>],
    (nx, ny): (usize, usize),
    rows: std::ops::Range<usize>,
    cols: &[std::ops::Range<usize>],
    inverse: bool,
) {
    assert_eq!(a.len(), nx * ny, "fft2: {} values for {nx} x {ny}", a.len());
    assert!(
        cols.iter().all(|c| c.start <= c.end && c.end <= nx)
            && cols.windows(2).all(|p| p[0].end <= p[1].start),
        "fft2: columns {cols:?} of {nx} (ascending, disjoint)"
    );
    assert!(
        rows.start <= rows.end && rows.end <= ny,
        "fft2: rows {rows:?} of {ny}"
    );
    if nx == 0 || ny == 0 {
        return;
    }
    let (fx, ix) = T::plans(nx);
    let (fy, iy) = T::plans(ny);
    let (px, py) = if inverse { (ix, iy) } else { (fx, fy) };
    let zero = Complex::new(T::zero(), T::zero());
    let mut scratch = vec![
        zero;
        px.get_inplace_scratch_len()
            .max(py.get_inplace_scratch_len())
    ];
    if !rows.is_empty() {
        px.process_with_scratch(&mut a[rows.start * nx..rows.end * nx], &mut scratch);
    }
    // Columns COLS at a time, each copied into its own slice of `col` (a stride of ny plus a
    // few values, so that the slices do not share the cache's sets), transformed, copied back.
    const COLS: usize = 8;
    let stride = ny + 4;
    let mut col = vec![zero; COLS * stride];
    for x0 in cols.iter().flat_map(|c| c.clone().step_by(COLS)) {
        let end = cols.iter().find(|c| c.contains(&x0)).map_or(nx, |c| c.end);
        let w = COLS.min(end - x0);
        for y in 0..ny {
            for (k, v) in a[y * nx + x0..y * nx + x0 + w].iter().enumerate() {
                col[k * stride + y] = *v;
            }
        }
        for k in 0..w {
            py.process_with_scratch(&mut col[k * stride..k * stride + ny], &mut scratch);
        }
        for y in 0..ny {
            for (k, v) in a[y * nx + x0..y * nx + x0 + w].iter_mut().enumerate() {
                *v = col[k * stride + y];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The transform as it was first written: all rows, a whole-array transpose, all columns,
    /// a transpose back.
    fn by_transposes(a: &mut [Complex<f64>], nx: usize, ny: usize) {
        fn transpose<T: Copy>(src: &[T], dst: &mut [T], nx: usize, ny: usize) {
            for y in 0..ny {
                for x in 0..nx {
                    dst[x * ny + y] = src[y * nx + x];
                }
            }
        }
        let (px, _) = f64::plans(nx);
        let (py, _) = f64::plans(ny);
        px.process(a);
        let mut t = a.to_vec();
        transpose(a, &mut t, nx, ny);
        py.process(&mut t);
        transpose(&t, a, ny, nx);
    }

    /// Bit for bit the transform by whole-array transposes (results did not move when the
    /// column pass changed), on sizes with and without a partial last block of columns, and
    /// with the zero rows skipped.
    #[test]
    fn equals_the_transform_by_transposes_bit_for_bit() {
        for (nx, ny) in [(256, 256), (100, 36), (13, 7)] {
            let mut a: Vec<Complex<f64>> = (0..nx * ny)
                .map(|k| {
                    Complex::new(
                        ((k * 7919) % 1000) as f64 / 7.0,
                        ((k * 104_729) % 997) as f64,
                    )
                })
                .collect();
            // Zero rows outside the middle third.
            let rows = ny / 3..2 * ny / 3 + 1;
            for y in (0..ny).filter(|y| !rows.contains(y)) {
                a[y * nx..(y + 1) * nx].fill(Complex::new(0.0, 0.0));
            }
            let mut reference = a.clone();
            by_transposes(&mut reference, nx, ny);
            let mut b = a.clone();
            fft2(&mut a, nx, ny, false);
            fft2_rows(&mut b, nx, ny, rows, false);
            assert!(a == reference && b == reference, "{nx} x {ny}");
        }
    }

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
