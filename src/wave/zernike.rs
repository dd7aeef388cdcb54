//! Least-squares fits of Zernike polynomials to a sampled wavefront. The polynomials, their
//! orderings (OpticStudio's Standard = Noll and Fringe) and values are in
//! [`crate::math::zernike`], re-exported here.
//!
//! # Examples
//! ```
//! use tolray::wave::zernike::{zernike, Ordering};
//! // Standard Z4 (defocus) at the rim and centre.
//! assert!((zernike(Ordering::Standard, 4, 1.0, 0.0) - 3f64.sqrt()).abs() < 1e-15);
//! ```

use crate::error::{Error, Result};
pub use crate::math::zernike::{
    fringe_nm, noll_nm, radial, term_nm, term_poly, zernike, Ordering, FRINGE_TERMS, STANDARD_TERMS,
};
use serde::Serialize;

/// A Zernike fit: coefficients (in the units of the data) and the weighted RMS of what they
/// leave.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ZernikeFit {
    /// The ordering of `coefficients`.
    pub ordering: Ordering,
    /// Coefficients Z1, Z2, ... (index 0 holds Z1).
    pub coefficients: Vec<f64>,
    /// Weighted RMS of the data minus the fitted sum.
    pub residual_rms: f64,
}

/// Checks a term count for `ordering`.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for 0 terms, more than 37 Fringe terms or more than
/// [`STANDARD_TERMS`] Standard terms.
pub fn check_terms(ordering: Ordering, terms: usize) -> Result<()> {
    let max = ordering.max_terms();
    if terms == 0 || terms > max {
        return Err(Error::argument(format!(
            "{terms} Zernike {} terms: give 1 to {max}",
            match ordering {
                Ordering::Standard => "Standard",
                Ordering::Fringe => "Fringe",
            }
        )));
    }
    Ok(())
}

/// The first terms of an ordering evaluated at Cartesian points without trigonometry: the
/// fits evaluate every term at every ray, and [`zernike`]'s `atan2`, `sin`/`cos` and factorials
/// per value took a quarter of a Monte Carlo trial with the MTF criterion. `ρ^m cos mθ` and
/// `ρ^m sin mθ` are the parts of `(x + iy)^m`, and `R_n^m(ρ) / ρ^m` is a polynomial in `ρ²`
/// (Horner); equal to [`zernike`] to rounding (checked in the tests).
struct Basis {
    /// Per term: azimuthal order, sine term, normalisation, and the radial coefficients
    /// (integers, exact in f64), highest power of `ρ²` first.
    terms: Vec<(usize, bool, f64, Vec<f64>)>,
    max_m: usize,
}

impl Basis {
    fn new(ordering: Ordering, k: usize) -> Basis {
        let terms: Vec<(usize, bool, f64, Vec<f64>)> =
            (1..=k).map(|j| term_poly(ordering, j)).collect();
        let max_m = terms.iter().map(|t| t.0).max().unwrap_or(0);
        Basis { terms, max_m }
    }

    /// The terms at `p` into `out` (one value per term).
    fn at(&self, p: [f64; 2], out: &mut [f64]) {
        // (x + iy)^m for m = 0 ..= max_m: at most radial order 20, so a fixed array.
        let mut pw = [(0.0, 0.0); 21];
        pw[0] = (1.0, 0.0);
        for m in 1..=self.max_m {
            let (a, b) = pw[m - 1];
            pw[m] = (a * p[0] - b * p[1], a * p[1] + b * p[0]);
        }
        let r2 = p[0] * p[0] + p[1] * p[1];
        for ((m, sine, norm, coef), o) in self.terms.iter().zip(out) {
            let radial = coef.iter().fold(0.0, |acc, c| acc * r2 + c);
            *o = norm * radial * if *sine { pw[*m].1 } else { pw[*m].0 };
        }
    }
}

