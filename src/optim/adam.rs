//! Adam with per-group learning rates and a schedule; deterministic.

use serde::{Deserialize, Serialize};

/// Adam state for a parameter vector.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Adam {
    /// Learning rate per parameter (from its group).
    pub lr: Vec<f64>,
    /// First-moment decay.
    pub beta1: f64,
    /// Second-moment decay.
    pub beta2: f64,
    /// Denominator guard.
    pub eps: f64,
    /// First moments.
    pub m: Vec<f64>,
    /// Second moments.
    pub v: Vec<f64>,
    /// Steps taken.
    pub t: u64,
}

impl Adam {
    /// Adam with learning rates `lr` (one per parameter) and the usual betas (0.9, 0.999).
    pub fn new(lr: Vec<f64>) -> Adam {
        let n = lr.len();
        Adam {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-12,
            m: vec![0.0; n],
            v: vec![0.0; n],
            t: 0,
        }
    }

    /// One step on `x` with gradient `g`; `scale` multiplies every learning rate (the schedule).
    pub fn step(&mut self, x: &mut [f64], g: &[f64], scale: f64) {
        self.t += 1;
        let (b1, b2) = (self.beta1, self.beta2);
        let c1 = 1.0 - b1.powi(self.t as i32);
        let c2 = 1.0 - b2.powi(self.t as i32);
        for i in 0..x.len() {
            let gi = if g[i].is_finite() { g[i] } else { 0.0 };
            self.m[i] = b1 * self.m[i] + (1.0 - b1) * gi;
            self.v[i] = b2 * self.v[i] + (1.0 - b2) * gi * gi;
            let mh = self.m[i] / c1;
            let vh = self.v[i] / c2;
            x[i] -= scale * self.lr[i] * mh / (vh.sqrt() + self.eps);
        }
    }
}

/// Cosine learning-rate schedule from 1 down to `floor` over `total` steps.
pub fn cosine_schedule(step: u64, total: u64, floor: f64) -> f64 {
    let t = (step as f64 / total.max(1) as f64).min(1.0);
    floor + (1.0 - floor) * 0.5 * (1.0 + (std::f64::consts::PI * t).cos())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adam_minimizes_a_quadratic_and_first_step_is_lr() {
        // The first Adam step moves each coordinate by lr against the gradient's sign.
        let mut a = Adam::new(vec![0.1, 0.01]);
        let mut x = [1.0, -2.0];
        a.step(&mut x, &[2.0, -4.0], 1.0);
        assert!((x[0] - 0.9).abs() < 1e-9 && (x[1] + 1.99).abs() < 1e-9);
        let mut x = [3.0, -2.0];
        let mut a = Adam::new(vec![0.05, 0.05]);
        for k in 0..2000 {
            let g = [2.0 * (x[0] - 1.0), 8.0 * (x[1] + 0.5)];
            a.step(&mut x, &g, cosine_schedule(k, 2000, 0.01));
        }
        assert!(
            (x[0] - 1.0).abs() < 1e-3 && (x[1] + 0.5).abs() < 1e-3,
            "{x:?}"
        );
    }
}
