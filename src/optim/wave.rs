//! The RMS wavefront error as a differentiable loss: the OPD of [`crate::wave::wavefront`]
//! computed in any number type, so that dual numbers carry its exact gradient (the rays'
//! launch, the reference sphere's centre on the chief ray and the paraxial exit pupil it passes
//! through all move with the design).

use super::Objective;
use crate::error::Result;
use crate::lens::{Lens, Param, System};
use crate::trace::{trace_serial, Bundles, Field, TraceOptions, Traceable};
use crate::wave::opd::{pupil_from_image, rms_about_plane, sphere_opd};
use crate::wave::{Reference, Sampling};

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
