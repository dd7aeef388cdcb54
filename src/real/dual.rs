//! Forward-mode dual numbers `Dual<T, N>`: a value and `N` directional derivatives.
//!
//! Fixed width and `Copy`, so the tracing kernel runs on them unchanged with no heap use. For P
//! parameters, ceil(P/N) passes each seed a different block of N parameters.

use super::Real;
use std::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};

/// A dual number: `re + Σ eps[k] ε_k` with ε_k ε_l = 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dual<T, const N: usize> {
    /// Value part.
    pub re: T,
    /// Derivative parts.
    pub eps: [T; N],
}

impl<T: Real, const N: usize> Dual<T, N> {
    /// A variable with value `re` seeded in direction `k` (derivative 1 there, 0 elsewhere).
    pub fn var(re: T, k: usize) -> Self {
        let mut eps = Self::ZERO.eps;
        eps[k] = T::cst(1.0);
        Dual { re, eps }
    }
    /// A constant.
    #[inline(always)]
    pub fn constant(re: T) -> Self {
        Dual {
            re,
            eps: Self::ZERO.eps,
        }
    }
    /// `f(re)` with derivative `df` by the chain rule.
    #[inline(always)]
    fn chain(self, f: T, df: T) -> Self {
        let mut eps = self.eps;
        for e in eps.iter_mut() {
            *e *= df;
        }
        Dual { re: f, eps }
    }
}

impl<T: Real, const N: usize> Default for Dual<T, N> {
    fn default() -> Self {
        Dual::constant(T::cst(0.0))
    }
}

impl<T: Real, const N: usize> Add for Dual<T, N> {
    type Output = Self;
    #[inline(always)]
    fn add(mut self, o: Self) -> Self {
        self.re += o.re;
        for k in 0..N {
            self.eps[k] += o.eps[k];
        }
        self
    }
}

impl<T: Real, const N: usize> Sub for Dual<T, N> {
    type Output = Self;
    #[inline(always)]
    fn sub(mut self, o: Self) -> Self {
        self.re -= o.re;
        for k in 0..N {
            self.eps[k] -= o.eps[k];
        }
        self
    }
}

impl<T: Real, const N: usize> Mul for Dual<T, N> {
    type Output = Self;
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        let mut eps = Self::ZERO.eps;
        for k in 0..N {
            eps[k] = self.eps[k] * o.re + o.eps[k] * self.re;
        }
        Dual {
            re: self.re * o.re,
            eps,
        }
    }
}

impl<T: Real, const N: usize> Div for Dual<T, N> {
    type Output = Self;
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        // The value part is divided exactly as the plain type would, so that value and
        // gradient passes agree bit for bit.
        let inv = T::cst(1.0) / o.re;
        let re = self.re / o.re;
        let mut eps = Self::ZERO.eps;
        for k in 0..N {
            eps[k] = (self.eps[k] - re * o.eps[k]) * inv;
        }
        Dual { re, eps }
    }
}

impl<T: Real, const N: usize> Neg for Dual<T, N> {
    type Output = Self;
    #[inline(always)]
    fn neg(mut self) -> Self {
        self.re = -self.re;
        for e in self.eps.iter_mut() {
            *e = -*e;
        }
        self
    }
}

impl<T: Real, const N: usize> AddAssign for Dual<T, N> {
    #[inline(always)]
    fn add_assign(&mut self, o: Self) {
        *self = *self + o;
    }
}
impl<T: Real, const N: usize> SubAssign for Dual<T, N> {
    #[inline(always)]
    fn sub_assign(&mut self, o: Self) {
        *self = *self - o;
    }
}
impl<T: Real, const N: usize> MulAssign for Dual<T, N> {
    #[inline(always)]
    fn mul_assign(&mut self, o: Self) {
        *self = *self * o;
    }
}

