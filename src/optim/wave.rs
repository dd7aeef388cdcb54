//! The RMS wavefront error as a differentiable loss: the OPD of [`crate::wave::wavefront`]
//! computed in any number type, so that dual numbers carry its exact gradient (the rays'
//! launch, the reference sphere's centre on the chief ray and the paraxial exit pupil it passes
//! through all move with the design), and the diffraction MTF at one frequency likewise
//! ([`MtfLoss`]).

use super::Objective;
use crate::error::{Error, Result};
use crate::lens::paraxial::{launch_optics, LaunchOptics};
use crate::lens::{Lens, Param, System};
use crate::math::Vec3;
use crate::tolerance::MtfDirection;
use crate::trace::rays::Beam;
use crate::trace::{trace_serial, Bundles, Field, LaunchSource, RayBatch, TraceOptions, Traceable};
use crate::wave::opd::{plane_fit, pupil_from_image, rms_about_plane, sphere_opd};
use crate::wave::psf::direction_map;
use crate::wave::{mtf, wavefront, Reference, Sampling, WaveOptions};

/// The wavefront term of a bundle whose chief ray is lost or through which fewer than three
/// rays pass, waves: far above any wavefront a design is trained to, so that losing a bundle is
/// never rewarded (as [`super::EMPTY_BUNDLE_PENALTY_MM`] for spots).
pub const LOST_WAVEFRONT_PENALTY_WAVES: f64 = 100.0;

/// The mean over fields and wavelengths of the RMS wavefront error to centroid (piston and tilt
/// removed over the entrance pupil; [`crate::wave::Wavefront::rms_to_centroid_waves`]), waves,
/// with the reference sphere centred on the chief ray, over a pupil quadrature.
///
/// Its value for an unperturbed lens is the wavefront analysis' to rounding, and its gradient
/// ([`super::gradient`]) is that of the loss as evaluated: the rays are launched again through
/// the design's paraxial entrance pupil and the reference sphere passes through the design's
/// paraxial exit pupil, both moving with the design variables.
///
/// # Examples
/// ```
/// use tolray::lens::{Adjustments, Param};
/// use tolray::optim::{gradient, value, WavefrontLoss};
/// use tolray::trace::{Field, TraceOptions};
/// use tolray::wave::{wavefront, Sampling, WaveOptions};
/// use tolray::Lens;
/// let lens = Lens::load("cooke-triplet")?;
/// let fields = [Field::fraction(0.7)];
/// let loss = WavefrontLoss::new(&lens, &fields, &[587.5618], Sampling::default(), TraceOptions::default())?;
/// let adj = Adjustments::none(lens.surfaces.len());
/// let w = wavefront(&lens, &lens.compile(), fields[0], 587.5618, &WaveOptions::default())?;
/// assert!((value(&loss, &lens, &adj) - w.rms_to_centroid_waves()?).abs() < 1e-9);
/// let (_, g) = gradient::<_, 2>(&loss, &lens, &adj, &[Param::Curvature(0), Param::Gap(5)])?;
/// assert!(g.iter().all(|d| d.is_finite() && *d != 0.0));
/// # Ok::<(), tolray::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct WavefrontLoss {
    /// The rays, one bundle a field and wavelength, through [`WavefrontLoss::points`].
    pub bundles: Bundles,
    /// The normalised entrance-pupil points (unit disk) the rays are launched through.
    pub points: Vec<[f64; 2]>,
    /// The quadrature weight of each point (normalised over the rays that get through).
    pub weights: Vec<f64>,
    /// Trace options.
    pub trace: TraceOptions,
}

impl WavefrontLoss {
    /// The loss of `lens` over `fields` × `wavelengths_nm` (field-major) through the pupil
    /// `sampling`, launched as [`crate::wave::wavefront`] launches its rays (no aiming).
    ///
    /// # Errors
    /// A sampling [`Sampling::check`] refuses; paraxial and ray-generation errors.
    pub fn new(
        lens: &Lens,
        fields: &[Field],
        wavelengths_nm: &[f64],
        sampling: Sampling,
        trace: TraceOptions,
    ) -> Result<WavefrontLoss> {
        sampling.check()?;
        let (points, weights) = sampling.points();
        let bundles = Bundles::at_points(lens, fields, wavelengths_nm, &points, false)?;
        Ok(WavefrontLoss {
            bundles,
            points,
            weights,
            trace,
        })
    }

