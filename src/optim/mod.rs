//! Design optimization: exact gradients by forward-mode dual numbers through the same tracer,
//! the paper's losses, and (in [`adam`]) the optimizer.

pub mod adam;
mod run;
pub mod train;

use crate::error::{Error, Result};
use crate::lens::{Adjustments, Lens, Param, System};
use crate::real::{Dual, Real};
use crate::trace::{Bundles, TraceOptions, Traceable};

/// Something to minimize, evaluable in any traceable number type so that the same code gives the
/// value (`f64`) and exact derivatives (`Dual<f64, N>`).
pub trait Objective: Sync {
    /// The objective for the compiled system `sys`. `lift` is how the design parameters entered
    /// it (the identity for a value; seeded dual numbers for a gradient): an objective whose rays
    /// or reference are launched from the design ([`Bundles`]) launches
    /// them through it again, so that its derivatives include the launch's.
    fn eval<S: Traceable>(&self, sys: &System<S>, lift: &dyn Fn(Param, S) -> S) -> S;
}

/// Width of the dual numbers used for gradients (derivatives per pass).
pub const GRAD_WIDTH: usize = 8;

/// Current value of a design parameter in `lens`.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] if the parameter names a surface that does not exist.
pub fn param_value(lens: &Lens, p: Param) -> Result<f64> {
    let s = |i: usize| {
        lens.surfaces
            .get(i)
            .ok_or_else(|| Error::argument(format!("{p:?}: surface {i} does not exist")))
    };
    Ok(match p {
        Param::Curvature(i) => s(i)?.c,
        Param::Conic(i) => s(i)?.k,
        Param::Asphere(i, j) => *s(i)?
            .asph
            .get(j)
            .ok_or_else(|| Error::argument(format!("{p:?}: asphere term {j} does not exist")))?,
        Param::Gap(i) => s(i)?.d_next_mm,
        Param::GlassNd(i) | Param::GlassVd(i) => match s(i)?.material {
            crate::lens::Material::Model { nd, vd } => {
                if matches!(p, Param::GlassNd(_)) {
                    nd
                } else {
                    vd
                }
            }
            _ => {
                return Err(Error::argument(format!(
                    "{p:?}: the material after surface {i} is not a model glass (n_d/V_d)"
                )))
            }
        },
    })
}

/// Sets a design parameter of `lens`.
///
/// # Errors
/// As [`param_value`].
pub fn set_param(lens: &mut Lens, p: Param, v: f64) -> Result<()> {
    param_value(lens, p)?;
    match p {
        Param::Curvature(i) => lens.surfaces[i].c = v,
        Param::Conic(i) => lens.surfaces[i].k = v,
        Param::Asphere(i, j) => lens.surfaces[i].asph[j] = v,
        Param::Gap(i) => lens.surfaces[i].d_next_mm = v,
        Param::GlassNd(i) | Param::GlassVd(i) => {
            if let crate::lens::Material::Model { nd, vd } = &mut lens.surfaces[i].material {
                if matches!(p, Param::GlassNd(_)) {
                    *nd = v;
                } else {
                    *vd = v;
                }
            }
        }
    }
    Ok(())
}

/// Value of `obj` for `lens` with adjustments `adj`.
pub fn value<O: Objective>(obj: &O, lens: &Lens, adj: &Adjustments) -> f64 {
    let sys: System<f64> = System::compile(lens, adj, &|_, v| v);
    obj.eval(&sys, &|_, v| v)
}

/// Value and gradient of `obj` with respect to `vars`, exactly, in ceil(P / N) forward passes
/// with `Dual<f64, N>`.
///
/// The derivative is that of the objective as it is evaluated when the design moves: `lens`
/// (with `adj`) is traced with each variable seeded, and the rays and references an objective
/// launches from the design ([`Bundles`]) move with the same
/// variables (the paraxial entrance pupil, the field angle of a fraction of the field, the
/// design's own PSFs); only aimed rays keep their launch (see
/// [`crate::trace::RaySet::launched_batch`]).
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for a parameter that does not exist.
pub fn gradient<O: Objective, const N: usize>(
    obj: &O,
    lens: &Lens,
    adj: &Adjustments,
    vars: &[Param],
) -> Result<(f64, Vec<f64>)>
where
    Dual<f64, N>: Traceable,
{
    gradient_slots::<O, N>(obj, lens, adj, vars, None)
}

/// As [`gradient`], with one more derivative last: with respect to `unit`, a parameter moved in
/// the traced system (`lens` with `adj`) only, not in the design the rays are launched from (a
/// fabricated unit's own refocus, say, seeded as the unit's image distance).
///
/// # Errors
/// As [`gradient`].
pub fn gradient_with_unit<O: Objective, const N: usize>(
    obj: &O,
    lens: &Lens,
    adj: &Adjustments,
    vars: &[Param],
    unit: Param,
) -> Result<(f64, Vec<f64>)>
where
    Dual<f64, N>: Traceable,
{
    gradient_slots::<O, N>(obj, lens, adj, vars, Some(unit))
}

