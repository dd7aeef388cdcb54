//! Forbes' Q^con polynomials on a conic base ([`crate::lens::Shape::Qcon`], OpticStudio's
//! Q-type asphere of type 1).
//!
//! The sag is the base conic plus a polynomial departure along the axis:
//!
//! ```text
//! z(ρ) = c ρ² / (1 + sqrt(1 - (1+k) c² ρ²)) + x² Σ_m a_m Q_m(x),   x = (ρ / ρ_n)²
//! Q_m(x) = P_m^(0,4)(2x - 1)   (Jacobi polynomials)
//! ```
//!
//! (G. W. Forbes, "Shape specification for axially symmetric optical surfaces", Opt. Express
//! 15, 5218 (2007), eq. (3.1); Q_0 = 1, Q_1 = -(5 - 6x), Q_2 = 15 - 14x (3 - 2x).) The departure
//! starts at ρ⁴, so it leaves the paraxial curvature to `c`; unlike Q^bfs it is an ordinary
//! even polynomial in ρ, of degree 2m + 4, in orthogonal form. The polynomials are evaluated
//! with the Jacobi three-term relation in `x`,
//!
//! ```text
//! P_n = (α_n + β_n x) P_{n-1} - γ_n P_{n-2},   P_0 = 1, P_1 = 6x - 5,
//! β_n = 2 (2n+3)(n+2) / (n (n+4)),   α_n = -β_n / 2 - 4 (2n+3) / (n (n+1)(n+4)),
//! γ_n = (n-1)(n+2)(n+3) / (n (n+1)(n+4)),
//! ```
//!
//! stable on and beyond [0, 1]. Checked in the tests: Forbes' closed forms, orthogonality with
//! weight x⁴ on [0, 1] (norm 1 / (2m + 5)), and derivatives against central differences; traced
//! ray by ray against optiland with the same surface written as an even asphere by SciPy's
//! Jacobi polynomials (`tests/zemax/`).

use super::N_ASPH;
use crate::real::Real;

/// (α_n, β_n, γ_n) of the three-term relation in `x`, n = 2..7 (index n - 2).
#[inline(always)]
fn coefficients(n: usize) -> (f64, f64, f64) {
    let f = n as f64;
    let beta = 2.0 * (2.0 * f + 3.0) * (f + 2.0) / (f * (f + 4.0));
    let alpha = -beta / 2.0 - 4.0 * (2.0 * f + 3.0) / (f * (f + 1.0) * (f + 4.0));
    let gamma = (f - 1.0) * (f + 2.0) * (f + 3.0) / (f * (f + 1.0) * (f + 4.0));
    (alpha, beta, gamma)
}

/// `Σ_{m<n} a_m Q_m(x)` and its derivative in `x`, in the number type of the kernel, by the
/// forward three-term relation (eight terms at most; no table of polynomials is kept).
#[inline(always)]
pub(crate) fn sum<S: Real>(a: &[S; N_ASPH], n: usize, x: S) -> (S, S) {
    let n = n.min(N_ASPH);
    let zero = S::cst(0.0);
    if n == 0 {
        return (zero, zero);
    }
    // (P_{m-2}, P_{m-1}) and their derivatives.
    let (mut p2, mut p1) = (zero, S::cst(1.0));
    let (mut d2, mut d1) = (zero, zero);
    let mut s = a[0];
    let mut ds = zero;
    for (m, &am) in a.iter().enumerate().take(n).skip(1) {
        let (p, d) = if m == 1 {
            (S::cst(6.0) * x - S::cst(5.0), S::cst(6.0))
        } else {
            let (al, be, ga) = coefficients(m);
            let t = S::cst(al) + S::cst(be) * x;
            (
                t * p1 - S::cst(ga) * p2,
                S::cst(be) * p1 + t * d1 - S::cst(ga) * d2,
            )
        };
        s += am * p;
        ds += am * d;
        p2 = p1;
        p1 = p;
        d2 = d1;
        d1 = d;
    }
    (s, ds)
}

/// The sag of a Q^con surface and its derivative with respect to `u = ρ²`, in the number type
/// of the kernel; `ok` is false beyond the base conic's rim. `inv_norm2` = 1 / ρ_n².
#[inline(always)]
pub(crate) fn sag_u<S: Real>(
    c: S,
    k1: S,
    a: &[S; N_ASPH],
    n: usize,
    inv_norm2: S,
    u: S,
) -> (S, S, bool) {
    let (z0, dz0, _, ok) = crate::lens::qbfs::base_conic(c, k1, u);
    let x = u * inv_norm2;
    let (s, ds) = sum(a, n, x);
    let xx = x * x;
    (
        z0 + xx * s,
        dz0 + (S::cst(2.0) * x * s + xx * ds) * inv_norm2,
        ok,
    )
}

/// The polynomials `Q_0(x), ..., Q_7(x)` ([`polynomials_and_slopes`]).
///
/// ```
/// let q = tolray::lens::qcon::polynomials(0.5);
/// assert_eq!(q[0], 1.0);
/// assert!((q[1] + 2.0).abs() < 1e-15); // Q_1 = -(5 - 6x)
/// assert!((q[2] - 1.0).abs() < 1e-14); // Q_2 = 15 - 14x (3 - 2x)
/// ```
pub fn polynomials(x: f64) -> [f64; N_ASPH] {
    polynomials_and_slopes(x).0
}

