//! Gradient-index media: OpticStudio's Gradient 1, 2 and 3 surfaces.
//!
//! A surface whose [`Material`](super::Material) is [`Material::Gradient`](super::Material)
//! is followed by a medium whose index varies with position, given in that surface's own frame
//! (x, y across, z from its vertex along its axis) by a polynomial in r² = x² + y² and z. Rays
//! in it follow curved paths, integrated from the ray equation
//!
//! d²R/dt² = ∇(n²) / 2, with dt = ds / n and dR/dt = n (unit direction),
//!
//! (Sharma, Kumar and Ghatak, Appl. Opt. 21, 984, 1982) by the fourth-order Runge-Kutta-Nyström
//! step in that parameter, in any number type, until the ray crosses the next surface; the last
//! step's length is found by Newton's method so that the ray ends on that surface. The optical
//! path is ∫ n ds = ∫ n² dt, by Simpson's rule on the step's three stages.

use super::system::Param;
use crate::error::{Error, Result};
use crate::math::Vec3;
use crate::real::Real;

/// How a [`Gradient`]'s polynomial P = Σ radial_k r^(2k+2) + Σ axial_j z^(j+1) gives
/// the index.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GradientForm {
    /// n = n0 + P (OpticStudio's Gradient 1: r² only; Gradient 3: r², r⁴, r⁶ and z, z², z³).
    Index,
    /// n² = n0² + P (OpticStudio's Gradient 2: r² to r¹², no axial terms).
    IndexSquared,
}

/// Number of radial terms a [`Gradient`] holds (r² to r¹²).
pub const N_RADIAL: usize = 6;
/// Number of axial terms a [`Gradient`] holds (z to z³).
pub const N_AXIAL: usize = 3;

/// A gradient-index medium (lengths in mm; the coefficients carry the matching powers of 1/mm).
///
/// ```
/// use tolray::lens::gradient::{Gradient, GradientForm};
/// // A SELFOC-like rod: n(r) = 1.6 - 0.05 r² (OpticStudio Gradient 1).
/// let g = Gradient::radial(GradientForm::Index, 1.6, &[-0.05], 0.05);
/// assert!((g.index(1.0, 0.0, 3.0) - 1.55).abs() < 1e-15);
/// assert_eq!(g.zemax_type(), "GRINSUR1");
/// assert!(g.validate().is_ok());
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gradient {
    /// Whether the polynomial gives n or n².
    pub form: GradientForm,
    /// Index at the vertex (r = 0, z = 0).
    pub n0: f64,
    /// Coefficients of r², r⁴, ..., r¹² (mm^-2, mm^-4, ...).
    pub radial: [f64; N_RADIAL],
    /// Coefficients of z, z², z³ (mm^-1, mm^-2, mm^-3).
    pub axial: [f64; N_AXIAL],
    /// The largest step along a ray, mm (OpticStudio's Δt, PARM 1): smaller is more exact.
    pub step_mm: f64,
}

/// The smallest integration step accepted, mm.
pub const MIN_STEP_MM: f64 = 1e-6;

impl Gradient {
    /// A medium with radial terms only (`radial[k]` on r^(2k+2)).
    pub fn radial(form: GradientForm, n0: f64, radial: &[f64], step_mm: f64) -> Gradient {
        let mut r = [0.0; N_RADIAL];
        r[..radial.len()].copy_from_slice(radial);
        Gradient {
            form,
            n0,
            radial: r,
            axial: [0.0; N_AXIAL],
            step_mm,
        }
    }

    /// Index at (x, y, z) in the medium's frame, mm.
    pub fn index(&self, x: f64, y: f64, z: f64) -> f64 {
        let row = GradientRow::<f64>::new(self, 0, &|_, v| v);
        row.index(Vec3::new(x, y, z))
    }