/// Fits `terms` terms of `ordering` to values `v` at unit-disk points `xy` with weights `w`
/// (quadrature weights, or equal weights for a uniform grid) by weighted least squares, solved
/// by Cholesky factorisation of the normal equations (well conditioned: over a disk sampled
/// well the Standard terms' Gram matrix is close to the identity).
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for a term count [`check_terms`] refuses;
/// [`crate::ErrorKind::Numerical`] when the points cannot determine that many terms (too few
/// points, or all on a few rings).
///
/// # Examples
/// ```
/// use tolray::wave::zernike::{fit, zernike, Ordering};
/// // Samples of 0.3 Z4 + 0.1 Z8 on a polar grid.
/// let mut xy = Vec::new();
/// for i in 0..12 {
///     for j in 0..24 {
///         let (r, t) = ((i as f64 + 0.5) / 12.0, std::f64::consts::TAU * j as f64 / 24.0);
///         xy.push([r * t.cos(), r * t.sin()]);
///     }
/// }
/// let v: Vec<f64> = xy.iter().map(|p| {
///     let (r, t) = (p[0].hypot(p[1]), p[1].atan2(p[0]));
///     0.3 * zernike(Ordering::Standard, 4, r, t) + 0.1 * zernike(Ordering::Standard, 8, r, t)
/// }).collect();
/// let w = vec![1.0; xy.len()];
/// let f = fit(Ordering::Standard, 11, &xy, &v, &w)?;
/// assert!((f.coefficients[3] - 0.3).abs() < 1e-12 && (f.coefficients[7] - 0.1).abs() < 1e-12);
/// assert!(f.residual_rms < 1e-12);
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn fit(
    ordering: Ordering,
    terms: usize,
    xy: &[[f64; 2]],
    v: &[f64],
    w: &[f64],
) -> Result<ZernikeFit> {
    check_terms(ordering, terms)?;
    let k = terms;
    // Basis values, point-major.
    let basis = Basis::new(ordering, k);
    let mut values = vec![0.0; xy.len() * k];
    for (p, out) in xy.iter().zip(values.chunks_exact_mut(k)) {
        basis.at(*p, out);
    }
    let basis = values;
    let mut g = vec![0.0; k * k];
    let mut b = vec![0.0; k];
    let mut wsum = 0.0;
    for (i, (&vi, &wi)) in v.iter().zip(w).enumerate() {
        let z = &basis[i * k..(i + 1) * k];
        for a in 0..k {
            let wa = wi * z[a];
            b[a] += wa * vi;
            for c in 0..=a {
                g[a * k + c] += wa * z[c];
            }
        }
        wsum += wi;
    }
    let singular = || {
        Error::numerical(format!(
            "the {} pupil points cannot determine {k} Zernike terms; sample the pupil more finely",
            xy.len()
        ))
    };
    if !(wsum > 0.0) {
        return Err(singular());
    }
    // Cholesky G = L Lᵀ (lower triangle of g), relative pivot floor against rank deficiency.
    let scale = (0..k).map(|a| g[a * k + a]).fold(0.0, f64::max);
    for a in 0..k {
        for c in 0..=a {
            let mut s = g[a * k + c];
            for e in 0..c {
                s -= g[a * k + e] * g[c * k + e];
            }
            if a == c {
                if !(s > 1e-12 * scale) {
                    return Err(singular());
                }
                g[a * k + a] = s.sqrt();
            } else {
                g[a * k + c] = s / g[c * k + c];
            }
        }
    }
    let mut y = b;
    for a in 0..k {
        let mut s = y[a];
        for e in 0..a {
            s -= g[a * k + e] * y[e];
        }
        y[a] = s / g[a * k + a];
    }
    for a in (0..k).rev() {
        let mut s = y[a];
        for e in a + 1..k {
            s -= g[e * k + a] * y[e];
        }
        y[a] = s / g[a * k + a];
    }
    let mut ss = 0.0;
    for (i, (&vi, &wi)) in v.iter().zip(w).enumerate() {
        let z = &basis[i * k..(i + 1) * k];
        let r = vi - z.iter().zip(&y).map(|(a, c)| a * c).sum::<f64>();
        ss += wi * r * r;
    }
    Ok(ZernikeFit {
        ordering,
        coefficients: y,
        residual_rms: (ss / wsum).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Noll's table (1976, Table 1) for the first 22 terms.
    #[test]
    fn noll_indices_follow_noll() {
        let want = [
            (0, 0, false),
            (1, 1, false),
            (1, 1, true),
            (2, 0, false),
            (2, 2, true),
            (2, 2, false),
            (3, 1, true),
            (3, 1, false),
            (3, 3, true),
            (3, 3, false),
            (4, 0, false),
            (4, 2, false),
            (4, 2, true),
            (4, 4, false),
            (4, 4, true),
            (5, 1, false),
            (5, 1, true),
            (5, 3, false),
            (5, 3, true),
            (5, 5, false),
            (5, 5, true),
            (6, 0, false),
        ];
        for (j, w) in want.iter().enumerate() {
            assert_eq!(noll_nm(j + 1), *w, "Noll j = {}", j + 1);
        }
    }

    /// The Fringe polynomials as OpticStudio's manual lists them (a few of them, in full).
    #[test]
    fn fringe_terms_are_opticstudios() {
        let (r, t) = (0.63f64, 0.41f64);
        let r2 = r * r;
        let cases: [(usize, f64); 10] = [
            (2, r * t.cos()),
            (6, r2 * (2.0 * t).sin()),
            (7, (3.0 * r2 - 2.0) * r * t.cos()),
            (9, 6.0 * r2 * r2 - 6.0 * r2 + 1.0),
            (13, (4.0 * r2 - 3.0) * r2 * (2.0 * t).sin()),
            (16, 20.0 * r2.powi(3) - 30.0 * r2 * r2 + 12.0 * r2 - 1.0),
            (20, (5.0 * r2 - 4.0) * r2 * r * (3.0 * t).sin()),
            (26, r2 * r2 * r * (5.0 * t).cos()),
            (
                35,
                (126.0 * r2.powi(4) - 280.0 * r2.powi(3) + 210.0 * r2 * r2 - 60.0 * r2 + 5.0)
                    * r
                    * t.sin(),
            ),
            (
                37,
                924.0 * r2.powi(6) - 2772.0 * r2.powi(5) + 3150.0 * r2.powi(4)
                    - 1680.0 * r2.powi(3)
                    + 420.0 * r2 * r2
                    - 42.0 * r2
                    + 1.0,
            ),
        ];
        for (j, want) in cases {
            let got = zernike(Ordering::Fringe, j, r, t);
            assert!((got - want).abs() < 1e-12, "Fringe Z{j}: {got} vs {want}");
        }
    }

    /// Standard terms are orthonormal over the disk (Gauss quadrature in ρ², uniform in θ).
    #[test]
    fn standard_terms_are_orthonormal() {
        let gl = crate::lens::qbfs::gauss_legendre(16);
        let k = 37;
        let mut g = vec![0.0; k * k];
        for &(x, wx) in &gl {
            let rho = (0.5 * (x + 1.0)).sqrt();
            for s in 0..40 {
                let t = std::f64::consts::TAU * (s as f64 + 0.5) / 40.0;
                let w = 0.5 * wx / 40.0;
                for a in 0..k {
                    for c in 0..k {
                        g[a * k + c] += w
                            * zernike(Ordering::Standard, a + 1, rho, t)
                            * zernike(Ordering::Standard, c + 1, rho, t);
                    }
                }
            }
        }
        for a in 0..k {
            for c in 0..k {
                let want = if a == c { 1.0 } else { 0.0 };
                assert!(
                    (g[a * k + c] - want).abs() < 1e-12,
                    "<Z{}, Z{}>",
                    a + 1,
                    c + 1
                );
            }
        }
    }

    #[test]
    fn the_fits_basis_equals_the_polar_terms() {
        for ordering in [Ordering::Standard, Ordering::Fringe] {
            let k = match ordering {
                Ordering::Standard => STANDARD_TERMS,
                Ordering::Fringe => FRINGE_TERMS,
            };
            let basis = Basis::new(ordering, k);
            let mut out = vec![0.0; k];
            for (r, t) in [
                (0.0, 0.0),
                (0.37, -2.1),
                (0.81, 0.4),
                (1.0, 2.9),
                (1.0, 0.0),
            ] {
                let p = [r * f64::cos(t), r * f64::sin(t)];
                basis.at(p, &mut out);
                for (j, v) in out.iter().enumerate() {
                    let want = zernike(ordering, j + 1, r, t);
                    assert!(
                        (v - want).abs() < 1e-10 * (1.0 + want.abs()),
                        "{ordering:?} Z{} at ({r}, {t}): {v} vs {want}",
                        j + 1
                    );
                }
            }
        }
    }

    #[test]
    fn term_counts_are_checked() {
        assert!(check_terms(Ordering::Fringe, 38).is_err());
        assert!(check_terms(Ordering::Standard, 0).is_err());
        assert!(check_terms(Ordering::Standard, 231).is_ok());
    }
}
