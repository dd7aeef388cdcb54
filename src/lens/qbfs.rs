//! Forbes' slope-orthogonal Q polynomials `Q_m^bfs` on a conic base ([`crate::lens::Shape::Qbfs`],
//! OpticStudio's Q-type asphere of type 0).
//!
//! The sag is the base conic plus a departure measured along the base conic's normal and
//! projected onto the axis:
//!
//! ```text
//! z(ρ) = c ρ² / (1 + sqrt(1 - (1+k) c² ρ²)) + φ(ρ) · x (1 - x) · Σ_m a_m Q_m(x),   x = (ρ / ρ_n)²
//! φ(ρ) = sqrt((1 - k c² ρ²) / (1 - (1+k) c² ρ²))
//! ```
//!
//! (G. W. Forbes, "Shape specification for axially symmetric optical surfaces", Opt. Express
//! 15, 5218 (2007), with a sphere; the conic base and φ, 1 / the axial component of the conic's
//! normal, as in his later papers and optiland's `ForbesQNormalSlopeGeometry`.) The polynomials
//! are evaluated as Forbes' "Robust, efficient computational methods for axially symmetric
//! optical aspheres", Opt. Express 18, 19700 (2010) prescribes: the coefficients are moved to the
//! basis `P_0 = 2`, `P_1 = 6 - 8x`, `P_m = (2 - 4x) P_{m-1} - P_{m-2}` by the three-term relation
//! `Q_m = (P_m - g_{m-1} Q_{m-1} - h_{m-2} Q_{m-2}) / f_m`, then summed by Clenshaw's recurrence.
//! Checked in the tests: the first polynomials against Forbes' closed forms, orthonormality in
//! his slope metric, and the derivative against central differences.
//!
//! Which formula OpticStudio uses for type 0 is not publicly specified to the letter; this one is
//! the only candidate under which Thorlabs' ASL5040-UV file (a conic base with `c ρ > 1` at the
//! rim, where 1 / sqrt(1 - c² ρ²) does not exist) focuses a collimated beam at the file's own
//! image distance and primary wavelength (0.28 µm RMS; `tests/zemax/`).

use super::N_ASPH;
use crate::real::Real;

/// `f_m` of the three-term relation, m = 0..7 (f_0 = 2, f_1 = √19 / 2, then
/// f_m = sqrt(m (m+1) + 3 - g_{m-1}² - h_{m-2}²)); recomputed from the recurrence in the tests.
const F: [f64; N_ASPH] = [
    2.0,
    2.179449471770337,
    2.9019050004400464,
    3.567211796347394,
    4.2799849438803905,
    4.971637704738899,
    5.681652322760158,
    6.380705142135172,
];
/// `g_m`, m = 0..6 (g_0 = -1/2, g_{m-1} = -(1 + g_{m-2} h_{m-2}) / f_{m-1}).
const G: [f64; N_ASPH - 1] = [
    -0.5,
    -0.5735393346764044,
    -0.61665481259351,
    -0.6377529930601431,
    -0.6513619300049629,
    -0.6603092839386494,
    -0.6669046163343583,
];
/// `h_m`, m = 0..5 (h_{m-2} = -m (m-1) / (2 f_{m-2})).
const H: [f64; N_ASPH - 2] = [
    -0.5,
    -1.3764944032233704,
    -2.0676073128135335,
    -2.803309859605024,
    -3.5046852259252232,
    -4.223960241508162,
];

/// The coefficients `b` with `Σ a_m Q_m = Σ b_m P_m` for the first `n` terms:
/// `b_m = (a_m - g_m b_{m+1} - h_m b_{m+2}) / f_m` from the top down.
#[inline(always)]
fn p_basis<S: Real>(a: &[S; N_ASPH], n: usize) -> [S; N_ASPH] {
    let mut b = [S::cst(0.0); N_ASPH];
    for m in (0..n.min(N_ASPH)).rev() {
        let mut v = a[m];
        if m + 1 < n {
            v -= S::cst(G[m]) * b[m + 1];
        }
        if m + 2 < n {
            v -= S::cst(H[m]) * b[m + 2];
        }
        b[m] = v / S::cst(F[m]);
    }
    b
}