    /// OpticStudio's surface type for this medium: `GRINSUR1` (n = n0 + nr2 r²), `GRINSUR3`
    /// (n = n0 + nr2 r² + nr4 r⁴ + nr6 r⁶ + nz1 z + nz2 z² + nz3 z³) or `GRINSUR2` (n² = n0² +
    /// nr2 r² + ... + nr12 r¹²).
    pub fn zemax_type(&self) -> &'static str {
        match self.form {
            GradientForm::IndexSquared => "GRINSUR2",
            GradientForm::Index
                if self.radial[1..]
                    .iter()
                    .chain(&self.axial)
                    .all(|&v| v == 0.0) =>
            {
                "GRINSUR1"
            }
            GradientForm::Index => "GRINSUR3",
        }
    }

    /// The medium of an OpticStudio Gradient 1, 2 or 3 surface (`ty` = `GRINSUR1` ..
    /// `GRINSUR3`) from its parameters `parm[k]` = PARM k (PARM 1 = Δt, PARM 2 = n0, then the
    /// coefficients in OpticStudio's order); `None` for another type.
    pub fn from_zemax(ty: &str, parm: &[f64; 9]) -> Option<Gradient> {
        let mut g = Gradient {
            form: GradientForm::Index,
            n0: parm[2],
            radial: [0.0; N_RADIAL],
            axial: [0.0; N_AXIAL],
            step_mm: parm[1],
        };
        match ty {
            "GRINSUR1" => g.radial[0] = parm[3],
            "GRINSUR2" => {
                g.form = GradientForm::IndexSquared;
                g.radial.copy_from_slice(&parm[3..9]);
            }
            "GRINSUR3" => {
                g.radial[..3].copy_from_slice(&parm[3..6]);
                g.axial.copy_from_slice(&parm[6..9]);
            }
            _ => return None,
        }
        Some(g)
    }

    /// The PARM lines of [`Gradient::zemax_type`]: (k, PARM k) for k = 1 to 8 (3 for
    /// Gradient 1).
    pub fn zemax_parms(&self) -> Vec<(usize, f64)> {
        let mut v = vec![(1, self.step_mm), (2, self.n0)];
        let terms: Vec<f64> = match self.zemax_type() {
            "GRINSUR1" => vec![self.radial[0]],
            "GRINSUR2" => self.radial.to_vec(),
            _ => self.radial[..3]
                .iter()
                .chain(&self.axial)
                .copied()
                .collect(),
        };
        v.extend(terms.into_iter().enumerate().map(|(k, c)| (k + 3, c)));
        v
    }

    /// Checks the medium: finite coefficients, n0 a usable index, a step from
    /// [`MIN_STEP_MM`] to 1e3 mm, and a form that OpticStudio can hold (the index form has
    /// radial terms up to r⁶ only, the squared form no axial terms).
    ///
    /// # Errors
    /// [`crate::ErrorKind::Invalid`] saying what is wrong.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::invalid(format!("gradient-index medium: {m}")));
        if !super::material::is_usable_index(self.n0) {
            return bad(format!("n0 = {} is not a usable index", self.n0));
        }
        if !(self.step_mm >= MIN_STEP_MM && self.step_mm <= 1e3) {
            return bad(format!(
                "step {} mm (PARM 1, Δt) must lie from {MIN_STEP_MM} to 1000 mm",
                self.step_mm
            ));
        }
        if let Some(v) = self
            .radial
            .iter()
            .chain(&self.axial)
            .find(|v| !v.is_finite())
        {
            return bad(format!("coefficient {v} is not a finite number"));
        }
        match self.form {
            GradientForm::Index if self.radial[3..].iter().any(|&v| v != 0.0) => {
                bad("the index form (Gradient 1 and 3) has radial terms up to r⁶ only".into())
            }
            GradientForm::IndexSquared if self.axial.iter().any(|&v| v != 0.0) => {
                bad("the squared form (Gradient 2) has no axial terms".into())
            }
            _ => Ok(()),
        }
    }
}