impl<T: Real, const N: usize> Real for Dual<T, N> {
    #[inline(always)]
    fn cst(v: f64) -> Self {
        Dual::constant(T::cst(v))
    }
    #[inline(always)]
    fn value(self) -> f64 {
        self.re.value()
    }
    #[inline(always)]
    fn is_constant(self) -> bool {
        self.re.is_constant() && self.eps.iter().all(|e| e.is_zero() && e.is_constant())
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        let s = self.re.sqrt();
        self.chain(s, T::cst(0.5) / s)
    }
    #[inline(always)]
    fn sin(self) -> Self {
        self.chain(self.re.sin(), self.re.cos())
    }
    #[inline(always)]
    fn cos(self) -> Self {
        self.chain(self.re.cos(), -self.re.sin())
    }
    const ZERO: Self = Dual {
        re: T::ZERO,
        eps: [T::ZERO; N],
    };
    const EPSILON: f64 = T::EPSILON;
    const NAME: &'static str = "dual";
    const PARTS: usize = T::PARTS * (N + 1);
    #[inline(always)]
    fn part(self, k: usize) -> f64 {
        let (c, r) = (k / T::PARTS, k % T::PARTS);
        if c == 0 {
            self.re.part(r)
        } else {
            self.eps[c - 1].part(r)
        }
    }
    #[inline(always)]
    fn from_parts(parts: &[f64]) -> Self {
        let t = T::PARTS;
        let mut eps = [T::cst(0.0); N];
        for (k, e) in eps.iter_mut().enumerate() {
            *e = T::from_parts(&parts[(k + 1) * t..(k + 2) * t]);
        }
        Dual {
            re: T::from_parts(&parts[..t]),
            eps,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// f(x, y) = sin(x) sqrt(x y) / (x + cos(y)) against its analytic partial derivatives.
    #[test]
    fn derivatives_match_analytic_forms() {
        let (x0, y0) = (0.7f64, 1.3f64);
        let x = Dual::<f64, 2>::var(x0, 0);
        let y = Dual::<f64, 2>::var(y0, 1);
        let f = x.sin() * (x * y).sqrt() / (x + y.cos());
        let g = |x: f64, y: f64| x.sin() * (x * y).sqrt() / (x + y.cos());
        let h = 1e-6;
        let fx = (g(x0 + h, y0) - g(x0 - h, y0)) / (2.0 * h);
        let fy = (g(x0, y0 + h) - g(x0, y0 - h)) / (2.0 * h);
        assert!((f.re - g(x0, y0)).abs() < 1e-15);
        assert!((f.eps[0] - fx).abs() < 1e-8 && (f.eps[1] - fy).abs() < 1e-8);
        // Exact analytic check of one partial: d/dy = sin(x) [x / (2 sqrt(xy)) (x + cos y) + sqrt(xy) sin y] / (x + cos y)^2
        let (s, q, d) = (x0.sin(), (x0 * y0).sqrt(), x0 + y0.cos());
        let exact = s * (x0 / (2.0 * q) * d + q * y0.sin()) / (d * d);
        assert!((f.eps[1] - exact).abs() < 1e-15);
    }

    /// Parts round-trip, nested duals included: value first, then each derivative's parts.
    #[test]
    fn parts_round_trip() {
        type D = Dual<Dual<f64, 2>, 3>;
        let mut x = D::constant(Dual {
            re: 1.0,
            eps: [2.0, 3.0],
        });
        for (k, e) in x.eps.iter_mut().enumerate() {
            *e = Dual {
                re: 4.0 + k as f64,
                eps: [10.0 + k as f64, 20.0 + k as f64],
            };
        }
        assert_eq!(D::PARTS, 12);
        let p: Vec<f64> = (0..D::PARTS).map(|k| x.part(k)).collect();
        assert_eq!(&p[..6], &[1.0, 2.0, 3.0, 4.0, 10.0, 20.0]);
        assert_eq!(D::from_parts(&p), x);
        assert_eq!(<f64 as Real>::PARTS, 1);
        assert_eq!(f64::from_parts(&[2.5]), 2.5);
    }
}