    /// The RMS wavefront error to centroid of bundle `k`, waves, or
    /// [`LOST_WAVEFRONT_PENALTY_WAVES`].
    fn bundle<S: Traceable>(
        &self,
        sys: &System<S>,
        k: usize,
        optics: Option<&crate::lens::paraxial::LaunchOptics<S>>,
        to_pupil: S,
    ) -> S {
        let lost = S::cst(LOST_WAVEFRONT_PENALTY_WAVES);
        let wl = self.bundles.sets[k].wavelength_nm;
        let mut batch = self.bundles.batch(k, optics, true);
        let launch: Vec<_> = batch.iter().map(|r| (r.o, r.d)).collect();
        trace_serial(sys, wl, &mut batch, self.trace);
        let idx = sys.indices(wl);
        let (n0, n_img) = (idx[0], idx[idx.len() - 1].abs());
        let lens = &self.bundles.launch.lens;
        let Ok(s) = sphere_opd(
            lens.object,
            &launch,
            &batch,
            n0,
            n_img,
            &sys.image,
            to_pupil,
            Reference::Chief,
            wl,
        ) else {
            return lost;
        };
        if s.rays.len() < 3 {
            return lost;
        }
        let pts: Vec<[f64; 2]> = s.rays.iter().map(|r| self.points[r.0]).collect();
        let total: f64 = s.rays.iter().map(|r| self.weights[r.0]).sum();
        let w: Vec<f64> = s.rays.iter().map(|r| self.weights[r.0] / total).collect();
        let opd: Vec<S> = s.rays.iter().map(|r| r.1).collect();
        rms_about_plane(&pts, &w, &opd).unwrap_or(lost)
    }
}

impl Objective for WavefrontLoss {
    fn eval<S: Traceable>(&self, sys: &System<S>, lift: &dyn Fn(Param, S) -> S) -> S {
        let optics = self.bundles.optics(lift);
        let launch = &self.bundles.launch;
        let to_pupil = pupil_from_image(&launch.lens, launch.stop, lift);
        let mut total = S::cst(0.0);
        for k in 0..self.bundles.len() {
            total += self.bundle(sys, k, optics.as_ref(), to_pupil);
        }
        total * S::cst(1.0 / self.bundles.len().max(1) as f64)
    }
}

/// The diffraction MTF at one frequency as a differentiable loss: the mean over fields and
/// wavelengths of `1 − MTF` (tangential, sagittal or their mean), the MTF computed as
/// [`crate::wave::mtf::direct_mtf`] computes it (the pupil's autocorrelation summed over rays
/// traced exactly through the pupil and through the pupil shifted by `δ = λ ν u / a`), in any
/// number type.
///
/// Everything the evaluated number depends on moves with the design variables, so that the
/// gradient ([`super::gradient`]) is that of the loss as evaluated: the rays are launched
/// through the design's paraxial entrance pupil, the reference sphere passes through its
/// paraxial exit pupil, the slopes `a` (the image-space direction cosines' least-squares plane
/// over the pupil) and the tangential direction (toward the chief ray's image point) are
/// computed from the traced rays, and the sheared rays are launched through the shifted pupil
/// points `p − δ` in the same number type. Which sheared points fall inside the pupil (and which
/// rays an aperture stops) is decided on the values: the loss is piecewise smooth.
///
/// A bundle whose chief ray is lost, or whose rays cannot determine the slopes, counts as MTF 0
/// (loss 1), never as a gain.
///
/// # Examples
/// ```
/// use tolray::lens::{Adjustments, Param};
/// use tolray::optim::{gradient, value, MtfLoss};
/// use tolray::tolerance::MtfDirection;
/// use tolray::trace::{Field, TraceOptions};
/// use tolray::wave::{mtf::direct_mtf, Sampling, WaveOptions};
/// use tolray::Lens;
/// let lens = Lens::load("cooke-triplet")?;
/// let fields = [Field::fraction(0.7)];
/// let loss = MtfLoss::new(&lens, &fields, &[587.5618], 30.0, MtfDirection::Tangential,
///                         Sampling::Grid(16), TraceOptions::default())?;
/// let opts = WaveOptions { sampling: Sampling::Grid(16), ..WaveOptions::default() };
/// let m = direct_mtf(&lens, &lens.compile(), fields[0], 587.5618, &opts, &[30.0])?;
/// let adj = Adjustments::none(lens.surfaces.len());
/// assert!((value(&loss, &lens, &adj) - (1.0 - m.tangential[0])).abs() < 1e-9);
/// let (_, g) = gradient::<_, 2>(&loss, &lens, &adj, &[Param::Curvature(0), Param::Gap(5)])?;
/// assert!(g.iter().all(|d| d.is_finite() && *d != 0.0));
/// # Ok::<(), tolray::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct MtfLoss {
    /// The design the rays are launched from.
    pub launch: LaunchSource,
    /// Each field as given (its vignetting factors are looked up by it) and as launched (a
    /// real image height resolved to an angle, held: the solve is not differentiated).
    pub fields: Vec<(Field, Field)>,
    /// Wavelengths, nm.
    pub wavelengths_nm: Vec<f64>,
    /// Frequency, cycles/mm.
    pub freq_lpmm: f64,
    /// Tangential, sagittal or their mean.
    pub direction: MtfDirection,
    /// The normalised entrance-pupil points (unit disk) of the unsheared pupil.
    pub points: Vec<[f64; 2]>,
    /// The weight of each point.
    pub weights: Vec<f64>,
    /// Trace options.
    pub trace: TraceOptions,
}