/// A [`Gradient`] compiled in number type `S`, its coefficients lifted as
/// [`Param::Gradient`] of its surface (0 = n0, 1 to 6 the radial terms, 7 to 9 the axial ones).
#[derive(Clone, Debug)]
pub struct GradientRow<S> {
    /// True for the squared form.
    pub squared: bool,
    /// n0 (the index form) or n0² (the squared form).
    pub base: S,
    /// The radial coefficients.
    pub radial: [S; N_RADIAL],
    /// The axial coefficients.
    pub axial: [S; N_AXIAL],
    /// Number of leading radial terms in use.
    pub n_radial: usize,
    /// True when an axial term is in use.
    pub has_axial: bool,
    /// The step in the parameter t (mm over the index): the largest step along the ray over n0.
    pub dt: f64,
    /// The most steps a ray may take before it counts as trapped (set for the medium's gap by
    /// [`GradientRow::limit_steps`]).
    pub max_steps: usize,
}

impl<S: Real> GradientRow<S> {
    /// Compiles the medium after surface `surface`, each coefficient through `lift`.
    pub fn new(g: &Gradient, surface: usize, lift: &dyn Fn(Param, S) -> S) -> GradientRow<S> {
        let n0 = lift(Param::Gradient(surface, 0), S::cst(g.n0));
        let radial: [S; N_RADIAL] =
            std::array::from_fn(|k| lift(Param::Gradient(surface, 1 + k), S::cst(g.radial[k])));
        let axial: [S; N_AXIAL] = std::array::from_fn(|j| {
            lift(
                Param::Gradient(surface, 1 + N_RADIAL + j),
                S::cst(g.axial[j]),
            )
        });
        let used = |v: &S| v.value() != 0.0 || !v.is_constant();
        GradientRow {
            squared: g.form == GradientForm::IndexSquared,
            base: if g.form == GradientForm::IndexSquared {
                n0 * n0
            } else {
                n0
            },
            n_radial: radial.iter().rposition(used).map_or(0, |k| k + 1),
            has_axial: axial.iter().any(used),
            radial,
            axial,
            dt: g.step_mm / g.n0,
            max_steps: 0,
        }
    }

    /// Sets [`GradientRow::max_steps`] for a medium `gap_mm` thick traced in steps of
    /// `step_mm`: sixteen times the steps across the gap, and 256 more.
    pub fn limit_steps(mut self, gap_mm: f64, step_mm: f64) -> Self {
        let n = (gap_mm.abs() / step_mm).ceil();
        self.max_steps = if n.is_finite() && n < 1e8 {
            256 + 16 * n as usize
        } else {
            0
        };
        self
    }

    /// The polynomial's value Q (n or n²) and its gradient at `p`.
    #[inline]
    fn poly(&self, p: Vec3<S>) -> (S, Vec3<S>) {
        let zero = S::cst(0.0);
        let r2 = p.x * p.x + p.y * p.y;
        // Horner in r²: q = Σ c_k r^(2k+2), dq/d(r²) = Σ (k+1) c_k r^(2k).
        let (mut q, mut dq) = (zero, zero);
        for k in (0..self.n_radial).rev() {
            dq = dq * r2 + self.radial[k] * S::cst((k + 1) as f64);
            q = (q + self.radial[k]) * r2;
        }
        let (mut qz, mut dqz) = (zero, zero);
        if self.has_axial {
            let z = p.z;
            let [a1, a2, a3] = self.axial;
            qz = ((a3 * z + a2) * z + a1) * z;
            dqz = (S::cst(3.0) * a3 * z + S::cst(2.0) * a2) * z + a1;
        }
        let two_dq = dq * S::cst(2.0);
        (
            self.base + q + qz,
            Vec3::new(two_dq * p.x, two_dq * p.y, dqz),
        )
    }

    /// n² and ∇(n²) / 2 at `p`.
    #[inline]
    pub fn n2_and_force(&self, p: Vec3<S>) -> (S, Vec3<S>) {
        let (q, g) = self.poly(p);
        if self.squared {
            (q, g * S::cst(0.5))
        } else {
            (q * q, g * q)
        }
    }

