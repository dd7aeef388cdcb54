//! A double-double number (an unevaluated sum `hi + lo` of two f64, about 106 significant bits)
//! implementing the tracer's number trait, so that a test can evaluate an objective ~1e-32
//! relative and take central differences far below f64's rounding floor.
//!
//! It is a test oracle, not a number type for users: the library never instantiates it. Written
//! here (Dekker's and Knuth's error-free sums and products, one Newton step for the square
//! root, Taylor series after a reduction by π/2 for the sine and cosine) because the test must
//! know exactly what precision it gets, and each operation is checked below against identities
//! that hold to that precision. `dd_central_diff` is the central difference the gradient tests
//! take with it.

use std::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};
use tolray::lens::{Adjustments, Param, System};
use tolray::optim::{param_value, set_param, Objective};
use tolray::real::Real;
use tolray::trace::Traceable;
use tolray::Lens;

/// `hi + lo` with `|lo| <= ulp(hi) / 2`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Dd {
    pub hi: f64,
    pub lo: f64,
}

/// `a + b` exactly, as a sum and its rounding error (Knuth).
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    (s, (a - (s - bb)) + (b - bb))
}

/// `a + b` exactly for `|a| >= |b|` (Dekker).
fn quick_two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    (s, b - (s - a))
}

/// `a · b` exactly, by a fused multiply-add.
fn two_prod(a: f64, b: f64) -> (f64, f64) {
    let p = a * b;
    (p, a.mul_add(b, -p))
}

impl Dd {
    fn new(hi: f64, lo: f64) -> Self {
        let (hi, lo) = quick_two_sum(hi, lo);
        Dd { hi, lo }
    }

    /// π/2 to about 107 bits.
    const HALF_PI: Dd = Dd {
        hi: std::f64::consts::FRAC_PI_2,
        lo: 6.123_233_995_736_766e-17,
    };

    /// The sine and cosine of `|r| <= π/4` by their Taylor series (terms below 1e-34 dropped).
    fn sin_cos_reduced(r: Dd) -> (Dd, Dd) {
        let r2 = r * r;
        let (mut s, mut c) = (r, Dd::cst(1.0));
        let (mut ts, mut tc) = (r, Dd::cst(1.0));
        for n in 1..30 {
            let k = 2.0 * f64::from(n);
            tc = -(tc * r2) / Dd::cst(k * (k - 1.0));
            ts = -(ts * r2) / Dd::cst(k * (k + 1.0));
            c += tc;
            s += ts;
            if ts.hi.abs() < 1e-34 && tc.hi.abs() < 1e-34 {
                break;
            }
        }
        (s, c)
    }

    /// The sine and cosine: `x = k π/2 + r` with `|r| <= π/4`, then the quadrant's symmetry.
    fn sin_cos(self) -> (Dd, Dd) {
        let k = (self.hi / std::f64::consts::FRAC_PI_2).round();
        // k π/2 exactly enough: the product of an integer below 2^20 and the two parts of π/2.
        assert!(
            k.abs() < 1048576.0,
            "double-double sin/cos: argument {} too large",
            self.hi
        );
        let (p, e) = two_prod(k, Dd::HALF_PI.hi);
        let kp = Dd::new(p, e + k * Dd::HALF_PI.lo);
        let (s, c) = Dd::sin_cos_reduced(self - kp);
        match (k as i64).rem_euclid(4) {
            0 => (s, c),
            1 => (c, -s),
            2 => (-s, -c),
            _ => (-c, s),
        }
    }
}

impl Add for Dd {
    type Output = Dd;
    fn add(self, o: Dd) -> Dd {
        let (s, e) = two_sum(self.hi, o.hi);
        let (t, f) = two_sum(self.lo, o.lo);
        let (s, e) = quick_two_sum(s, e + t);
        Dd::new(s, e + f)
    }
}

impl Neg for Dd {
    type Output = Dd;
    fn neg(self) -> Dd {
        Dd {
            hi: -self.hi,
            lo: -self.lo,
        }
    }
}

impl Sub for Dd {
    type Output = Dd;
    fn sub(self, o: Dd) -> Dd {
        self + -o
    }
}

impl Mul for Dd {
    type Output = Dd;
    fn mul(self, o: Dd) -> Dd {
        let (p, e) = two_prod(self.hi, o.hi);
        Dd::new(p, e + (self.hi * o.lo + self.lo * o.hi))
    }
}

impl Div for Dd {
    type Output = Dd;
    fn div(self, o: Dd) -> Dd {
        // Three quotient digits, each from the remainder of the last.
        let q1 = self.hi / o.hi;
        let r = self - o * Dd::cst(q1);
        let q2 = r.hi / o.hi;
        let r = r - o * Dd::cst(q2);
        let q3 = r.hi / o.hi;
        Dd::new(q1, q2) + Dd::cst(q3)
    }
}

impl AddAssign for Dd {
    fn add_assign(&mut self, o: Dd) {
        *self = *self + o;
    }
}

impl SubAssign for Dd {
    fn sub_assign(&mut self, o: Dd) {
        *self = *self - o;
    }
}

impl MulAssign for Dd {
    fn mul_assign(&mut self, o: Dd) {
        *self = *self * o;
    }
}

