//! Design optimization: exact gradients by forward-mode dual numbers through the same tracer,
//! the paper's losses, and (in [`adam`]) the optimizer.

pub mod adam;
mod run;
pub mod train;
mod wave;

pub use wave::{DiffractionPsfs, MtfLoss, WavefrontLoss, LOST_WAVEFRONT_PENALTY_WAVES};

use crate::analysis::SpotMoments;
use crate::error::{Error, Result};
use crate::lens::{Adjustments, Lens, Param, System};
use crate::real::sqrt_or_zero;
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

pub use crate::real::GRAD_WIDTH;

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
        Param::Zernike(i, j) => *s(i)?.zernike.get(j).ok_or_else(|| {
            Error::argument(format!(
                "{p:?}: surface {i} has no Zernike term {} (Z{})",
                j,
                j + 1
            ))
        })?,
        Param::Phase(i, j) => *s(i)?
            .phase
            .as_ref()
            .and_then(|p| p.coefficients.get(j))
            .ok_or_else(|| {
                Error::argument(format!(
                    "{p:?}: surface {i} has no diffractive phase coefficient {j} (A_{})",
                    j + 1
                ))
            })?,
        Param::Gap(i) => s(i)?.d_next_mm,
        Param::Gradient(i, j) => match &s(i)?.material {
            crate::lens::Material::Gradient(g) => match j {
                0 => g.n0,
                1..=6 => g.radial[j - 1],
                7..=9 => g.axial[j - 7],
                _ => {
                    return Err(Error::argument(format!(
                        "{p:?}: a gradient-index medium has coefficients 0 to 9"
                    )))
                }
            },
            _ => {
                return Err(Error::argument(format!(
                    "{p:?}: the medium after surface {i} is not a gradient-index medium"
                )))
            }
        },
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
        Param::Zernike(i, j) => lens.surfaces[i].zernike[j] = v,
        Param::Phase(i, j) => {
            if let Some(p) = &mut lens.surfaces[i].phase {
                p.coefficients[j] = v;
            }
        }
        Param::Gap(i) => lens.surfaces[i].d_next_mm = v,
        Param::Gradient(i, j) => {
            if let crate::lens::Material::Gradient(g) = &mut lens.surfaces[i].material {
                match j {
                    0 => g.n0 = v,
                    1..=6 => g.radial[j - 1] = v,
                    _ => g.axial[j - 7] = v,
                }
            }
        }
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

/// Spot size of a point set (see [`SpotMeasure`]), mm; zero for an empty set. Both measures are
/// about the centroid of [`SpotMoments`] (the mean distance computes the centroid alone), the RMS
/// is its [`SpotMoments::rms`].
pub fn spot_size<S: Real>(pts: &[[S; 2]], measure: SpotMeasure) -> S {
    if pts.is_empty() {
        return S::cst(0.0);
    }
    match measure {
        SpotMeasure::Rms => SpotMoments::of_points(pts).map_or(S::cst(0.0), |m| m.rms()),
        SpotMeasure::Mean => {
            // A ray exactly on the centroid contributes 0 with derivative 0 (see `sqrt_or_zero`).
            let [cx, cy] = SpotMoments::centroid_of(pts).unwrap_or([S::cst(0.0); 2]);
            let mut acc = S::cst(0.0);
            for p in pts {
                acc += sqrt_or_zero((p[0] - cx) * (p[0] - cx) + (p[1] - cy) * (p[1] - cy));
            }
            acc * S::cst(1.0 / pts.len() as f64)
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
}