/// `Σ_{m<n} a_m Q_m(x)` and its derivative in `x`, by Clenshaw's recurrence on the `P` basis:
/// `α_k = b_k + (2 - 4x) α_{k+1} - α_{k+2}`, the sum `2 (α_0 + α_1)`.
#[inline(always)]
pub(crate) fn sum<S: Real>(a: &[S; N_ASPH], n: usize, x: S) -> (S, S) {
    let zero = S::cst(0.0);
    let b = p_basis(a, n);
    let t = S::cst(2.0) - S::cst(4.0) * x;
    let four = S::cst(4.0);
    // (α_{k+1}, α_{k+2}) and their derivatives.
    let (mut a1, mut a2, mut d1, mut d2) = (zero, zero, zero, zero);
    for k in (0..n.min(N_ASPH)).rev() {
        let a0 = b[k] + t * a1 - a2;
        let d0 = t * d1 - four * a1 - d2;
        a2 = a1;
        a1 = a0;
        d2 = d1;
        d1 = d0;
    }
    // Now a1 = α_0 and a2 = α_1 (0 for a single term).
    let two = S::cst(2.0);
    (two * (a1 + a2), two * (d1 + d2))
}

/// The base conic of a Q-type surface at `u = ρ²` (`k1` = 1 + k): its sag, dz/du,
/// `1 - (1+k) c² u` (1 beyond the rim) and whether `u` lies inside the rim.
#[inline(always)]
pub(crate) fn base_conic<S: Real>(c: S, k1: S, u: S) -> (S, S, S, bool) {
    let one = S::cst(1.0);
    let den = one - k1 * (c * c) * u;
    let ok = S::cst(0.0).lt(den);
    let den = S::pick(ok, den, one);
    let q = den.sqrt();
    (c * u / (one + q), c / (S::cst(2.0) * q), den, ok)
}

/// The sag of a Qbfs surface and its derivative with respect to `u = ρ²`, in the number type
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
    let one = S::cst(1.0);
    let cc = c * c;
    let (z0, dz0, den, ok) = base_conic(c, k1, u);
    // φ² = (1 - k c² u) / den = 1 + c² u / den; d(φ²)/du = c² / den².
    let phi = (one + cc * u / den).sqrt();
    let dphi = cc / (S::cst(2.0) * phi * den * den);
    let x = u * inv_norm2;
    let (s, ds) = sum(a, n, x);
    let w = x * (one - x);
    let d = w * s;
    let dd = ((one - S::cst(2.0) * x) * s + w * ds) * inv_norm2;
    (z0 + phi * d, dz0 + dphi * d + phi * dd, ok)
}

/// The polynomials `Q_0(x), ..., Q_7(x)` one by one from the three-term relation (not the
/// summation the kernel uses): for the sag in [`crate::lens::Surface::sag_xy`] and the paraxial
/// curvature.
///
/// ```
/// let q = tolray::lens::qbfs::polynomials(0.5);
/// assert!((q[0] - 1.0).abs() < 1e-15);
/// assert!((q[1] - 5.0 / 19f64.sqrt()).abs() < 1e-15); // (13 - 16 x) / √19
/// ```
pub fn polynomials(x: f64) -> [f64; N_ASPH] {
    polynomials_and_slopes(x).0
}

