//! Design optimization: exact gradients by forward-mode dual numbers through the same tracer,
//! the paper's losses, and (in [`adam`]) the optimizer.

pub mod adam;
mod run;
pub mod train;

use crate::error::{Error, Result};
use crate::lens::{Adjustments, Lens, Param, System};
use crate::math::Vec3;
use crate::real::{Dual, Real};
use crate::trace::{trace_serial, Field, Pupil, RayBatch, RaySet, TraceOptions, Traceable};

/// Something to minimize, evaluable in any traceable number type so that the same code gives the
/// value (`f64`) and exact derivatives (`Dual<f64, N>`).
pub trait Objective: Sync {
    /// The objective for the compiled system `sys`.
    fn eval<S: Traceable>(&self, sys: &System<S>) -> S;
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
    obj.eval(&sys)
}

/// Value and gradient of `obj` with respect to `vars`, exactly, in ceil(P / N) forward passes
/// with `Dual<f64, N>`.
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
    for &p in vars {
        param_value(lens, p)?;
    }
    let mut grad = vec![0.0; vars.len()];
    let mut val = None;
    for (b, block) in vars.chunks(N).enumerate() {
        let lift = |p: Param, v: Dual<f64, N>| match block.iter().position(|&q| q == p) {
            Some(k) => Dual::var(v.re, k),
            None => v,
        };
        let sys: System<Dual<f64, N>> = System::compile(lens, adj, &lift);
        let f = obj.eval(&sys);
        for k in 0..block.len() {
            grad[b * N + k] = f.eps[k];
        }
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

/// Rays of the bundles an objective traces (fields × wavelengths), generated once in f64 from the
/// nominal lens and aimed at its paraxial entrance pupil.
#[derive(Clone, Debug)]
pub struct Bundles {
    /// (field index, wavelength nm, rays).
    pub sets: Vec<(usize, f64, RaySet)>,
    /// Trace options.
    pub trace: TraceOptions,
}

impl Bundles {
    /// Rays for every field and wavelength.
    ///
    /// # Errors
    /// Paraxial and ray-generation errors.
    pub fn new(
        lens: &Lens,
        fields: &[Field],
        wavelengths_nm: &[f64],
        pupil: &Pupil,
        trace: TraceOptions,
    ) -> Result<Bundles> {
        let para = lens.paraxial(
            wavelengths_nm
                .first()
                .copied()
                .unwrap_or(lens.primary_wavelength_nm),
        )?;
        let mut sets = Vec::new();
        for (f, field) in fields.iter().enumerate() {
            for &wl in wavelengths_nm {
                sets.push((f, wl, RaySet::generate(lens, &para, *field, pupil, wl)?));
            }
        }
        Ok(Bundles { sets, trace })
    }

    /// Traces bundle `k` in `S` and returns, for each ray that arrives, its sensor-plane position
    /// and slopes `[x, y, dx/dz, dy/dz]` in the sensor frame (what a refocus moves).
    pub fn sensor_rays<S: Traceable>(&self, sys: &System<S>, k: usize) -> Vec<[S; 4]> {
        self.arrived(sys, k, |o, d| {
            let p = sys.image.point_to_local(o);
            let d = sys.image.rotation.apply_t(d);
            [p.x, p.y, d.x / d.z, d.y / d.z]
        })
    }

    /// Traces bundle `k` in `S` and returns the sensor-plane positions of the rays that arrive.
    pub fn sensor_points<S: Traceable>(&self, sys: &System<S>, k: usize) -> Vec<[S; 2]> {
        self.arrived(sys, k, |o, _| {
            let p = sys.image.point_to_local(o);
            [p.x, p.y]
        })
    }

    /// Traces bundle `k` and maps `f(position, direction)` (global frame) over the rays that
    /// arrive.
    fn arrived<S: Traceable, T>(
        &self,
        sys: &System<S>,
        k: usize,
        f: impl Fn(Vec3<S>, Vec3<S>) -> T,
    ) -> Vec<T> {
        let (_, wl, set) = &self.sets[k];
        let mut b: RayBatch<S> = set.batch();
        trace_serial(sys, *wl, &mut b, self.trace);
        b.iter()
            .filter(|r| r.status.is_alive())
            .map(|r| f(r.o, r.d))
            .collect()
    }
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
    let mut acc = S::cst(0.0);
    for p in pts {
        let d2 = (p[0] - cx) * (p[0] - cx) + (p[1] - cy) * (p[1] - cy);
        acc += match measure {
            SpotMeasure::Mean => d2.sqrt(),
            SpotMeasure::Rms => d2,
        };
    }
    match measure {
        SpotMeasure::Mean => acc * inv,
        SpotMeasure::Rms => (acc * inv).sqrt(),
    }
}

/// The paper's spot loss: the sum over fields and wavelengths of the spot size of each bundle, mm.
#[derive(Clone, Debug)]
pub struct SpotLoss {
    /// The bundles.
    pub bundles: Bundles,
    /// Mean distance (the paper) or RMS.
    pub measure: SpotMeasure,
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

impl Objective for SpotLoss {
    fn eval<S: Traceable>(&self, sys: &System<S>) -> S {
        let mut total = S::cst(0.0);
        for k in 0..self.bundles.sets.len() {
            total += bundle_spot(&self.bundles.sensor_points(sys, k), self.measure);
        }
        total
    }
}

/// The paper's PSF-similarity loss: 1 − mean over PSFs of the similarity between each PSF and
/// its ideal PSF (a constant, e.g. from the nominal lens at the same field and wavelength).
#[derive(Clone, Debug)]
pub struct PsfLoss {
    /// Rays of each PSF.
    pub rays: crate::psf::PsfRays,
    /// The ideal PSF of each ray set (constant).
    pub ideal: Vec<Vec<f64>>,
    /// PSF settings.
    pub opts: crate::psf::PsfOptions,
    /// Trace options.
    pub trace: TraceOptions,
}

impl PsfLoss {
    /// A PSF loss whose ideal PSFs are those of `ideal_sys` (typically the nominal design).
    pub fn new(
        rays: crate::psf::PsfRays,
        ideal_sys: &System<f64>,
        opts: crate::psf::PsfOptions,
        trace: TraceOptions,
    ) -> PsfLoss {
        let ideal = (0..rays.sets.len())
            .map(|k| crate::psf::psf_of(ideal_sys, &rays, k, &opts, trace).0)
            .collect();
        PsfLoss {
            rays,
            ideal,
            opts,
            trace,
        }
    }
}

impl Objective for PsfLoss {
    fn eval<S: Traceable>(&self, sys: &System<S>) -> S {
        let mut sim = S::cst(0.0);
        for k in 0..self.rays.sets.len() {
            let (psf, _) = crate::psf::psf_of(sys, &self.rays, k, &self.opts, self.trace);
            sim += crate::psf::psf_similarity(&self.ideal[k], &psf, self.opts.ks);
        }
        S::cst(1.0) - sim * S::cst(1.0 / self.rays.sets.len().max(1) as f64)
    }
}
