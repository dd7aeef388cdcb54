//! Zernike polynomials on the unit disk in OpticStudio's two orderings, and their least-squares
//! fit to a sampled wavefront.
//!
//! - **Standard** ([`Ordering::Standard`]): Noll's (1976) ordering and normalisation, orthonormal
//!   over the unit disk (the mean of `Z_j Z_k` over the disk is `δ_jk`): Z1 = 1, Z2 = 2ρ cos θ,
//!   Z3 = 2ρ sin θ, Z4 = √3 (2ρ² − 1), Z5 = √6 ρ² sin 2θ, Z6 = √6 ρ² cos 2θ, …; for m ≠ 0 an even
//!   index holds the cosine term and an odd index the sine term. This is OpticStudio's "Zernike
//!   Standard"; optiland's `"standard"` is the OSA/ANSI ordering and its `"noll"` this one.
//! - **Fringe** ([`Ordering::Fringe`]): the University of Arizona ordering, unnormalised (each
//!   term is 1 at ρ = 1, θ = 0 for its cosine form): Z4 = 2ρ² − 1, Z9 = 6ρ⁴ − 6ρ² + 1, …, 37 terms
//!   (Z37 = the 12th-order spherical term).
//!
//! θ is measured from the x axis toward y, as in OpticStudio.
//!
//! # Examples
//! ```
//! use tolray::wave::zernike::{zernike, Ordering};
//! // Standard Z4 (defocus) at the rim and centre.
//! assert!((zernike(Ordering::Standard, 4, 1.0, 0.0) - 3f64.sqrt()).abs() < 1e-15);
//! assert!((zernike(Ordering::Standard, 4, 0.0, 0.0) + 3f64.sqrt()).abs() < 1e-15);
//! // Fringe Z9 (primary spherical) is 1 at the rim.
//! assert!((zernike(Ordering::Fringe, 9, 1.0, 0.3) - 1.0).abs() < 1e-14);
//! ```

use crate::error::{Error, Result};
use serde::Serialize;

/// A Zernike ordering (and normalisation).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Ordering {
    /// OpticStudio's Zernike Standard: Noll's ordering, orthonormal on the unit disk.
    Standard,
    /// OpticStudio's Zernike Fringe: the University of Arizona ordering, 37 terms, unnormalised.
    Fringe,
}

/// Most Fringe terms (OpticStudio's Fringe set ends at Z37).
pub const FRINGE_TERMS: usize = 37;
/// Most Standard terms tolray fits (radial order up to 20).
pub const STANDARD_TERMS: usize = 231;

/// The radial order n, azimuthal order m (>= 0) and whether the term is a sine term, of Noll's
/// index `j` (from 1).
#[must_use]
pub fn noll_nm(j: usize) -> (usize, usize, bool) {
    assert!(j >= 1, "Noll indices start at 1");
    let mut n = 0;
    let mut j1 = j - 1;
    while j1 > n {
        n += 1;
        j1 -= n;
    }
    // Within radial order n, |m| grows with the index; pairs (cos, sin) share an |m|.
    let m = (n % 2) + 2 * ((j1 + (n + 1) % 2) / 2);
    (n, m, m != 0 && j % 2 == 1)
}

/// The (n, m, sine) of Fringe index `j` (1..=37): terms 1..=36 grouped by (n + m) / 2, within
/// a group by decreasing m, cosine before sine; Z37 is the 12th-order spherical term.
#[must_use]
pub fn fringe_nm(j: usize) -> (usize, usize, bool) {
    assert!(
        (1..=FRINGE_TERMS).contains(&j),
        "Fringe indices run from 1 to 37"
    );
    // The set ends with the 12th-order spherical term, out of the pattern of the rest.
    if j == FRINGE_TERMS {
        return (12, 0, false);
    }
    let mut k = 0;
    // Group g holds m = g, g-1, ..., 0 with n = 2g - m; m > 0 terms twice.
    for g in 0.. {
        for m in (0..=g).rev() {
            let n = 2 * g - m;
            for sine in [false, true] {
                if sine && m == 0 {
                    continue;
                }
                k += 1;
                if k == j {
                    return (n, m, sine);
                }
            }
        }
        if g > 6 {
            break;
        }
    }
    unreachable!("Fringe index {j} within 1..=36 is always found")
}

/// The radial polynomial R_n^m(ρ) (n − m even, m <= n).
#[must_use]
pub fn radial(n: usize, m: usize, rho: f64) -> f64 {
    let mut sum = 0.0;
    for k in 0..=(n - m) / 2 {
        let c = fact(n - k) / (fact(k) * fact((n + m) / 2 - k) * fact((n - m) / 2 - k));
        let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
        sum += sign * c * rho.powi((n - 2 * k) as i32);
    }
    sum
}

fn fact(k: usize) -> f64 {
    (1..=k).map(|v| v as f64).product()
}

/// The (n, m, sine) of term `j` in `ordering`.
#[must_use]
pub fn term_nm(ordering: Ordering, j: usize) -> (usize, usize, bool) {
    match ordering {
        Ordering::Standard => noll_nm(j),
        Ordering::Fringe => fringe_nm(j),
    }
}

/// Term `j` (from 1) of `ordering` at polar point (ρ, θ) of the unit disk.
#[must_use]
pub fn zernike(ordering: Ordering, j: usize, rho: f64, theta: f64) -> f64 {
    let (n, m, sine) = term_nm(ordering, j);
    let norm = match ordering {
        Ordering::Standard if m == 0 => ((n + 1) as f64).sqrt(),
        Ordering::Standard => (2.0 * (n + 1) as f64).sqrt(),
        Ordering::Fringe => 1.0,
    };
    let ang = if m == 0 {
        1.0
    } else if sine {
        (m as f64 * theta).sin()
    } else {
        (m as f64 * theta).cos()
    };
    norm * radial(n, m, rho) * ang
}

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
    let max = match ordering {
        Ordering::Standard => STANDARD_TERMS,
        Ordering::Fringe => FRINGE_TERMS,
    };
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
        let terms: Vec<(usize, bool, f64, Vec<f64>)> = (1..=k)
            .map(|j| {
                let (n, m, sine) = term_nm(ordering, j);
                let norm = match ordering {
                    Ordering::Standard if m == 0 => ((n + 1) as f64).sqrt(),
                    Ordering::Standard => (2.0 * (n + 1) as f64).sqrt(),
                    Ordering::Fringe => 1.0,
                };
                // R_n^m(ρ) = Σ_s (−1)^s c_s ρ^(n − 2s), s = 0 ..= (n − m) / 2: the power of ρ²
                // after taking out ρ^m is (n − m) / 2 − s, highest first.
                let coef = (0..=(n - m) / 2)
                    .map(|s| {
                        let c =
                            fact(n - s) / (fact(s) * fact((n + m) / 2 - s) * fact((n - m) / 2 - s));
                        if s % 2 == 0 {
                            c
                        } else {
                            -c
                        }
                    })
                    .collect();
                (m, sine, norm, coef)
            })
            .collect();
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