/// `Q_m(x)` and `dQ_m/dx`, m = 0..7, from the three-term relation and its derivative
/// (`P'_m = (2 - 4x) P'_{m-1} - 4 P_{m-1} - P'_{m-2}`).
///
/// ```
/// let (_, dq) = tolray::lens::qbfs::polynomials_and_slopes(0.3);
/// assert!((dq[1] + 16.0 / 19f64.sqrt()).abs() < 1e-14); // Q_1 = (13 - 16 x) / √19
/// ```
pub fn polynomials_and_slopes(x: f64) -> ([f64; N_ASPH], [f64; N_ASPH]) {
    let (mut p, mut dp) = ([0.0; N_ASPH], [0.0; N_ASPH]);
    p[0] = 2.0;
    p[1] = 6.0 - 8.0 * x;
    dp[1] = -8.0;
    for m in 2..N_ASPH {
        p[m] = (2.0 - 4.0 * x) * p[m - 1] - p[m - 2];
        dp[m] = (2.0 - 4.0 * x) * dp[m - 1] - 4.0 * p[m - 1] - dp[m - 2];
    }
    let (mut q, mut dq) = ([0.0; N_ASPH], [0.0; N_ASPH]);
    q[0] = p[0] / F[0];
    q[1] = (p[1] - G[0] * q[0]) / F[1];
    dq[1] = dp[1] / F[1];
    for m in 2..N_ASPH {
        q[m] = (p[m] - G[m - 1] * q[m - 1] - H[m - 2] * q[m - 2]) / F[m];
        dq[m] = (dp[m] - G[m - 1] * dq[m - 1] - H[m - 2] * dq[m - 2]) / F[m];
    }
    (q, dq)
}

/// Sag (mm) of a Qbfs surface at `ρ²` = `u` mm² and its derivative with respect to `u`, or
/// `None` beyond the base conic's rim, written from the definition term by term with
/// [`polynomials_and_slopes`] (the reference for the kernel's summation).
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
    let num = 1.0 - k * c * c * u;
    let base = c * u / (1.0 + den.sqrt());
    let dbase = c / (2.0 * den.sqrt());
    let phi = (num / den).sqrt();
    // dφ/du = (num' den - num den') / (2 φ den²), num' = -k c², den' = -(1+k) c².
    let dphi = (-k * c * c * den + (1.0 + k) * c * c * num) / (2.0 * phi * den * den);
    let r2 = norm_radius_mm * norm_radius_mm;
    let x = u / r2;
    let (q, dq) = polynomials_and_slopes(x);
    let s: f64 = a.iter().zip(q).map(|(a, q)| a * q).sum();
    let ds: f64 = a.iter().zip(dq).map(|(a, q)| a * q).sum();
    let w = x - x * x;
    let dw = 1.0 - 2.0 * x;
    Some((
        base + phi * w * s,
        dbase + dphi * w * s + phi * (dw * s + w * ds) / r2,
    ))
}

/// Sag (mm) of a Qbfs surface at `ρ²` = `u` mm², or `None` beyond the base conic's rim.
pub(crate) fn sag(c: f64, k: f64, a: &[f64; N_ASPH], norm_radius_mm: f64, u: f64) -> Option<f64> {
    sag_and_slope(c, k, a, norm_radius_mm, u).map(|(z, _)| z)
}

/// `n`-point Gauss-Legendre nodes and weights on [-1, 1], by Newton on the Legendre polynomial
/// (the Q polynomials' orthogonality tests; the wave module's pupil quadrature).
pub(crate) fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    let mut nodes = Vec::new();
    for i in 1..=n {
        let mut x = (std::f64::consts::PI * (i as f64 - 0.25) / (n as f64 + 0.5)).cos();
        let mut dp = 0.0;
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, x);
            for k in 2..=n {
                let kf = k as f64;
                let p2 = ((2.0 * kf - 1.0) * x * p1 - (kf - 1.0) * p0) / kf;
                p0 = p1;
                p1 = p2;
            }
            dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
            let step = p1 / dp;
            x -= step;
            if step.abs() < 1e-16 {
                break;
            }
        }
        nodes.push((x, 2.0 / ((1.0 - x * x) * dp * dp)));
    }
    nodes
}