impl MtfLoss {
    /// The loss of `lens` at `freq_lpmm` cycles/mm along `direction` over `fields` ×
    /// `wavelengths_nm` (field-major) through the pupil `sampling`, launched as
    /// [`crate::wave::wavefront`] launches its rays (no aiming).
    ///
    /// # Errors
    /// A sampling [`Sampling::check`] refuses; paraxial, ray-generation and wavefront errors of
    /// the design; [`crate::ErrorKind::Argument`] for a frequency that is not finite and
    /// positive or not below the design's cutoff at some field and wavelength (named).
    pub fn new(
        lens: &Lens,
        fields: &[Field],
        wavelengths_nm: &[f64],
        freq_lpmm: f64,
        direction: MtfDirection,
        sampling: Sampling,
        trace: TraceOptions,
    ) -> Result<MtfLoss> {
        sampling.check()?;
        if !(freq_lpmm > 0.0 && freq_lpmm.is_finite()) {
            return Err(Error::argument(format!(
                "MTF loss frequency {freq_lpmm} cycles/mm: give a finite frequency above 0"
            )));
        }
        let para = lens.paraxial(lens.primary_wavelength_nm)?;
        let opts = WaveOptions {
            sampling,
            trace,
            ..WaveOptions::default()
        };
        let sys = lens.compile();
        let mut launched = Vec::with_capacity(fields.len());
        for &f in fields {
            launched.push((f, f.resolved(lens, &para, false)?));
            // The design's cutoff, so that a frequency it cannot pass is refused by name.
            for &wl in wavelengths_nm {
                let w = wavefront(lens, &sys, f, wl, &opts)?;
                let map = direction_map(&w)?;
                let (t, s) = mtf::directions(&w);
                mtf::check_freqs(
                    &[freq_lpmm],
                    [
                        mtf::cutoff_along(&w, &map, t),
                        mtf::cutoff_along(&w, &map, s),
                    ],
                )
                .map_err(|e| e.context(format!("field {}, {wl} nm", f.label())))?;
            }
        }
        let (points, weights) = sampling.points();
        Ok(MtfLoss {
            launch: LaunchSource::new(lens, &para),
            fields: launched,
            wavelengths_nm: wavelengths_nm.to_vec(),
            freq_lpmm,
            direction,
            points,
            weights,
            trace,
        })
    }

    /// The loss at its `k`-th field alone (the design's cutoff there was checked by
    /// [`MtfLoss::new`]; nothing is traced again).
    pub(crate) fn at_field(&self, k: usize) -> MtfLoss {
        MtfLoss {
            fields: vec![self.fields[k]],
            ..self.clone()
        }
    }