fn gradient_slots<O: Objective, const N: usize>(
    obj: &O,
    lens: &Lens,
    adj: &Adjustments,
    vars: &[Param],
    unit: Option<Param>,
) -> Result<(f64, Vec<f64>)>
where
    Dual<f64, N>: Traceable,
{
    for &p in vars.iter().chain(&unit) {
        param_value(lens, p)?;
    }
    let slots = vars.len() + usize::from(unit.is_some());
    let mut grad = vec![0.0; slots];
    let mut val = None;
    for start in (0..slots).step_by(N) {
        let block = start..(start + N).min(slots);
        // Slot k differentiates vars[k] (in the system and the design alike), the last slot
        // `unit` (in the system only).
        let seed = |p: Param, v: Dual<f64, N>, system: bool| {
            let mut d = v;
            for k in block.clone() {
                let q = match vars.get(k) {
                    Some(&q) => q,
                    None if system => unit.unwrap_or(p),
                    None => continue,
                };
                if q == p {
                    d.eps[k - start] = 1.0;
                }
            }
            d
        };
        let sys: System<Dual<f64, N>> = System::compile(lens, adj, &|p, v| seed(p, v, true));
        let f = obj.eval(&sys, &|p, v| seed(p, v, false));
        grad[block.clone()].copy_from_slice(&f.eps[..block.len()]);
        val.get_or_insert(f.re);
    }
    let v = match val {
        Some(v) => v,
        None => value(obj, lens, adj),
    };
    Ok((v, grad))
}

/// How the spot size of one bundle is measured.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SpotMeasure {
    /// The paper's: mean distance of the ray positions from their centroid, mean |P_i - P̄|.
    Mean,
    /// RMS radius about the centroid, sqrt(mean |P_i - P̄|²).
    Rms,
}

/// Spot size of a point set (see [`SpotMeasure`]), mm; zero for an empty set.
pub fn spot_size<S: Real>(pts: &[[S; 2]], measure: SpotMeasure) -> S {
    if pts.is_empty() {
        return S::cst(0.0);
    }
    let inv = S::cst(1.0 / pts.len() as f64);
    let (mut cx, mut cy) = (S::cst(0.0), S::cst(0.0));
    for p in pts {
        cx += p[0];
        cy += p[1];
    }
    cx *= inv;
    cy *= inv;
    // A distance of exactly 0 (a ray on the centroid, or a perfect point image) is the tip of
    // the cone |x|: its derivative is not defined and sqrt's chain rule would give 0 · ∞ = NaN.
    // It contributes 0 with derivative 0 there, a subgradient of the loss (the one that makes
    // a perfect focus a stationary point).
    let root = |x: S| {
        if x.value() == 0.0 {
            S::cst(0.0)
        } else {
            x.sqrt()
        }
    };
    let mut acc = S::cst(0.0);
    for p in pts {
        let d2 = (p[0] - cx) * (p[0] - cx) + (p[1] - cy) * (p[1] - cy);
        acc += match measure {
            SpotMeasure::Mean => root(d2),
            SpotMeasure::Rms => d2,
        };
    }
    match measure {
        SpotMeasure::Mean => acc * inv,
        SpotMeasure::Rms => root(acc * inv),
    }
}

/// Focus moments of a set of rays at the sensor: with the rays' positions `p` and slopes
/// `s = (dx/dz, dy/dz)` in the sensor frame, each taken about its mean,
/// `a = mean |p|²`, `b = mean p·s` and `c = mean |s|²`, so that the mean-square spot radius about
/// the centroid after moving the sensor by `δ` along its normal is `a + 2 b δ + c δ²`.
///
/// One accumulator for every refocus: the Monte Carlo's focus compensator (in `f64`) and the
/// differentiated refocus of deep-optics training (in dual numbers) both use it, so they refocus
/// identically.
///
/// # Examples
/// ```
/// use tolray::optim::FocusMoments;
/// // Two rays crossing the axis 1 mm behind the sensor: [x, y, dx/dz, dy/dz].
/// let rays: [[f64; 4]; 2] = [[0.1, 0.0, -0.1, 0.0], [-0.1, 0.0, 0.1, 0.0]];
/// let m = FocusMoments::of(&rays).unwrap();
/// let d = FocusMoments::best_focus(&[m]);
/// assert!((d - 1.0).abs() < 1e-12 && m.rms_at(d).abs() < 1e-12);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FocusMoments<S> {
    /// Mean square radius about the centroid at the sensor, mm².
    pub a: S,
    /// Mean product of the centred positions and slopes, mm.
    pub b: S,
    /// Mean square of the centred slopes.
    pub c: S,
}