/// A Q type's kernel sag (`sag_u`) against its term-by-term definition (`sag_and_slope`) and
/// that definition's central difference, at ρ = 0, step, .., 40 step (all inside the base
/// conic's rim), and both refusing ρ² = 1e4 mm² beyond it.
#[cfg(test)]
#[allow(clippy::type_complexity)]
pub(crate) fn check_kernel_sag(
    sag_u: fn(f64, f64, &[f64; N_ASPH], usize, f64, f64) -> (f64, f64, bool),
    sag_and_slope: fn(f64, f64, &[f64], f64, f64) -> Option<(f64, f64)>,
    (c, k, rn): (f64, f64, f64),
    a: &[f64; N_ASPH],
    n: usize,
    step: f64,
) {
    let sag = |u: f64| sag_and_slope(c, k, &a[..], rn, u).unwrap().0;
    for i in 0..=40 {
        let u = (i as f64 * step).powi(2);
        let (z, dz, ok) = sag_u(c, 1.0 + k, a, n, 1.0 / (rn * rn), u);
        assert!(ok);
        let (want, slope) = sag_and_slope(c, k, &a[..], rn, u).unwrap();
        assert!((z - want).abs() < 1e-13, "u {u}: {z} vs {want}");
        assert!(
            (dz - slope).abs() < 1e-13 * (1.0 + slope.abs()),
            "u {u}: {dz} vs {slope}"
        );
        let h = 1e-4 * (1.0 + u);
        let fd = (sag(u + h) - sag(u - h)) / (2.0 * h);
        assert!(
            (dz - fd).abs() < 1e-8 * (1.0 + fd.abs()),
            "u {u}: {dz} vs {fd}"
        );
    }
    assert!(sag_and_slope(c, k, &a[..], rn, 1e4).is_none());
    assert!(!sag_u(c, 1.0 + k, a, n, 1.0 / (rn * rn), 1e4).2);
}

