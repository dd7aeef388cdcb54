//! Radial diffractive phase on a surface ([`RadialPhase`]: OpticStudio's Binary 2 surface,
//! `BINARY_2`): `Φ(x, y) = M Σ_i A_i ρ^(2i)` radians, `ρ = r / R`, with the diffraction order
//! `M`, the normalization radius `R` and the coefficients `A_i` in radians (the phase is the
//! same at every wavelength; its effect scales with the wavelength).
//!
//! A ray crossing the surface keeps the continuity of its tangential wave vector plus the
//! phase's gradient: `n' t' = n t + (λ / 2π) ∇_t Φ` (λ in mm, ∇_t the gradient of Φ in the
//! surface's local x-y plane projected on its tangent plane), and its optical path gains
//! `λ Φ / 2π`. A ruled grating is the special case `Φ = 2π m T y`. Negative `A_1` focuses: the
//! paraxial power is `−M λ A_1 / (π R²)`.
//!
//! ```
//! use tolray::lens::phase::{PhaseRow, RadialPhase};
//! // Φ = −1000 ρ² over R = 10 mm, first order.
//! let p = RadialPhase { order: 1.0, norm_radius_mm: 10.0, coefficients: vec![-1000.0] };
//! let row = PhaseRow::<f64>::new(&p, &[-1000.0]);
//! let (phi, gx, gy) = row.eval(3.0, 4.0);
//! assert!((phi + 250.0).abs() < 1e-12); // −1000 (25 / 100)
//! assert!((gx + 60.0).abs() < 1e-12 && (gy + 80.0).abs() < 1e-12); // −2000 x / 100
//! // The paraxial power at 550 nm: f = π R² / (λ M |A_1|) ≈ 571 mm.
//! assert!((1.0 / p.power_per_mm(550.0) - 571.198).abs() < 1e-3);
//! ```

use crate::real::Real;

/// Most phase coefficients a surface takes (OpticStudio's Binary 2 surface keeps them in its
/// extra data, which holds at most 240 terms).
pub const MAX_PHASE_TERMS: usize = 240;

/// A radial phase polynomial on a surface (OpticStudio's Binary 2).
#[derive(Clone, Debug, PartialEq)]
pub struct RadialPhase {
    /// Diffraction order M (OpticStudio's PARM 0; 0 turns the phase off).
    pub order: f64,
    /// Normalization radius R, mm.
    pub norm_radius_mm: f64,
    /// A_1, A_2, ... on ρ², ρ⁴, ..., radians.
    pub coefficients: Vec<f64>,
}

impl RadialPhase {
    /// Paraxial power at `wavelength_nm`, 1/mm: `−M λ A_1 / (π R²)` (`n' u' = n u − y K`).
    pub fn power_per_mm(&self, wavelength_nm: f64) -> f64 {
        let a1 = self.coefficients.first().copied().unwrap_or(0.0);
        -self.order * wavelength_nm * 1e-6 * a1
            / (std::f64::consts::PI * self.norm_radius_mm * self.norm_radius_mm)
    }
}

/// A compiled phase: the coefficients times the order (in number type `S`, so that dual numbers
/// carry their derivatives) and 1 / R².
#[derive(Clone, Debug)]
pub struct PhaseRow<S> {
    /// M A_1, M A_2, ..., radians.
    coef: Vec<S>,
    /// 1 / R², 1/mm².
    inv_norm2: f64,
}

impl<S: Real> PhaseRow<S> {
    /// `phase` with its coefficients `a` (A_1, A_2, ...; `phase.coefficients` lifted).
    pub fn new(phase: &RadialPhase, a: &[S]) -> Self {
        PhaseRow {
            coef: a.iter().map(|&c| c * S::cst(phase.order)).collect(),
            inv_norm2: 1.0 / (phase.norm_radius_mm * phase.norm_radius_mm),
        }
    }

    /// Φ (radians) and its gradient (`∂Φ/∂x`, `∂Φ/∂y`, radians/mm) at local `(x, y)` (mm).
    #[inline(always)]
    pub fn eval(&self, x: S, y: S) -> (S, S, S) {
        let zero = S::cst(0.0);
        let u = (x * x + y * y) * S::cst(self.inv_norm2);
        // Φ = u (c1 + u (c2 + ...)), dΦ/du by Horner alongside.
        let (mut p, mut dp) = (zero, zero);
        for (j, &c) in self.coef.iter().enumerate().rev() {
            dp = dp * u + S::cst((j + 1) as f64) * c;
            p = p * u + c;
        }
        let g = S::cst(2.0 * self.inv_norm2) * dp;
        (p * u, g * x, g * y)
    }

    /// The same phase in another number type (derivatives dropped).
    pub fn convert<T: Real>(&self) -> PhaseRow<T> {
        PhaseRow {
            coef: self.coef.iter().map(|c| T::cst(c.value())).collect(),
            inv_norm2: self.inv_norm2,
        }
    }

    /// The normalization radius R, mm.
    pub fn norm_radius_mm(&self) -> f64 {
        1.0 / self.inv_norm2.sqrt()
    }

    /// M A_1, M A_2, ... (radians), for checks written from the definition.
    pub fn order_times_coefficients(&self) -> &[S] {
        &self.coef
    }
}
