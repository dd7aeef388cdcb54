//! Zernike sag surfaces ([`crate::lens::Shape::Zernike`]: OpticStudio's Zernike Fringe Sag,
//! `FZERNSAG`, and Zernike Standard Sag, `SZERNSAG`): the even asphere plus a sum of Zernike
//! polynomials over a normalization circle,
//!
//! `z(x, y) = c r² / (1 + √(1 − (1 + k) c² r²)) + Σ α_i r^(2i) + Σ_j A_j Z_j(ρ, θ)`,
//!
//! with `α_1..α_8` in [`crate::lens::Surface::asph`], the coefficients `A_j` (mm) in
//! [`crate::lens::Surface::zernike`], and `(ρ, θ)` the polar coordinates of
//! `((x − dx) / R, (y − dy) / R)`: `R` the normalization radius, `(dx, dy)` the Zernike decenter
//! (the polynomials' centre on the surface). The terms follow [`crate::math::zernike`]
//! (Standard = Noll, normalised; Fringe, unnormalised, 37 terms). When the surface does not
//! extrapolate, the Zernike sum is 0 beyond `ρ = 1` (OpticStudio's `Extrapolate` = 0).
//!
//! [`ZernikeSag`] evaluates the sum and its gradient in any number type without trigonometry:
//! terms sharing an azimuthal form are merged at compile time into one polynomial in `ρ²`
//! multiplying `Re` or `Im (X + iY)^m`, so the kernel's Newton loop runs at most 41 short
//! Horner sums, and dual-number coefficients carry their derivatives into the sag.
//!
//! ```
//! use tolray::lens::zernike::ZernikeSag;
//! use tolray::math::zernike::Ordering;
//! // 0.01 mm of Fringe Z4 (2ρ² − 1) over a 10 mm circle: z = 0.01 (2 r² / 100 − 1).
//! let z = ZernikeSag::<f64>::new(Ordering::Fringe, 10.0, [0.0; 2], true, &[0.0, 0.0, 0.0, 0.01]);
//! let (v, gx, gy) = z.eval(3.0, 4.0);
//! assert!((v - 0.01 * (2.0 * 25.0 / 100.0 - 1.0)).abs() < 1e-17);
//! assert!((gx - 0.01 * 4.0 * 3.0 / 100.0).abs() < 1e-17 && (gy - 0.0016).abs() < 1e-17);
//! ```

use crate::math::zernike::{term_poly, Ordering};
use crate::real::Real;

/// Highest azimuthal order of any term (radial order 20, Standard term 231).
const MAX_M: usize = 20;

/// A compiled Zernike sum: the terms merged by azimuthal form, in number type `S`.
#[derive(Clone, Debug)]
pub struct ZernikeSag<S> {
    inv_norm: f64,
    decenter: [f64; 2],
    extrapolate: bool,
    max_m: usize,
    /// (m, sine, coefficients of the polynomial in ρ², lowest power first, scaled by the
    /// terms' coefficients and normalisations).
    groups: Vec<(usize, bool, Vec<S>)>,
    /// The coefficients as given (Z1 first), for checks written from the definitions.
    terms: Vec<S>,
}