impl<S: Real> FocusMoments<S> {
    /// The moments of `rays` (`[x, y, dx/dz, dy/dz]` in the sensor frame); `None` for no ray.
    pub fn of(rays: &[[S; 4]]) -> Option<FocusMoments<S>> {
        if rays.is_empty() {
            return None;
        }
        let inv = S::cst(1.0 / rays.len() as f64);
        let mut m = [S::cst(0.0); 4];
        for q in rays {
            for k in 0..4 {
                m[k] += q[k] * inv;
            }
        }
        let (mut a, mut b, mut c) = (S::cst(0.0), S::cst(0.0), S::cst(0.0));
        for q in rays {
            let (px, py, sx, sy) = (q[0] - m[0], q[1] - m[1], q[2] - m[2], q[3] - m[3]);
            a += (px * px + py * py) * inv;
            b += (px * sx + py * sy) * inv;
            c += (sx * sx + sy * sy) * inv;
        }
        Some(FocusMoments { a, b, c })
    }

    /// RMS spot radius about the centroid with the sensor moved by `delta` mm, mm.
    pub fn rms_at(&self, delta: S) -> S {
        let ms = self.a + S::cst(2.0) * self.b * delta + self.c * delta * delta;
        if ms.value() > 0.0 {
            ms.sqrt()
        } else {
            S::cst(0.0)
        }
    }

    /// The sensor shift (mm, along its normal) that minimizes the sum of the mean-square radii of
    /// all `moments`: `−Σb / Σc`, and 0 when `Σc` is 0 (parallel rays: no focus to find).
    pub fn best_focus(moments: &[FocusMoments<S>]) -> S {
        let (mut sb, mut sc) = (S::cst(0.0), S::cst(0.0));
        for m in moments {
            sb += m.b;
            sc += m.c;
        }
        if sc.value() > 0.0 {
            -(sb / sc)
        } else {
            S::cst(0.0)
        }
    }
}

/// The paper's spot loss: the sum over fields and wavelengths of the spot size of each bundle, mm.
#[derive(Clone, Debug)]
pub struct SpotLoss {
    /// The bundles.
    pub bundles: Bundles,
    /// Mean distance (the paper) or RMS.
    pub measure: SpotMeasure,
    /// Trace options.
    pub trace: TraceOptions,
}

/// Spot-loss value of a bundle none of whose rays reaches the image, mm: far larger than any spot
/// a design is trained to, so that losing a whole bundle is never rewarded (an empty bundle has
/// no spot size, and counting it as 0 made the loss prefer lenses that lose their rays).
pub const EMPTY_BUNDLE_PENALTY_MM: f64 = 10.0;

/// The spot term of one bundle in a loss: its spot size, or [`EMPTY_BUNDLE_PENALTY_MM`] when no
/// ray arrives.
pub fn bundle_spot<S: Real>(pts: &[[S; 2]], measure: SpotMeasure) -> S {
    if pts.is_empty() {
        S::cst(EMPTY_BUNDLE_PENALTY_MM)
    } else {
        spot_size(pts, measure)
    }
}

/// The sum over `bundles` of [`bundle_spot`], mm, with the rays launched through `lift` (the
/// spot term of every loss: [`SpotLoss`], training and deep optics).
pub fn spot_sum<S: Traceable>(
    bundles: &Bundles,
    sys: &System<S>,
    lift: &dyn Fn(Param, S) -> S,
    measure: SpotMeasure,
    trace: TraceOptions,
) -> S {
    let optics = bundles.optics(lift);
    let mut total = S::cst(0.0);
    for k in 0..bundles.len() {
        let pts = bundles.launched_sensor_points(sys, optics.as_ref(), k, trace);
        total += bundle_spot(&pts, measure);
    }
    total
}

impl Objective for SpotLoss {
    fn eval<S: Traceable>(&self, sys: &System<S>, lift: &dyn Fn(Param, S) -> S) -> S {
        spot_sum(&self.bundles, sys, lift, self.measure, self.trace)
    }
}

/// The paper's PSF-similarity loss: 1 − mean over PSFs of the similarity between each PSF and
/// the design's own PSF at the same field and wavelength (the lens the rays were launched from,
/// without adjustments; it moves with the design in gradients).
#[derive(Clone, Debug)]
pub struct PsfLoss {
    /// Rays of each PSF, launched from the design.
    pub rays: Bundles,
    /// PSF settings.
    pub opts: crate::psf::PsfOptions,
    /// Trace options.
    pub trace: TraceOptions,
}

