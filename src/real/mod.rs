//! The number trait every geometric kernel in tolray is generic over.
//!
//! The tracer is written once against [`Real`]. Value traces instantiate it with `f32` or `f64`;
//! gradient traces instantiate it with forward-mode dual numbers. Comparisons and branches look at
//! the value part only ([`Real::value`]), so the same code path is taken for every number type
//! and derivatives flow through the arithmetic unchanged.

mod dual;
pub use dual::Dual;

/// Width of the dual numbers used for gradients (derivatives per pass). The kernel compiles its
/// gradient entry points for this width once, in the library (`trace::kernel`).
pub const GRAD_WIDTH: usize = 8;

use std::fmt::Debug;
use std::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};

/// Everything the tracing kernel needs from a number.
///
/// Implementations must be plain `Copy` values (no heap), so that ray state stays on the stack
/// and inner loops vectorize.
pub trait Real:
    Copy
    + Send
    + Sync
    + Debug
    + Default
    + 'static
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
{
    /// A constant (derivatives zero).
    fn cst(v: f64) -> Self;
    /// The value part as `f64` (for branching, reporting and statistics).
    fn value(self) -> f64;
    /// Square root.
    fn sqrt(self) -> Self;
    /// `self` if `cond`, else `other`; written so that LLVM can turn it into a select.
    #[inline(always)]
    fn pick(cond: bool, a: Self, b: Self) -> Self {
        if cond {
            a
        } else {
            b
        }
    }
    /// Sine.
    fn sin(self) -> Self;
    /// Cosine.
    fn cos(self) -> Self;
    /// Absolute value (by the value part's sign).
    #[inline(always)]
    fn abs(self) -> Self {
        if self.value() < 0.0 {
            -self
        } else {
            self
        }
    }
    /// `|self|` with the sign of `sign` (by value parts; `+0` counts as positive).
    #[inline(always)]
    fn copysign(self, sign: Self) -> Self {
        let a = self.abs();
        if sign.value() < 0.0 {
            -a
        } else {
            a
        }
    }
    /// `self < other`, comparing value parts in the native type (no widening, so that lane
    /// loops vectorize).
    #[inline(always)]
    fn lt(self, other: Self) -> bool {
        self.value() < other.value()
    }
    /// `self == 0` by value.
    #[inline(always)]
    fn is_zero(self) -> bool {
        self.value() == 0.0
    }
    /// True when no derivative part is carried (always for plain floats). The compiled lens uses it
    /// so that a surface whose coefficient is being differentiated keeps the routine that coefficient
    /// enters, even while its value is zero.
    #[inline(always)]
    fn is_constant(self) -> bool {
        true
    }
    /// Zero (derivatives zero), as a constant: what [`Real::cst`]`(0.0)` gives, known at compile
    /// time (a dual number's zero is then a constant, not parts filled at run time).
    const ZERO: Self;
    /// Machine epsilon of the value type.
    const EPSILON: f64;
    /// Short type name for reports and benchmark labels.
    const NAME: &'static str;
    /// Number of `f64` components: the value and, for dual numbers, each derivative part
    /// (1 for plain floats). A map that is linear with constant coefficients (an FFT) applies
    /// to a number component by component, so a crate written for `f64` can carry any `Real`.
    const PARTS: usize = 1;
    /// Component `k` of [`Real::PARTS`] (0 is the value).
    #[inline(always)]
    fn part(self, k: usize) -> f64 {
        debug_assert_eq!(k, 0);
        self.value()
    }
    /// The number whose components are `parts` ([`Real::PARTS`] of them).
    #[inline(always)]
    fn from_parts(parts: &[f64]) -> Self {
        Self::cst(parts[0])
    }
}

macro_rules! impl_real_float {
    ($t:ty) => {
        impl Real for $t {
            #[inline(always)]
            fn cst(v: f64) -> Self {
                v as $t
            }
            #[inline(always)]
            fn value(self) -> f64 {
                self as f64
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline(always)]
            fn sin(self) -> Self {
                <$t>::sin(self)
            }
            #[inline(always)]
            fn cos(self) -> Self {
                <$t>::cos(self)
            }
            #[inline(always)]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline(always)]
            fn copysign(self, sign: Self) -> Self {
                <$t>::copysign(self, sign)
            }
            #[inline(always)]
            fn lt(self, other: Self) -> bool {
                self < other
            }
            #[inline(always)]
            fn is_zero(self) -> bool {
                self == 0.0
            }
            const ZERO: Self = 0.0;
            const EPSILON: f64 = <$t>::EPSILON as f64;
            const NAME: &'static str = stringify!($t);
        }
    };
}
impl_real_float!(f32);
impl_real_float!(f64);

/// `√x` for `x > 0`, else 0 with derivative 0: a radius of exactly 0 (a perfect point image) is
/// the tip of the cone `|x|`, where sqrt's chain rule would give 0 · ∞ = NaN; 0 there is a
/// subgradient (the one that makes a perfect focus a stationary point).
pub(crate) fn sqrt_or_zero<S: Real>(x: S) -> S {
    if x.value() > 0.0 {
        x.sqrt()
    } else {
        S::cst(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::Real;

    fn generic_hypot<S: Real>(a: S, b: S) -> S {
        (a * a + b * b).sqrt()
    }

    #[test]
    fn float_impls_agree_with_std() {
        assert_eq!(generic_hypot(3.0f64, 4.0).value(), 5.0);
        assert_eq!(generic_hypot(3.0f32, 4.0).value(), 5.0);
        assert_eq!(Real::copysign(2.0f64, -0.5), -2.0);
        assert_eq!(<f64 as Real>::pick(false, 1.0, 2.0), 2.0);
        assert_eq!(<f32 as Real>::cst(0.1), 0.1f32);
    }
}