/// A Q type's kernel summation `sum` (value and x-derivative of Σ_{m<n} a_m Q_m(x)) against the
/// polynomials one by one (`polys`: values and slopes) and a central difference, for every
/// number of terms and x from -0.2 to 1.2.
#[cfg(test)]
#[allow(clippy::type_complexity)]
pub(crate) fn check_summation(
    sum: fn(&[f64; N_ASPH], usize, f64) -> (f64, f64),
    polys: fn(f64) -> ([f64; N_ASPH], [f64; N_ASPH]),
) {
    let a = [0.3, -0.7, 0.11, 0.05, -0.02, 0.013, -0.004, 0.002];
    for n in 0..=N_ASPH {
        for i in 0..=10 {
            let x = -0.2 + 1.4 * i as f64 / 10.0;
            let (s, ds) = sum(&a, n, x);
            let (q, dq) = polys(x);
            let want: f64 = q.iter().zip(&a).take(n).map(|(q, a)| q * a).sum();
            let dwant: f64 = dq.iter().zip(&a).take(n).map(|(q, a)| q * a).sum();
            assert!((s - want).abs() < 1e-12, "n {n} x {x}: {s} vs {want}");
            assert!((ds - dwant).abs() < 1e-11, "n {n} x {x}: {ds} vs {dwant}");
            let h = 1e-6;
            let fd = (sum(&a, n, x + h).0 - sum(&a, n, x - h).0) / (2.0 * h);
            assert!(
                (ds - fd).abs() < 1e-6 * (1.0 + fd.abs()),
                "n {n} x {x}: {ds} vs {fd}"
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// f, g, h recomputed from Forbes' recurrence equal the tables.
    #[test]
    fn the_tables_follow_the_recurrence() {
        let mut f = [0.0; N_ASPH];
        let mut g = [0.0; N_ASPH];
        let mut h = [0.0; N_ASPH];
        f[0] = 2.0;
        g[0] = -0.5;
        f[1] = 19f64.sqrt() / 2.0;
        for m in 2..N_ASPH {
            let mf = m as f64;
            h[m - 2] = -mf * (mf - 1.0) / (2.0 * f[m - 2]);
            g[m - 1] = -(1.0 + g[m - 2] * h[m - 2]) / f[m - 1];
            f[m] = (mf * (mf + 1.0) + 3.0 - g[m - 1].powi(2) - h[m - 2].powi(2)).sqrt();
        }
        for m in 0..N_ASPH {
            assert!((f[m] - F[m]).abs() < 1e-15 * F[m], "f_{m}");
        }
        for m in 0..N_ASPH - 1 {
            assert!((g[m] - G[m]).abs() < 1e-15, "g_{m}");
        }
        for m in 0..N_ASPH - 2 {
            assert!((h[m] - H[m]).abs() < 1e-14, "h_{m}");
        }
    }

    /// Forbes (2007) gives Q_0 = 1, Q_1 = (13 - 16x) / √19, Q_2 = √2 (29 - 4x (25 - 19x)) / √95.
    #[test]
    fn the_first_polynomials_are_forbes_closed_forms() {
        for i in 0..=20 {
            let x = i as f64 / 20.0;
            let q = polynomials(x);
            assert!((q[0] - 1.0).abs() < 1e-15);
            assert!((q[1] - (13.0 - 16.0 * x) / 19f64.sqrt()).abs() < 1e-14);
            let q2 = 2f64.sqrt() * (29.0 - 4.0 * x * (25.0 - 19.0 * x)) / 95f64.sqrt();
            assert!((q[2] - q2).abs() < 1e-13, "{x}: {} vs {q2}", q[2]);
        }
    }

    /// The defining property: the slopes of u² (1 - u²) Q_m(u²) are orthonormal in Forbes'
    /// metric <f g> = (2/π) ∫_0^1 f g / sqrt(1 - u²) du (u = sin t; Gauss-Legendre in t).
    #[test]
    fn the_departure_slopes_are_orthonormal() {
        let nodes = gauss_legendre(64);
        let slope = |m: usize, u: f64| {
            // d/du [u² (1 - u²) Q_m(u²)] with dQ/dx from the kernel's summation.
            let mut a = [0.0; N_ASPH];
            a[m] = 1.0;
            let x = u * u;
            let (q, dq) = sum(&a, N_ASPH, x);
            (2.0 * u - 4.0 * u * u * u) * q + x * (1.0 - x) * dq * 2.0 * u
        };
        for i in 0..N_ASPH {
            for j in 0..N_ASPH {
                let mut s = 0.0;
                for &(t, w) in &nodes {
                    // t in [-1, 1] -> angle in [0, π/2].
                    let ang = (t + 1.0) * std::f64::consts::PI / 4.0;
                    s += w * std::f64::consts::PI / 4.0 * slope(i, ang.sin()) * slope(j, ang.sin());
                }
                s *= 2.0 / std::f64::consts::PI;
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((s - want).abs() < 1e-10, "<Q{i} Q{j}> = {s}");
            }
        }
    }

    /// Clenshaw's sum equals the sum of the polynomials, and its x-derivative their slopes and
    /// central differences, for every number of terms.
    #[test]
    fn the_summation_matches_the_polynomials() {
        check_summation(sum::<f64>, polynomials_and_slopes);
    }

    /// The kernel's sag and dz/du equal the definition's sag and its central difference.
    #[test]
    fn the_kernel_sag_matches_the_definition() {
        let a = [
            -0.8148, -0.3231, 0.10591, -0.05058, 0.00987, -0.0022, 0.0, 0.0,
        ];
        let (c, k, rn) = (0.0575607876278, -0.676091206404, 27.0);
        check_kernel_sag(sag_u::<f64>, sag_and_slope, (c, k, rn), &a, 6, 0.6);
    }
}