    /// The MTF of field `f` at `wl` along the chosen direction through `sys`, the launch's
    /// first-order numbers `optics` and the exit pupil `to_pupil` mm from the image plane, or
    /// `None` when the bundle is lost.
    fn bundle<S: Traceable>(
        &self,
        sys: &System<S>,
        f: usize,
        wl: f64,
        optics: &LaunchOptics<S>,
        to_pupil: S,
    ) -> Option<S> {
        let (given, field) = self.fields[f];
        let tracer = PupilTracer::new(
            &self.launch.lens,
            sys,
            optics,
            given,
            field,
            wl,
            to_pupil,
            self.trace,
        )?;
        let base = tracer.wave(&self.points, &self.weights)?;
        let (p, w, [ax, ay]) = (&base.pupil, &base.weights, base.slopes);
        // Tangential: toward the chief ray's image point (y on axis); sagittal across it.
        let c = sys.image.point_to_local(base.centre);
        let r = (c.x * c.x + c.y * c.y).sqrt();
        let t = if r.value() > 1e-9 {
            [c.x / r, c.y / r]
        } else {
            [S::cst(0.0), S::cst(1.0)]
        };
        let lambda_mm = S::cst(wl * 1e-6);
        let otf = |u: [S; 2]| -> Option<S> {
            let k = S::cst(self.freq_lpmm) * lambda_mm;
            let shift = [k * u[0] / ax, k * u[1] / ay];
            let mut owner = Vec::with_capacity(p.len());
            let mut rays = Vec::with_capacity(p.len());
            for (i, q) in p.iter().enumerate() {
                let q = [S::cst(q[0]) - shift[0], S::cst(q[1]) - shift[1]];
                if q[0].value().powi(2) + q[1].value().powi(2) <= 1.0 {
                    owner.push(i);
                    rays.push(tracer.ray(q));
                }
            }
            let (mut re, mut im) = (S::cst(0.0), S::cst(0.0));
            if !rays.is_empty() {
                let (sheared, _) = tracer.opd(rays)?;
                for &(k, v, _) in &sheared.rays {
                    let i = owner[k];
                    let phase = (base.opd_waves[i] - v) * S::cst(std::f64::consts::TAU);
                    re += phase.cos() * S::cst(w[i]);
                    im += phase.sin() * S::cst(w[i]);
                }
            }
            let m2 = re * re + im * im;
            // |OTF|, 0 with derivative 0 where it vanishes.
            Some(if m2.value() > 0.0 {
                m2.sqrt()
            } else {
                S::cst(0.0)
            })
        };
        let s = [t[1], -t[0]];
        Some(match self.direction {
            MtfDirection::Tangential => otf(t)?,
            MtfDirection::Sagittal => otf(s)?,
            MtfDirection::Mean => (otf(t)? + otf(s)?) * S::cst(0.5),
        })
    }
}

/// The rays of one field and wavelength through normalised entrance-pupil points, in any number
/// type, launched from a design (its first-order numbers moving with the design variables), its
/// vignetting factors applied, traced through a system and measured against the reference
/// sphere on the chief ray through the exit pupil: the wavefront of
/// [`crate::wave::wavefront`] (no aiming) as a differentiable function.
pub(crate) struct PupilTracer<'a, S: Traceable> {
    lens: &'a Lens,
    sys: &'a System<S>,
    beam: Beam<S>,
    vig: crate::lens::Vignetting,
    chief: (Vec3<S>, Vec3<S>),
    wl: f64,
    n0: S,
    n_img: S,
    to_pupil: S,
    trace: TraceOptions,
}

/// The unsheared wavefront of a [`PupilTracer`] over the rays that got through.
pub(crate) struct TracedWave<S> {
    /// Their normalised pupil points.
    pub pupil: Vec<[f64; 2]>,
    /// Their weights, normalised over them.
    pub weights: Vec<f64>,
    /// Their OPD, waves.
    pub opd_waves: Vec<S>,
    /// The slopes of `n'` times the image-space direction cosines over the pupil (x, y).
    pub slopes: [S; 2],
    /// The reference sphere's centre (the chief ray's image point), global frame.
    pub centre: Vec3<S>,
}