    /// The index at `p` (NaN-free only where n² > 0).
    #[inline]
    pub fn index(&self, p: Vec3<S>) -> S {
        let (q, _) = self.poly(p);
        if self.squared {
            q.sqrt()
        } else {
            q
        }
    }

    /// The index on the axis at `z` and its rate of change with r² there: n ≈ N + N₂ r².
    fn on_axis(&self, z: S) -> (S, S) {
        let (q, _) = self.poly(Vec3::new(S::cst(0.0), S::cst(0.0), z));
        let c2 = if self.n_radial > 0 {
            self.radial[0]
        } else {
            S::cst(0.0)
        };
        if self.squared {
            let n = q.sqrt();
            (n, c2 / (n * S::cst(2.0)))
        } else {
            (q, c2)
        }
    }

    /// The paraxial transfer through `len_mm` of the medium: the matrix `[a, b, c, d]` taking a
    /// paraxial ray's height y and reduced slope w = n dy/dz at the entry vertex plane to those
    /// at the exit plane, and the axial index at entry and exit. It integrates dy/dz = w / N(z),
    /// dw/dz = 2 N₂(z) y by the classical Runge-Kutta method in 1024 steps (its error grows as
    /// the fourth power of the medium's length in pitches; the tests hold the focal length of
    /// rods of 0.14 and 0.23 pitch to 1e-9 of the closed form).
    pub fn paraxial_transfer(&self, len_mm: S) -> ([S; 4], S, S) {
        const STEPS: usize = 1024;
        let h = len_mm / S::cst(STEPS as f64);
        let half = S::cst(0.5);
        // Two columns: the rays (1, 0) and (0, 1).
        let mut cols = [[S::cst(1.0), S::cst(0.0)], [S::cst(0.0), S::cst(1.0)]];
        let f = |z: S, y: S, w: S| {
            let (n, n2) = self.on_axis(z);
            (w / n, S::cst(2.0) * n2 * y)
        };
        for k in 0..STEPS {
            let z = h * S::cst(k as f64);
            for [y, w] in cols.iter_mut() {
                let (k1y, k1w) = f(z, *y, *w);
                let (k2y, k2w) = f(z + h * half, *y + k1y * h * half, *w + k1w * h * half);
                let (k3y, k3w) = f(z + h * half, *y + k2y * h * half, *w + k2w * h * half);
                let (k4y, k4w) = f(z + h, *y + k3y * h, *w + k3w * h);
                let sixth = h * S::cst(1.0 / 6.0);
                *y += (k1y + (k2y + k3y) * S::cst(2.0) + k4y) * sixth;
                *w += (k1w + (k2w + k3w) * S::cst(2.0) + k4w) * sixth;
            }
        }
        let [[a, c], [b, d]] = cols;
        (
            [a, b, c, d],
            self.on_axis(S::cst(0.0)).0,
            self.on_axis(len_mm).0,
        )
    }

    /// The same medium in another number type (derivatives dropped).
    pub fn convert<T: Real>(&self) -> GradientRow<T> {
        GradientRow {
            squared: self.squared,
            base: T::cst(self.base.value()),
            radial: self.radial.map(|v| T::cst(v.value())),
            axial: self.axial.map(|v| T::cst(v.value())),
            n_radial: self.n_radial,
            has_axial: self.has_axial,
            dt: self.dt,
            max_steps: self.max_steps,
        }
    }

