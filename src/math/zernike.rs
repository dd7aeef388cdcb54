//! Zernike polynomials on the unit disk in OpticStudio's two orderings: their indices, radial
//! polynomials and values. The wavefront fits ([`crate::wave::zernike`]) and the Zernike sag
//! surfaces ([`crate::lens::Shape::Zernike`]) both use them.
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
//! use tolray::math::zernike::{zernike, Ordering};
//! // Standard Z4 (defocus) at the rim and centre.
//! assert!((zernike(Ordering::Standard, 4, 1.0, 0.0) - 3f64.sqrt()).abs() < 1e-15);
//! assert!((zernike(Ordering::Standard, 4, 0.0, 0.0) + 3f64.sqrt()).abs() < 1e-15);
//! // Fringe Z9 (primary spherical) is 1 at the rim.
//! assert!((zernike(Ordering::Fringe, 9, 1.0, 0.3) - 1.0).abs() < 1e-14);
//! ```

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

impl Ordering {
    /// The most terms of this ordering tolray fits or puts on a sag surface:
    /// [`FRINGE_TERMS`] or [`STANDARD_TERMS`] (OpticStudio's `FZERNSAG` and `SZERNSAG` likewise).
    ///
    /// ```
    /// use tolray::math::zernike::Ordering;
    /// assert_eq!(Ordering::Fringe.max_terms(), 37);
    /// assert_eq!(Ordering::Standard.max_terms(), 231);
    /// ```
    #[must_use]
    pub const fn max_terms(self) -> usize {
        match self {
            Ordering::Standard => STANDARD_TERMS,
            Ordering::Fringe => FRINGE_TERMS,
        }
    }
}

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

/// Term `j` (from 1) of `ordering` in the Cartesian form the fits and sag surfaces evaluate
/// without trigonometry: `(m, sine, norm, coef)` such that the term at `(x, y)` is
/// `norm · P(x² + y²) · Re or Im (x + iy)^m` (the imaginary part for a sine term), where
/// `P(u) = Σ coef[i] u^(len − 1 − i)` (highest power first; the coefficients are integers,
/// exact in f64): `R_n^m(ρ) / ρ^m` is a polynomial in `ρ²`.
///
/// ```
/// use tolray::math::zernike::{term_poly, Ordering};
/// // Fringe Z9 = 6ρ⁴ − 6ρ² + 1.
/// assert_eq!(term_poly(Ordering::Fringe, 9), (0, false, 1.0, vec![6.0, -6.0, 1.0]));
/// // Standard Z6 = √6 ρ² cos 2θ = √6 Re (x + iy)².
/// let (m, sine, norm, coef) = term_poly(Ordering::Standard, 6);
/// assert_eq!((m, sine, coef), (2, false, vec![1.0]));
/// assert!((norm - 6f64.sqrt()).abs() < 1e-15);
/// ```
#[must_use]
pub fn term_poly(ordering: Ordering, j: usize) -> (usize, bool, f64, Vec<f64>) {
    let (n, m, sine) = term_nm(ordering, j);
    let norm = match ordering {
        Ordering::Standard if m == 0 => ((n + 1) as f64).sqrt(),
        Ordering::Standard => (2.0 * (n + 1) as f64).sqrt(),
        Ordering::Fringe => 1.0,
    };
    // R_n^m(ρ) = Σ_s (−1)^s c_s ρ^(n − 2s), s = 0 ..= (n − m) / 2: the power of ρ² after
    // taking out ρ^m is (n − m) / 2 − s, highest first.
    let coef = (0..=(n - m) / 2)
        .map(|s| {
            let c = fact(n - s) / (fact(s) * fact((n + m) / 2 - s) * fact((n - m) / 2 - s));
            if s % 2 == 0 {
                c
            } else {
                -c
            }
        })
        .collect();
    (m, sine, norm, coef)
}