impl<S: Real> ZernikeSag<S> {
    /// Merges the coefficients `terms` (mm; `terms[0]` is Z1) of `ordering` over a circle of
    /// `norm_radius_mm` centred at `decenter_mm`. A coefficient that is zero and constant is
    /// left out; one being differentiated counts even at zero. Terms beyond
    /// [`Ordering::max_terms`] are not read ([`crate::Lens::validate`] refuses a surface that
    /// has them).
    pub fn new(
        ordering: Ordering,
        norm_radius_mm: f64,
        decenter_mm: [f64; 2],
        extrapolate: bool,
        terms: &[S],
    ) -> Self {
        let mut groups: Vec<(usize, bool, Vec<S>)> = Vec::new();
        for (j, &a) in terms.iter().take(ordering.max_terms()).enumerate() {
            if a.value() == 0.0 && a.is_constant() {
                continue;
            }
            let (m, sine, norm, coef) = term_poly(ordering, j + 1);
            let g = match groups.iter().position(|g| g.0 == m && g.1 == sine) {
                Some(g) => g,
                None => {
                    groups.push((m, sine, Vec::new()));
                    groups.len() - 1
                }
            };
            let poly = &mut groups[g].2;
            if poly.len() < coef.len() {
                poly.resize(coef.len(), S::cst(0.0));
            }
            // coef is highest power first: coef[i] multiplies (ρ²)^(len − 1 − i).
            for (p, c) in coef.iter().rev().enumerate() {
                poly[p] += a * S::cst(norm * c);
            }
        }
        groups.sort_by_key(|g| (g.0, g.1));
        ZernikeSag {
            inv_norm: 1.0 / norm_radius_mm,
            decenter: decenter_mm,
            extrapolate,
            max_m: groups.iter().map(|g| g.0).max().unwrap_or(0),
            groups,
            terms: terms.iter().take(ordering.max_terms()).copied().collect(),
        }
    }

    /// The coefficients A_1, A_2, ... (mm) it was built from.
    pub fn terms(&self) -> &[S] {
        &self.terms
    }

    /// The sum `Σ A_j Z_j` (mm) and its gradient (`∂/∂x`, `∂/∂y`) at surface point `(x, y)` (mm).
    #[inline(always)]
    pub fn eval(&self, x: S, y: S) -> (S, S, S) {
        let zero = S::cst(0.0);
        let s = S::cst(self.inv_norm);
        let (px, py) = (
            (x - S::cst(self.decenter[0])) * s,
            (y - S::cst(self.decenter[1])) * s,
        );
        let u = px * px + py * py;
        // (X + iY)^m for m = 0 ..= max_m.
        let mut pw = [(zero, zero); MAX_M + 1];
        pw[0] = (S::cst(1.0), zero);
        for m in 1..=self.max_m {
            let (a, b) = pw[m - 1];
            pw[m] = (a * px - b * py, a * py + b * px);
        }
        let (mut z, mut gx, mut gy) = (zero, zero, zero);
        for (m, sine, poly) in &self.groups {
            // P(u) and P'(u) by Horner.
            let (mut p, mut dp) = (zero, zero);
            for &c in poly.iter().rev() {
                dp = dp * u + p;
                p = p * u + c;
            }
            let (re, im) = pw[*m];
            let t = if *sine { im } else { re };
            // ∂(X + iY)^m / ∂X = m (X + iY)^(m−1), ∂/∂Y = i m (X + iY)^(m−1).
            let (tx, ty) = if *m == 0 {
                (zero, zero)
            } else {
                let (a, b) = pw[*m - 1];
                let mf = S::cst(*m as f64);
                if *sine {
                    (mf * b, mf * a)
                } else {
                    (mf * a, -(mf * b))
                }
            };
            let two_dp_t = S::cst(2.0) * dp * t;
            z += p * t;
            gx += two_dp_t * px + p * tx;
            gy += two_dp_t * py + p * ty;
        }
        let inside = self.extrapolate || !S::cst(1.0).lt(u);
        (
            S::pick(inside, z, zero),
            S::pick(inside, gx * s, zero),
            S::pick(inside, gy * s, zero),
        )
    }

    /// The same sum in another number type (derivatives dropped).
    pub fn convert<T: Real>(&self) -> ZernikeSag<T> {
        ZernikeSag {
            inv_norm: self.inv_norm,
            decenter: self.decenter,
            extrapolate: self.extrapolate,
            max_m: self.max_m,
            groups: self
                .groups
                .iter()
                .map(|(m, s, p)| (*m, *s, p.iter().map(|c| T::cst(c.value())).collect()))
                .collect(),
            terms: self.terms.iter().map(|c| T::cst(c.value())).collect(),
        }
    }
}