impl Real for Dd {
    fn cst(v: f64) -> Self {
        Dd { hi: v, lo: 0.0 }
    }
    fn value(self) -> f64 {
        self.hi
    }
    fn sqrt(self) -> Self {
        if self.hi <= 0.0 {
            return Dd::cst(self.hi.sqrt());
        }
        // One Newton step from the f64 root doubles its 53 bits.
        let q = Dd::cst(self.hi.sqrt());
        q + (self - q * q) / (q * Dd::cst(2.0))
    }
    fn sin(self) -> Self {
        self.sin_cos().0
    }
    fn cos(self) -> Self {
        self.sin_cos().1
    }
    const ZERO: Self = Dd { hi: 0.0, lo: 0.0 };
    const EPSILON: f64 = 4.930_380_657_631_324e-32; // 2^-104
    const NAME: &'static str = "double-double";
    // Its two f64 components, so that a linear map with constant coefficients (an FFT) applies
    // to each: the high part's transform rounds as an f64 one does, which a test must allow for.
    const PARTS: usize = 2;
    fn part(self, k: usize) -> f64 {
        [self.hi, self.lo][k]
    }
    fn from_parts(parts: &[f64]) -> Self {
        let (hi, lo) = two_sum(parts[0], parts[1]);
        Dd { hi, lo }
    }
}

impl Traceable for Dd {}

/// The objective evaluated in double-double numbers (the same generic code, ~1e-32 relative).
pub fn value_dd<O: Objective>(obj: &O, lens: &Lens, adj: &Adjustments) -> Dd {
    let sys: System<Dd> = System::compile(lens, adj, &|_, v| v);
    obj.eval(&sys, &|_, v| v)
}

/// The central difference `(L(x + h) − L(x − h)) / 2h` in `p` of the objective `make` builds at
/// each stepped design (its rays launched from it), evaluated in double-double numbers, over the
/// step between the stored parameter values; with `extrapolate`, the fourth-order difference
/// extrapolated by Richardson's rule from steps h and h/2.
pub fn dd_central_diff<O: Objective>(
    make: &dyn Fn(&Lens) -> O,
    lens: &Lens,
    adj: &Adjustments,
    p: Param,
    h: f64,
    extrapolate: bool,
) -> f64 {
    let x0 = param_value(lens, p).unwrap();
    let stepped = |dx: f64| {
        let mut l = lens.clone();
        set_param(&mut l, p, x0 + dx).unwrap();
        l
    };
    let f = |dx: f64| {
        let l = stepped(dx);
        value_dd(&make(&l), &l, adj)
    };
    // The step between the stored values x0 ± h (their rounding would otherwise show).
    let at = |dx: f64| Dd::cst(param_value(&stepped(dx), p).unwrap());
    if !extrapolate {
        return ((f(h) - f(-h)) / (at(h) - at(-h))).hi;
    }
    let d4 = |h: f64| {
        let num = f(-2.0 * h) - f(2.0 * h) + Dd::cst(8.0) * (f(h) - f(-h));
        (num / (Dd::cst(6.0) * (at(h) - at(-h)))).hi
    };
    (16.0 * d4(0.5 * h) - d4(h)) / 15.0
}

#[test]
fn double_double_arithmetic_holds_to_its_precision() {
    let third = Dd::cst(1.0) / Dd::cst(3.0);
    // 3 · (1/3) − 1 and the root of 2 squared, to 2^-104 relative.
    assert!((third * Dd::cst(3.0) - Dd::cst(1.0)).hi.abs() < 1e-31);
    let r2 = Dd::cst(2.0).sqrt();
    assert!((r2 * r2 - Dd::cst(2.0)).hi.abs() < 1e-31);
    assert!(r2.lo != 0.0, "the root carries more than an f64");
    // (1 + 1e-20) − 1 keeps the 1e-20 that f64 loses.
    let tiny = Dd::cst(1.0) + Dd::cst(1e-20) - Dd::cst(1.0);
    assert!((tiny.hi - 1e-20).abs() < 1e-36);
    for x in [0.1, 0.7, 1.3, 2.9, -4.2, 17.0, 123.456, -987.6] {
        let (s, c) = Dd::cst(x).sin_cos();
        // The identity, and agreement with libm to its own rounding.
        assert!(
            (s * s + c * c - Dd::cst(1.0)).hi.abs() < 1e-30,
            "sin²+cos² at {x}"
        );
        assert!(
            (s.hi - x.sin()).abs() < 2e-16 && (c.hi - x.cos()).abs() < 2e-16,
            "{x}"
        );
        // The addition theorem at x and a nearby angle: sin(x + d) from both.
        let d = Dd::cst(0.375);
        let (sd, cd) = d.sin_cos();
        let (sxd, _) = (Dd::cst(x) + d).sin_cos();
        assert!(
            (sxd - (s * cd + c * sd)).hi.abs() < 1e-29,
            "sin(x + d) at {x}"
        );
    }
    // sin(π/6) = 1/2 from π/6 in double-double.
    let pi_6 = Dd::HALF_PI / Dd::cst(3.0);
    assert!((pi_6.sin() - Dd::cst(0.5)).hi.abs() < 1e-31);
}