    /// One Runge-Kutta-Nyström step of length `h` in t from position `p` and optical direction
    /// cosines `tv` (n times the unit direction): the new position and optical direction, the
    /// optical path gained (∫ n² dt by Simpson's rule) and whether n² stayed positive.
    #[inline]
    pub fn step(&self, p: Vec3<S>, tv: Vec3<S>, h: S) -> (Vec3<S>, Vec3<S>, S, bool) {
        let half = S::cst(0.5);
        let sixth = S::cst(1.0 / 6.0);
        let (n2a, fa) = self.n2_and_force(p);
        let a = fa * h;
        let pm = p + tv * (h * half) + a * (h * S::cst(0.125));
        let (n2b, fb) = self.n2_and_force(pm);
        let b = fb * h;
        let pe = p + tv * h + b * (h * half);
        let (n2c, fc) = self.n2_and_force(pe);
        let c = fc * h;
        let p1 = p + (tv + (a + b * S::cst(2.0)) * sixth) * h;
        let t1 = tv + (a + b * S::cst(4.0) + c) * sixth;
        let dopl = (n2a + n2b * S::cst(4.0) + n2c) * (h * sixth);
        let zero = S::cst(0.0);
        let ok = zero.lt(n2a) & zero.lt(n2b) & zero.lt(n2c);
        (p1, t1, dopl, ok)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zemax_parameters_read_back() {
        let mut parm = [0.0; 9];
        parm[1..9].copy_from_slice(&[0.1, 1.6, -0.01, 1e-4, -1e-6, 0.002, -3e-5, 1e-7]);
        let g = Gradient::from_zemax("GRINSUR3", &parm).unwrap();
        assert_eq!(g.zemax_type(), "GRINSUR3");
        let mut back = [0.0; 9];
        for (k, v) in g.zemax_parms() {
            back[k] = v;
        }
        assert_eq!(back, parm);
        assert!(Gradient::from_zemax("STANDARD", &parm).is_none());
    }

    #[test]
    fn forms_give_their_index() {
        let sq = Gradient::radial(GradientForm::IndexSquared, 1.5, &[-0.1, 0.001], 0.1);
        let r2: f64 = 0.5 * 0.5 + 0.25;
        let want = (1.5f64 * 1.5 - 0.1 * r2 + 0.001 * r2 * r2).sqrt();
        assert!((sq.index(0.5, 0.5, 7.0) - want).abs() < 1e-15);
        let mut g3 = Gradient::radial(GradientForm::Index, 1.6, &[-0.01, 0.0, 2e-5], 0.1);
        g3.axial = [0.01, -0.001, 1e-4];
        let (x, y, z) = (0.3, -0.4, 2.0);
        let r2: f64 = x * x + y * y;
        let want =
            1.6 - 0.01 * r2 + 2e-5 * r2.powi(3) + 0.01 * z - 0.001 * z * z + 1e-4 * z.powi(3);
        assert!((g3.index(x, y, z) - want).abs() < 1e-15);
        // The force is half the gradient of n², checked by central differences.
        let row = GradientRow::<f64>::new(&g3, 0, &|_, v| v);
        let p = Vec3::new(x, y, z);
        let (_, f) = row.n2_and_force(p);
        let e = 1e-6;
        let n2 = |q: Vec3<f64>| row.n2_and_force(q).0;
        let fd = |dq: Vec3<f64>| (n2(p + dq) - n2(p - dq)) / (4.0 * e);
        assert!((f.x - fd(Vec3::new(e, 0.0, 0.0))).abs() < 1e-9);
        assert!((f.y - fd(Vec3::new(0.0, e, 0.0))).abs() < 1e-9);
        assert!((f.z - fd(Vec3::new(0.0, 0.0, e))).abs() < 1e-9);
    }

    #[test]
    fn validation_names_the_fault() {
        let mut g = Gradient::radial(GradientForm::Index, 1.6, &[-0.01], 0.1);
        assert!(g.validate().is_ok());
        g.step_mm = 0.0;
        assert!(g.validate().unwrap_err().to_string().contains("step"));
        g.step_mm = 0.1;
        g.radial[4] = 1e-9;
        assert!(g.validate().unwrap_err().to_string().contains("r⁶"));
        let mut s = Gradient::radial(GradientForm::IndexSquared, 1.6, &[-0.01], 0.1);
        s.axial[0] = 0.1;
        assert!(s.validate().unwrap_err().to_string().contains("axial"));
        s.axial[0] = f64::NAN;
        assert!(s.validate().is_err());
    }
}