/// `Q_m(x)` and `dQ_m/dx`, m = 0..7, one by one from the three-term relation (the reference
/// for the kernel's running sum).
///
/// ```
/// let (_, dq) = tolray::lens::qcon::polynomials_and_slopes(0.3);
/// assert_eq!(dq[1], 6.0);
/// assert!((dq[2] - (-42.0 + 56.0 * 0.3)).abs() < 1e-13);
/// ```
pub fn polynomials_and_slopes(x: f64) -> ([f64; N_ASPH], [f64; N_ASPH]) {
    let (mut p, mut dp) = ([0.0; N_ASPH], [0.0; N_ASPH]);
    p[0] = 1.0;
    p[1] = 6.0 * x - 5.0;
    dp[1] = 6.0;
    for m in 2..N_ASPH {
        let (al, be, ga) = coefficients(m);
        p[m] = (al + be * x) * p[m - 1] - ga * p[m - 2];
        dp[m] = be * p[m - 1] + (al + be * x) * dp[m - 1] - ga * dp[m - 2];
    }
    (p, dp)
}

/// Sag (mm) of a Q^con surface at `ρ²` = `u` mm² and its derivative with respect to `u`, or
/// `None` beyond the base conic's rim, term by term with [`polynomials_and_slopes`].
pub(crate) fn sag_and_slope(
    c: f64,
    k: f64,
    a: &[f64],
    norm_radius_mm: f64,
    u: f64,
) -> Option<(f64, f64)> {
    let den = 1.0 - (1.0 + k) * c * c * u;
    if !(den > 0.0) {
        return None;
    }
    let r2 = norm_radius_mm * norm_radius_mm;
    let x = u / r2;
    let (q, dq) = polynomials_and_slopes(x);
    let s: f64 = a.iter().zip(q).map(|(a, q)| a * q).sum();
    let ds: f64 = a.iter().zip(dq).map(|(a, q)| a * q).sum();
    Some((
        c * u / (1.0 + den.sqrt()) + x * x * s,
        c / (2.0 * den.sqrt()) + (2.0 * x * s + x * x * ds) / r2,
    ))
}

/// Sag (mm) of a Q^con surface at `ρ²` = `u` mm², or `None` beyond the base conic's rim.
pub(crate) fn sag(c: f64, k: f64, a: &[f64; N_ASPH], norm_radius_mm: f64, u: f64) -> Option<f64> {
    sag_and_slope(c, k, a, norm_radius_mm, u).map(|(z, _)| z)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Forbes (2007) eq. (3.4): Q_0 = 1, Q_1 = -(5 - 6x), Q_2 = 15 - 14x (3 - 2x),
    /// Q_3 = -{35 - 12x [14 - x (21 - 10x)]}.
    #[test]
    fn the_first_polynomials_are_forbes_closed_forms() {
        for i in 0..=20 {
            let x = -0.25 + 1.5 * i as f64 / 20.0;
            let q = polynomials(x);
            assert_eq!(q[0], 1.0);
            assert!((q[1] + (5.0 - 6.0 * x)).abs() < 1e-14);
            assert!((q[2] - (15.0 - 14.0 * x * (3.0 - 2.0 * x))).abs() < 1e-12);
            let q3 = -(35.0 - 12.0 * x * (14.0 - x * (21.0 - 10.0 * x)));
            assert!((q[3] - q3).abs() < 1e-11, "{x}: {} vs {q3}", q[3]);
        }
    }

    /// Orthogonality: ∫_0^1 Q_m Q_n x⁴ dx = δ_mn / (2m + 5) (the Jacobi P^(0,4) norm), by
    /// 32-point Gauss-Legendre quadrature (exact for these degrees).
    #[test]
    fn the_polynomials_are_orthogonal_with_weight_x4() {
        // Nodes on [-1, 1] moved to [0, 1].
        let nodes: Vec<(f64, f64)> = crate::lens::qbfs::gauss_legendre(32)
            .into_iter()
            .map(|(t, w)| ((t + 1.0) / 2.0, w / 2.0))
            .collect();
        for i in 0..N_ASPH {
            for j in 0..N_ASPH {
                let s: f64 = nodes
                    .iter()
                    .map(|&(x, w)| {
                        let q = polynomials(x);
                        w * x.powi(4) * q[i] * q[j]
                    })
                    .sum();
                let want = if i == j {
                    1.0 / (2 * i + 5) as f64
                } else {
                    0.0
                };
                assert!((s - want).abs() < 1e-12, "<Q{i} Q{j}> = {s}");
            }
        }
    }

    /// The running sum equals the sum of the polynomials, and its derivative the polynomials'
    /// slopes and central differences, for every number of terms.
    #[test]
    fn the_summation_matches_the_polynomials() {
        crate::lens::qbfs::check_summation(sum::<f64>, polynomials_and_slopes);
    }

    /// The kernel's sag and dz/du equal the definition's and its central difference.
    #[test]
    fn the_kernel_sag_matches_the_definition() {
        let a = [2e-3, -8e-4, 3e-4, -1e-4, 5e-5, -2e-5, 1e-5, -4e-6];
        crate::lens::qbfs::check_kernel_sag(
            sag_u::<f64>,
            sag_and_slope,
            (1.0 / 18.0, -0.7, 6.5),
            &a,
            8,
            0.18,
        );
        // The departure starts at ρ⁴: no ρ² term, so the paraxial curvature is c.
        let (z, dz, _) = sag_u(0.0, 1.0, &a, 8, 1.0 / (6.5 * 6.5), 1e-8);
        assert!(z.abs() < 1e-17 && dz.abs() < 1e-9);
    }
}