impl<'a, S: Traceable> PupilTracer<'a, S> {
    /// The tracer of field `field` (as launched; `given` as the user gave it, which names its
    /// vignetting factors) at `wl` through `sys`, launched from `lens` with `optics`, the exit
    /// pupil `to_pupil` mm from the image plane; `None` when the field cannot be launched.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        lens: &'a Lens,
        sys: &'a System<S>,
        optics: &LaunchOptics<S>,
        given: Field,
        field: Field,
        wl: f64,
        to_pupil: S,
        trace: TraceOptions,
    ) -> Option<Self> {
        let beam = Beam::launch(lens, optics, field).ok()?;
        let vig = lens.vignetting_of(given);
        let idx = sys.indices(wl);
        let (n0, n_img) = (idx[0], idx[idx.len() - 1].abs());
        let mut t = PupilTracer {
            lens,
            sys,
            beam,
            vig,
            chief: (Vec3::cst(0.0, 0.0, 0.0), Vec3::cst(0.0, 0.0, 0.0)),
            wl,
            n0,
            n_img,
            to_pupil,
            trace,
        };
        t.chief = t.ray([S::cst(0.0); 2]);
        Some(t)
    }

    /// The ray through the normalised pupil point `q` (the vignetted pupil is an affine map of
    /// the normalised one).
    pub(crate) fn ray(&self, q: [S; 2]) -> (Vec3<S>, Vec3<S>) {
        let [x, y] = self.vig.apply(q);
        self.beam.ray(x * self.beam.r_ep, y * self.beam.r_ep)
    }

    /// Traces `rays` (the chief ray appended) and returns their OPD against the sphere, and the
    /// traced batch; `None` when the chief ray is lost.
    pub(crate) fn opd(
        &self,
        rays: Vec<(Vec3<S>, Vec3<S>)>,
    ) -> Option<(crate::wave::opd::SphereOpd<S>, RayBatch<S>)> {
        let mut launch = rays;
        launch.push(self.chief);
        let mut batch = RayBatch::collect_unit(launch.iter().copied());
        trace_serial(self.sys, self.wl, &mut batch, self.trace);
        let s = sphere_opd(
            self.lens.object,
            &launch,
            &batch,
            self.n0,
            self.n_img,
            &self.sys.image,
            self.to_pupil,
            Reference::Chief,
            self.wl,
        )
        .ok()?;
        Some((s, batch))
    }

    /// The wavefront through `points` of quadrature `weights`; `None` when the chief ray is lost,
    /// fewer than three rays get through or the slopes vanish.
    pub(crate) fn wave(&self, points: &[[f64; 2]], weights: &[f64]) -> Option<TracedWave<S>> {
        let rays = points.iter().map(|p| self.ray(p.map(S::cst))).collect();
        let (base, batch) = self.opd(rays)?;
        if base.rays.len() < 3 {
            return None;
        }
        let pupil: Vec<[f64; 2]> = base.rays.iter().map(|r| points[r.0]).collect();
        let total: f64 = base.rays.iter().map(|r| weights[r.0]).sum();
        let w: Vec<f64> = base.rays.iter().map(|r| weights[r.0] / total).collect();
        let img = &self.sys.image;
        let dirs: Vec<Vec3<S>> = base
            .rays
            .iter()
            .map(|r| img.rotation.apply_t(batch.get(r.0).d) * self.n_img)
            .collect();
        let ax = plane_fit(&pupil, &w, &dirs.iter().map(|d| d.x).collect::<Vec<_>>())?[1];
        let ay = plane_fit(&pupil, &w, &dirs.iter().map(|d| d.y).collect::<Vec<_>>())?[2];
        if !(ax.value().abs() > 0.0 && ay.value().abs() > 0.0) {
            return None;
        }
        Some(TracedWave {
            pupil,
            weights: w,
            opd_waves: base.rays.iter().map(|r| r.1).collect(),
            slopes: [ax, ay],
            centre: base.centre,
        })
    }
}

impl Objective for MtfLoss {
    fn eval<S: Traceable>(&self, sys: &System<S>, lift: &dyn Fn(Param, S) -> S) -> S {
        let lens = &*self.launch.lens;
        let optics = launch_optics(lens, self.launch.wavelength_nm, self.launch.stop, lift);
        let to_pupil = pupil_from_image(lens, self.launch.stop, lift);
        let mut total = S::cst(0.0);
        let n = self.fields.len() * self.wavelengths_nm.len();
        for f in 0..self.fields.len() {
            for &wl in &self.wavelengths_nm {
                let m = self
                    .bundle(sys, f, wl, &optics, to_pupil)
                    .unwrap_or(S::cst(0.0));
                total += S::cst(1.0) - m;
            }
        }
        total * S::cst(1.0 / n.max(1) as f64)
    }
}