impl Objective for PsfLoss {
    fn eval<S: Traceable>(&self, sys: &System<S>, lift: &dyn Fn(Param, S) -> S) -> S {
        let optics = self.rays.launch.optics(lift);
        let design = self.rays.launch.design(lift);
        let mut sim = S::cst(0.0);
        for k in 0..self.rays.sets.len() {
            let at = |s: &System<S>| {
                crate::psf::psf_of_launched(
                    s,
                    &self.rays,
                    k,
                    optics.as_ref(),
                    &self.opts,
                    self.trace,
                )
                .0
            };
            sim += crate::psf::psf_similarity_of(&at(&design), &at(sys), self.opts.ks);
        }
        S::cst(1.0) - sim * S::cst(1.0 / self.rays.sets.len().max(1) as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A perfect point image, or a ray exactly on the centroid, gives finite (zero-slope)
    /// derivatives for both measures, not NaN (header review: the Mean loss had none for a
    /// perfect point spot); elsewhere the dual derivative equals central differences.
    #[test]
    fn spot_size_has_a_derivative_at_a_perfect_focus() {
        type D = crate::real::Dual<f64, 1>;
        for m in [SpotMeasure::Mean, SpotMeasure::Rms] {
            let pts = [[D::var(0.5, 0), D::constant(0.2)]; 4];
            let s = spot_size(&pts, m);
            assert_eq!(s.value(), 0.0);
            assert_eq!(s.eps[0], 0.0, "{m:?}");
            // Three rays symmetric about the centroid, one on it (distance 0).
            let at = |x: D| {
                let pts = [
                    [D::constant(-1.0), D::constant(0.0)],
                    [D::constant(1.0), D::constant(0.0)],
                    [D::constant(0.0), x],
                    [D::constant(0.0), -x],
                    [D::constant(0.0), D::constant(0.0)],
                ];
                spot_size(&pts, m)
            };
            let g = at(D::var(0.3, 0));
            let h = 1e-6;
            let fd =
                (at(D::constant(0.3 + h)).value() - at(D::constant(0.3 - h)).value()) / (2.0 * h);
            assert!(
                g.eps[0].is_finite() && (g.eps[0] - fd).abs() < 1e-8,
                "{m:?}: {} vs {fd}",
                g.eps[0]
            );
        }
    }

    /// RMS radius about the centroid of rays propagated by `delta` along z.
    fn direct_rms(rays: &[[f64; 4]], delta: f64) -> f64 {
        let pts: Vec<[f64; 2]> = rays
            .iter()
            .map(|q| [q[0] + q[2] * delta, q[1] + q[3] * delta])
            .collect();
        spot_size(&pts, SpotMeasure::Rms)
    }

    #[test]
    fn focus_moments_match_propagated_rays_and_find_the_minimum() {
        // A deterministic, astigmatic and decentred fan.
        let rays: Vec<[f64; 4]> = (0..97)
            .map(|i| {
                let t = i as f64 * 0.37;
                let (u, v) = (t.cos() * (1.0 + 0.1 * t.sin()), t.sin() * 0.8);
                [
                    0.3 + 0.05 * u,
                    -0.2 + 0.04 * v,
                    -0.021 * u,
                    -0.017 * v + 0.001,
                ]
            })
            .collect();
        let m = FocusMoments::of(&rays).unwrap();
        for d in [-3.0, -0.5, 0.0, 1.0, 2.5] {
            let (a, b) = (m.rms_at(d), direct_rms(&rays, d));
            assert!((a - b).abs() < 1e-13, "delta {d}: {a} vs {b}");
        }
        let best = FocusMoments::best_focus(&[m]);
        let at = direct_rms(&rays, best);
        for e in [-1e-3, 1e-3] {
            assert!(direct_rms(&rays, best + e) > at, "not a minimum at {best}");
        }
        // Two bundles: the best focus minimizes the sum of their mean squares.
        let other: Vec<[f64; 4]> = rays
            .iter()
            .map(|q| [q[0], q[1], q[2] * 0.5, q[3]])
            .collect();
        let m2 = FocusMoments::of(&other).unwrap();
        let both = FocusMoments::best_focus(&[m, m2]);
        let sum = |d: f64| direct_rms(&rays, d).powi(2) + direct_rms(&other, d).powi(2);
        assert!(sum(both + 1e-3) > sum(both) && sum(both - 1e-3) > sum(both));
        // No rays: no moments; parallel rays: no focus to find.
        assert!(FocusMoments::<f64>::of(&[]).is_none());
        let flat = FocusMoments::of(&[[0.1, 0.0, 0.0, 0.0], [0.2, 0.0, 0.0, 0.0]]).unwrap();
        assert_eq!(FocusMoments::best_focus(&[flat]), 0.0);
    }
}