/// What one unit (1 mm) of each of the first `n` terms of a Zernike sag `shape` adds at the
/// surface's vertex, over its decentred circle: `[sag, y² coefficient]`, the sag in mm per mm
/// and the coefficient (half the second derivative along y at `(0, 0)`) in 1/mm per mm; empty
/// for other shapes. The paraxial model (in the y-z plane, as OpticStudio traces paraxial rays)
/// takes the vertex at the sag and its curvature gains twice `Σ w_j A_j`, so that it is the
/// limit of the real rays near the axis; the slope at the vertex (tilt terms, a decenter) has
/// no place in a centred paraxial model and is left out.
///
/// ```
/// use tolray::lens::{zernike::vertex_weights, Shape};
/// use tolray::math::zernike::Ordering;
/// // Fringe Z4 = 2ρ² − 1: −1 at the vertex and 2 / R² on y²; Z5 = ρ² cos 2θ = (x² − y²) / R²:
/// // −1 / R² on y².
/// let shape = Shape::Zernike {
///     ordering: Ordering::Fringe,
///     norm_radius_mm: 10.0,
///     decenter_mm: [0.0; 2],
///     extrapolate: true,
/// };
/// let w = vertex_weights(shape, 5);
/// assert_eq!(w[3][0], -1.0);
/// assert!((w[3][1] - 0.02).abs() < 1e-17 && (w[4][1] + 0.01).abs() < 1e-17);
/// ```
pub fn vertex_weights(shape: crate::lens::Shape, n: usize) -> Vec<[f64; 2]> {
    let crate::lens::Shape::Zernike {
        ordering,
        norm_radius_mm: r,
        decenter_mm: [dx, dy],
        extrapolate,
    } = shape
    else {
        return Vec::new();
    };
    // The vertex in the circle's coordinates, p = (X, Y) = −decenter / R, u = X² + Y².
    let (x, y) = (-dx / r, -dy / r);
    let u = x * x + y * y;
    if !extrapolate && u > 1.0 {
        return vec![[0.0; 2]; n.min(ordering.max_terms())];
    }
    // (X + iY)^k for k = 0 ..= MAX_M, as (re, im).
    let mut pw = vec![(1.0, 0.0)];
    for k in 1..=MAX_M {
        let (a, b): (f64, f64) = pw[k - 1];
        pw.push((a * x - b * y, a * y + b * x));
    }
    (1..=n.min(ordering.max_terms()))
        .map(|j| {
            // A term is norm · P(u) · T(X, Y) with T = Re or Im (X + iY)^m. Along y (Y = (y −
            // dy) / R): ∂²/∂Y² (P T) = 2 P′ T + 4 Y² P″ T + 4 Y P′ T_Y + P T_YY, with T_Y and
            // T_YY the parts of i m (X + iY)^(m−1) and −m (m − 1) (X + iY)^(m−2).
            let (m, sine, norm, coef) = term_poly(ordering, j);
            let (mut p, mut dp, mut ddp) = (0.0, 0.0, 0.0);
            for &c in &coef {
                ddp = ddp * u + 2.0 * dp;
                dp = dp * u + p;
                p = p * u + c;
            }
            let part = |k: usize, scale: f64, times_i: bool| {
                let (re, im) = pw[k];
                // The part of scale · i^times_i · (re + i im) that T takes.
                let (re, im) = if times_i { (-im, re) } else { (re, im) };
                scale * if sine { im } else { re }
            };
            let mf = m as f64;
            let t = part(m, 1.0, false);
            let t_y = if m >= 1 { part(m - 1, mf, true) } else { 0.0 };
            let t_yy = if m >= 2 {
                part(m - 2, -mf * (mf - 1.0), false)
            } else {
                0.0
            };
            let d2 = 2.0 * dp * t + 4.0 * y * y * ddp * t + 4.0 * y * dp * t_y + p * t_yy;
            [norm * p * t, 0.5 * norm * d2 / (r * r)]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::zernike::zernike;

    /// Every term of both sets, alone, merged and evaluated without trigonometry, equals its
    /// polar definition; the gradient equals a central difference; a decentred, non-extrapolated
    /// sum vanishes outside its circle.
    #[test]
    fn every_term_is_its_polar_definition() {
        let pts = [
            (0.3, -0.4),
            (-0.71, 0.2),
            (0.05, 0.93),
            (-0.5, -0.5),
            (0.0, 0.0),
        ];
        for ordering in [Ordering::Fringe, Ordering::Standard] {
            for j in 1..=ordering.max_terms() {
                let mut terms = vec![0.0; j];
                terms[j - 1] = 1.0;
                let r = 2.0;
                let sag = ZernikeSag::<f64>::new(ordering, r, [0.0; 2], true, &terms);
                for &(x, y) in &pts {
                    let want = zernike(ordering, j, f64::hypot(x, y), f64::atan2(y, x));
                    let (z, gx, gy) = sag.eval(r * x, r * y);
                    assert!(
                        (z - want).abs() < 1e-9 * want.abs().max(1.0),
                        "{ordering:?} Z{j}"
                    );
                    // Fourth-order central differences (degree-20 terms: a larger step than
                    // rounding would allow a second-order one).
                    let d = |f: &dyn Fn(f64) -> f64| {
                        let h = 1e-3;
                        (f(-2.0 * h) - 8.0 * f(-h) + 8.0 * f(h) - f(2.0 * h)) / (12.0 * h)
                    };
                    let fx = d(&|h| sag.eval(r * x + h, r * y).0);
                    let fy = d(&|h| sag.eval(r * x, r * y + h).0);
                    assert!(
                        (gx - fx).abs() < 1e-5 * fx.abs().max(1.0),
                        "{ordering:?} Z{j} x"
                    );
                    assert!(
                        (gy - fy).abs() < 1e-5 * fy.abs().max(1.0),
                        "{ordering:?} Z{j} y"
                    );
                }
            }
        }
        let sag = ZernikeSag::<f64>::new(Ordering::Standard, 1.0, [0.5, 0.0], false, &[1.0, 0.3]);
        assert_eq!(sag.eval(1.6, 0.0), (0.0, 0.0, 0.0));
        assert!(sag.eval(1.4, 0.0).0 > 1.0);
    }

    /// The vertex weights, computed in closed form, equal the sag of each term alone at the
    /// vertex and half its second derivative along y there (a dual-number gradient of the
    /// compiled sum, differentiated by central differences), decentred and centred, extrapolated
    /// or not.
    #[test]
    fn vertex_weights_are_the_vertex_sag_and_curvature() {
        for ordering in [Ordering::Fringe, Ordering::Standard] {
            for (decenter, extrapolate) in [
                ([0.0, 0.0], true),
                ([0.7, -1.3], true),
                ([0.7, -1.3], false),
                ([3.0, 1.0], false),
            ] {
                let r = 2.5;
                let shape = crate::lens::Shape::Zernike {
                    ordering,
                    norm_radius_mm: r,
                    decenter_mm: decenter,
                    extrapolate,
                };
                let n = ordering.max_terms();
                let w = vertex_weights(shape, n + 5);
                assert_eq!(w.len(), n);
                for j in 1..=n {
                    let mut terms = vec![0.0; j];
                    terms[j - 1] = 1.0;
                    let sag = ZernikeSag::<f64>::new(ordering, r, decenter, extrapolate, &terms);
                    let h = 1e-4;
                    let gy = |y: f64| sag.eval(0.0, y).2;
                    let y2 = 0.25 * (gy(h) - gy(-h)) / h;
                    let z0 = sag.eval(0.0, 0.0).0;
                    let scale = z0.abs().max(1.0);
                    assert!(
                        (w[j - 1][0] - z0).abs() < 1e-9 * scale,
                        "{ordering:?} Z{j} sag"
                    );
                    assert!(
                        (w[j - 1][1] - y2).abs() < 1e-5 * y2.abs().max(1.0),
                        "{ordering:?} Z{j} {decenter:?}: {} vs {y2}",
                        w[j - 1][1]
                    );
                }
            }
        }
    }
}