/// The diffraction PSFs of one field at several wavelengths on sensor pixels, in any number
/// type: [`crate::wave::psf::diffraction_psf_map`]'s PSF of that field (the same sampling rule,
/// FFT and bilinear deposit, centred on the chief ray), its wavefront traced as a differentiable
/// function of the design (launched through the design's paraxial entrance pupil, the
/// reference sphere through its exit pupil, as [`MtfLoss`] traces it). Its dual-number
/// derivative is that of the PSF as evaluated: the OPD, the FFT's pixel pitch (from the
/// rays' direction cosines) and the deposit's bilinear weights all move with the design; which
/// pupil and FFT sizes are used, and which pixels a sample lands between, is decided on values.
///
/// # Examples
/// ```
/// use tolray::optim::DiffractionPsfs;
/// use tolray::trace::{Field, TraceOptions};
/// use tolray::wave::psf::diffraction_psf_map;
/// use tolray::Lens;
/// let lens = Lens::load("lens1")?;
/// let field = tolray::psf::grid_fields(&lens, 2)[3];
/// let d = DiffractionPsfs::new(&lens, field, &[587.5618], 15, 0.0036, TraceOptions::default())?;
/// let p = d.psfs(&lens.compile(), &|_, v| v)[0].clone().unwrap();
/// let map = diffraction_psf_map(&lens, &lens.compile(), 2, 587.5618, 15, 0.0036)?;
/// assert!(p.iter().zip(&map[3]).all(|(a, b)| (a - b).abs() < 1e-9));
/// # Ok::<(), tolray::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct DiffractionPsfs {
    /// The design the rays are launched from (at its primary wavelength).
    pub launch: LaunchSource,
    /// The field as given and as launched (held).
    pub field: (Field, Field),
    /// Wavelengths, nm: one PSF each.
    pub wavelengths_nm: Vec<f64>,
    /// Window side, pixels (odd).
    pub ks: usize,
    /// Pixel pitch, mm.
    pub pitch_mm: f64,
    /// Trace options.
    pub trace: TraceOptions,
}

impl DiffractionPsfs {
    /// The PSFs of `field` of `lens` at `wavelengths_nm` on `ks x ks` pixels of `pitch_mm`.
    ///
    /// # Errors
    /// Paraxial errors of the design; a field it cannot resolve; a window
    /// [`crate::wave::psf::pixel_psf`] refuses.
    pub fn new(
        lens: &Lens,
        field: Field,
        wavelengths_nm: &[f64],
        ks: usize,
        pitch_mm: f64,
        trace: TraceOptions,
    ) -> Result<DiffractionPsfs> {
        let para = lens.paraxial(lens.primary_wavelength_nm)?;
        let resolved = field.resolved(lens, &para, false)?;
        crate::wave::psf::check_window(ks, pitch_mm)?;
        Ok(DiffractionPsfs {
            launch: LaunchSource::new(lens, &para),
            field: (field, resolved),
            wavelengths_nm: wavelengths_nm.to_vec(),
            ks,
            pitch_mm,
            trace,
        })
    }

    /// Each wavelength's PSF through `sys` (the design compiled with `lift`, or a unit of it),
    /// unit sum, or `None` where it has none (the chief ray lost, fewer than three rays through,
    /// a wavefront the sampling rule cannot resolve): the caller stands in for it.
    pub fn psfs<S: Traceable>(
        &self,
        sys: &System<S>,
        lift: &dyn Fn(Param, S) -> S,
    ) -> Vec<Option<Vec<S>>> {
        let lens = &*self.launch.lens;
        let optics = launch_optics(lens, self.launch.wavelength_nm, self.launch.stop, lift);
        let to_pupil = pupil_from_image(lens, self.launch.stop, lift);
        let (given, field) = self.field;
        self.wavelengths_nm
            .iter()
            .map(|&wl| {
                let tracer =
                    PupilTracer::new(lens, sys, &optics, given, field, wl, to_pupil, self.trace)?;
                let mut wave_at = |s: usize| -> Result<crate::wave::psf::GridWave<S>> {
                    let (points, weights) = Sampling::Grid(s).points();
                    let t = tracer
                        .wave(&points, &weights)
                        .ok_or_else(|| Error::numerical("no wavefront"))?;
                    Ok(crate::wave::psf::GridWave {
                        pupil: t.pupil,
                        opd_waves: t.opd_waves,
                        slopes: t.slopes,
                    })
                };
                crate::wave::psf::sampled_pixel_psf(&mut wave_at, wl, self.ks, self.pitch_mm).ok()
            })
            .collect()
    }
}
