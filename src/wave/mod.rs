//! Wave optics: the optical path difference (OPD) at the exit pupil, RMS and peak-to-valley
//! wavefront error, Zernike fits, Strehl ratios, diffraction PSFs and MTFs.
//!
//! # Conventions (OpticStudio's, `docs/wave-optics.md` has the cross-check against optiland)
//! - **Reference sphere**: centred on the chief ray's point on the image surface
//!   ([`Reference::Chief`], the default; the spot's centroid as an option), through the
//!   paraxial exit pupil's centre on the axis, at the primary wavelength. The OPD of a ray is the
//!   chief ray's optical path to that sphere minus the ray's, in waves of the analysis
//!   wavelength: positive where the wavefront leads the sphere (a sensor behind the focus gives
//!   positive defocus, W020 = Δz / (8 N²)). For a lens whose exit pupil is at infinity
//!   (telecentric in image space) the sphere passes through the last surface's vertex instead.
//! - Rays are launched as every other analysis launches them ([`crate::trace::RaySet`]): through
//!   the primary wavelength's paraxial entrance pupil, or aimed at the real stop, with the lens
//!   file's vignetting factors. For an object at infinity the optical path starts on a plane
//!   wavefront, for a finite object at the object point.
//! - **Pupil coordinates**: averages and fits are over the normalised entrance pupil (the unit
//!   disk the rays are launched through, uniform in area, as OpticStudio and optiland sample it).
//!   Zernike fits are made in entrance-pupil coordinates by default ([`PupilCoords::Entrance`],
//!   optiland's) or in normalised exit-pupil coordinates ([`PupilCoords::Exit`], OpticStudio's:
//!   the ray's point on the reference sphere relative to the chief ray's, over the paraxial exit
//!   pupil radius). They differ off axis by the pupil's aberrations.
//! - **RMS to chief** removes piston only, **RMS to centroid** piston and tilt (a weighted
//!   least-squares plane); PV likewise. **Strehl (Maréchal)** is exp(−(2π σ)²) with σ the RMS to
//!   centroid in waves, as OpticStudio's Zernike listing prints it.
//! - Integrals over the pupil use a **polar Gauss quadrature** by default ([`Sampling`]): Gauss–
//!   Legendre in ρ², equally spaced in θ. It integrates smooth wavefronts to near machine
//!   precision with a few hundred rays, where a square grid of 64² rays misses RMS values by up
//!   to 2 % (the grid's staircase rim).
//!
//! # Examples
//! ```
//! use tolray::trace::Field;
//! use tolray::wave::{wavefront, WaveOptions};
//! use tolray::Lens;
//! let lens = Lens::load("lens2")?;
//! let w = wavefront(&lens, &lens.compile(), Field::fraction(0.0), 587.5618, &WaveOptions::default())?;
//! let s = w.stats(37)?;
//! assert!(s.rms_to_chief_waves >= s.rms_to_centroid_waves);
//! // On axis the wavefront of a rotationally symmetric lens has no tilt or astigmatism.
//! let z = &s.zernike_standard.coefficients;
//! assert!(z[1].abs() < 1e-9 && z[4].abs() < 1e-9 && z[5].abs() < 1e-9);
//! # Ok::<(), tolray::Error>(())
//! ```

pub mod mtf;
pub(crate) mod opd;
pub mod psf;
pub mod zernike;

use crate::error::{Error, Result};
use crate::lens::{Lens, System};
use crate::math::{Rigid, Vec3};
use crate::trace::{self, Field, RaySet, TraceOptions};
use serde::Serialize;
use zernike::{Ordering, ZernikeFit};

/// How the pupil is sampled.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Sampling {
    /// Polar Gauss quadrature: `rings` Gauss–Legendre nodes in ρ² times `spokes` equally spaced
    /// angles (exact for polynomials up to degree 2·rings − 1 in ρ² and spokes − 1 in θ).
    Quadrature {
        /// Radial nodes.
        rings: usize,
        /// Angular nodes.
        spokes: usize,
    },
    /// Cell-centred `n x n` square grid, cells whose centre is inside the unit disk, equal
    /// weights (the pupil function of the FFT PSF, the OPD map).
    Grid(usize),
}

impl Default for Sampling {
    /// 16 rings x 48 spokes (768 rays).
    fn default() -> Self {
        Sampling::Quadrature {
            rings: 16,
            spokes: 48,
        }
    }
}

/// Most rays a sampling may trace per field and wavelength (as for pupil patterns).
pub const MAX_SAMPLES: usize = trace::rays::MAX_PUPIL_RAYS;

impl Sampling {
    /// Checks the sampling is not empty and not larger than [`MAX_SAMPLES`].
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] saying the count and the limit.
    pub fn check(&self) -> Result<()> {
        let n = match *self {
            Sampling::Quadrature { rings, spokes } => {
                if rings == 0 || spokes == 0 {
                    return Err(Error::argument(
                        "pupil quadrature needs at least one ring and one spoke",
                    ));
                }
                rings.saturating_mul(spokes)
            }
            Sampling::Grid(n) => {
                if n == 0 {
                    return Err(Error::argument("pupil grid 0: give at least 1"));
                }
                n.saturating_mul(n)
            }
        };
        if n > MAX_SAMPLES {
            return Err(Error::argument(format!(
                "pupil sampling {self:?} would trace {n} rays per field and wavelength; at most {MAX_SAMPLES} are allowed"
            )));
        }
        Ok(())
    }

    /// The unit-disk points and their weights (summing to 1).
    ///
    /// # Examples
    /// ```
    /// use tolray::wave::Sampling;
    /// let (pts, w) = Sampling::Quadrature { rings: 4, spokes: 8 }.points();
    /// assert_eq!(pts.len(), 32);
    /// // The mean of ρ² over the disk is 1/2.
    /// let m: f64 = pts.iter().zip(&w).map(|(p, w)| w * (p[0] * p[0] + p[1] * p[1])).sum();
    /// assert!((m - 0.5).abs() < 1e-15);
    /// ```
    #[must_use]
    pub fn points(&self) -> (Vec<[f64; 2]>, Vec<f64>) {
        match *self {
            Sampling::Quadrature { rings, spokes } => {
                let gl = crate::lens::qbfs::gauss_legendre(rings);
                let mut pts = Vec::with_capacity(rings * spokes);
                let mut w = Vec::with_capacity(rings * spokes);
                for &(x, wx) in &gl {
                    // Nodes on [-1, 1] mapped to ρ² on [0, 1]; weights to sum 1 over the disk.
                    let rho = (0.5 * (x + 1.0)).sqrt();
                    for j in 0..spokes {
                        let t = std::f64::consts::TAU * (j as f64 + 0.5) / spokes as f64;
                        pts.push([rho * t.cos(), rho * t.sin()]);
                        w.push(0.5 * wx / spokes as f64);
                    }
                }
                (pts, w)
            }
            Sampling::Grid(n) => {
                let mut pts = Vec::new();
                for j in 0..n {
                    for i in 0..n {
                        let x = (2 * i + 1) as f64 / n as f64 - 1.0;
                        let y = (2 * j + 1) as f64 / n as f64 - 1.0;
                        if x * x + y * y <= 1.0 {
                            pts.push([x, y]);
                        }
                    }
                }
                let w = vec![1.0 / pts.len().max(1) as f64; pts.len()];
                (pts, w)
            }
        }
    }
}

/// The centre of the reference sphere.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub enum Reference {
    /// The chief ray's point on the image surface (OpticStudio's default).
    #[default]
    Chief,
    /// The centroid of the rays' points on the image surface.
    Centroid,
}

/// The pupil coordinates Zernike terms are fitted in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub enum PupilCoords {
    /// Normalised entrance-pupil coordinates (the launch points; optiland's).
    #[default]
    Entrance,
    /// Normalised exit-pupil coordinates (the points on the reference sphere; OpticStudio's).
    Exit,
}

/// Options of a wavefront analysis.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WaveOptions {
    /// Pupil sampling.
    pub sampling: Sampling,
    /// Centre of the reference sphere.
    pub reference: Reference,
    /// Coordinates of the Zernike fits.
    pub zernike_pupil: PupilCoords,
    /// Aim rays at the real stop (as [`crate::trace::Pupil::aim`]).
    pub aim: bool,
    /// Trace options (apertures clip by default).
    pub trace: TraceOptions,
}

/// The OPD of one field at one wavelength over the rays that reached the reference sphere.
#[derive(Clone, Debug, Serialize)]
pub struct Wavefront {
    /// The field.
    pub field: Field,
    /// Wavelength, nm.
    pub wavelength_nm: f64,
    /// Rays launched (without the chief ray).
    pub n_launched: usize,
    /// Normalised entrance-pupil point of each ray that got through (unit disk; before the
    /// field's vignetting factors are applied).
    pub pupil: Vec<[f64; 2]>,
    /// Index of each ray among the pupil points it was launched from.
    pub ray_index: Vec<usize>,
    /// Normalised exit-pupil point of each ray (see [`PupilCoords::Exit`]).
    pub exit_pupil: Vec<[f64; 2]>,
    /// Weight of each ray, summing to 1 (the sampling's weights over the rays that got
    /// through).
    pub weight: Vec<f64>,
    /// OPD of each ray, waves.
    pub opd_waves: Vec<f64>,
    /// Each ray's point on the reference sphere, global frame, mm.
    #[serde(skip)]
    pub sphere_points: Vec<Vec3<f64>>,
    /// Each ray's unit direction after the last surface, in the image plane's frame.
    #[serde(skip)]
    pub directions: Vec<Vec3<f64>>,
    /// Each ray's point on the image plane, in the image plane's frame (x, y), mm.
    #[serde(skip)]
    pub image_points: Vec<[f64; 2]>,
    /// The image plane's placement (its local frame in the global one).
    #[serde(skip)]
    pub image: Rigid<f64>,
    /// Centre of the reference sphere, global frame, mm.
    pub centre_mm: [f64; 3],
    /// The centre in the image plane's frame (x, y), mm.
    pub centre_image_mm: [f64; 2],
    /// Radius of the reference sphere, mm.
    pub radius_mm: f64,
    /// Refractive index of image space.
    pub image_index: f64,
}

/// Wavefront error of one field and wavelength: [`Wavefront::stats`].
#[derive(Clone, Debug, Serialize)]
pub struct WavefrontStats {
    /// RMS OPD with piston removed, waves.
    pub rms_to_chief_waves: f64,
    /// RMS OPD with piston and tilt removed, waves.
    pub rms_to_centroid_waves: f64,
    /// Peak to valley of the OPD, waves.
    pub pv_to_chief_waves: f64,
    /// Peak to valley with tilt removed, waves.
    pub pv_to_centroid_waves: f64,
    /// Maréchal's estimate exp(−(2π σ)²), σ the RMS to centroid in waves.
    pub strehl_marechal: f64,
    /// Zernike Standard (Noll) fit, waves.
    pub zernike_standard: ZernikeFit,
    /// Zernike Fringe fit (at most 37 terms), waves.
    pub zernike_fringe: ZernikeFit,
}

/// Traces the rays of `field` at `wavelength_nm` through `sys` (a compiled, possibly perturbed
/// form of `lens`) and returns their OPD against the reference sphere.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] for an afocal lens (no image point to refer to) or a sampling
/// [`Sampling::check`] refuses; [`crate::ErrorKind::Numerical`] when the chief ray does not
/// reach the image (a field beyond the lens' reach) or fewer than three rays get through;
/// ray-generation errors.
pub fn wavefront(
    lens: &Lens,
    sys: &System<f64>,
    field: Field,
    wavelength_nm: f64,
    opts: &WaveOptions,
) -> Result<Wavefront> {
    opts.sampling.check()?;
    let (pts, w) = opts.sampling.points();
    wavefront_at(lens, sys, field, wavelength_nm, &pts, &w, opts)
}

/// As [`wavefront`], through the normalised entrance-pupil points `pts` (unit disk) with
/// weights `w` (any positive numbers; they are normalised over the rays that get through)
/// instead of `opts.sampling`: another engine's sample points, or a quadrature of one's own.
///
/// # Errors
/// As [`wavefront`]; [`crate::ErrorKind::Argument`] when `pts` and `w` differ in length, are
/// empty or longer than [`MAX_SAMPLES`], or a weight is not positive and finite.
pub fn wavefront_at(
    lens: &Lens,
    sys: &System<f64>,
    field: Field,
    wavelength_nm: f64,
    pts: &[[f64; 2]],
    w: &[f64],
    opts: &WaveOptions,
) -> Result<Wavefront> {
    trace_wavefront(lens, sys, field, wavelength_nm, pts, w, opts, 3)
}

/// [`wavefront_at`], refusing fewer than `min_rays` rays through (0 for the sheared pupils of
/// [`mtf::direct_mtf`], where none getting through is an answer).
#[allow(clippy::too_many_arguments)]
pub(crate) fn trace_wavefront(
    lens: &Lens,
    sys: &System<f64>,
    field: Field,
    wavelength_nm: f64,
    pts: &[[f64; 2]],
    w: &[f64],
    opts: &WaveOptions,
    min_rays: usize,
) -> Result<Wavefront> {
    if pts.len() != w.len() || pts.is_empty() || pts.len() > MAX_SAMPLES {
        return Err(Error::argument(format!(
            "{} pupil points with {} weights: give 1 to {MAX_SAMPLES} points, one weight each",
            pts.len(),
            w.len()
        )));
    }
    if let Some(b) = w.iter().find(|v| !(**v > 0.0 && v.is_finite())) {
        return Err(Error::argument(format!(
            "pupil weight {b}: weights must be positive and finite"
        )));
    }
    let para = lens.paraxial(lens.primary_wavelength_nm)?;
    if para.is_afocal() {
        return Err(Error::argument(
            "the lens is afocal: a wavefront needs an image point to refer to (no focus forms)",
        ));
    }
    let what = || format!("wavefront of field {} at {wavelength_nm} nm", field.label());
    let set = RaySet::generate_at(lens, &para, field, pts, opts.aim, wavelength_nm)
        .map_err(|e| e.context(what()))?;
    let mut batch = set.batch::<f64>();
    batch.push(set.chief.0, set.chief.1);
    trace::trace(sys, wavelength_nm, &mut batch, opts.trace);
    let idx = sys.indices(wavelength_nm);
    let (n0, n_img) = (idx[0], idx[idx.len() - 1].abs());
    let m = pts.len();
    let launch: Vec<(Vec3<f64>, Vec3<f64>)> = set
        .origins
        .iter()
        .copied()
        .zip(set.directions.iter().copied())
        .chain(std::iter::once(set.chief))
        .collect();
    let img = &sys.image;
    // The exit pupil's centre on the image-space axis, at its axial distance from the image
    // plane (in the image plane's frame); the last vertex when the pupil is at infinity (as
    // `opd::pupil_from_image` gives it in any number type, to rounding).
    let z = lens.vertex_z_mm();
    let z_img = z[z.len() - 1];
    let mut to_pupil = para.exit_pupil_z_mm - z_img;
    if !to_pupil.is_finite() || to_pupil.abs() > 1e6 * (1.0 + z_img.abs()) {
        to_pupil = z[z.len() - 2] - z_img;
    }
    let sphere = opd::sphere_opd(
        lens.object,
        &launch,
        &batch,
        n0,
        n_img,
        img,
        to_pupil,
        opts.reference,
        wavelength_nm,
    )
    .map_err(|f| {
        Error::numerical(match f {
            opd::OpdFailure::ChiefLost(status) => format!(
                "{}: the chief ray does not reach the image ({status}), so there is no \
                 reference sphere; is the field beyond the lens' reach?",
                what()
            ),
            opd::OpdFailure::NoRay => format!("{}: no ray reaches the image", what()),
            opd::OpdFailure::PupilOnImage => format!(
                "{}: the exit pupil lies on the image point, no reference sphere",
                what()
            ),
            opd::OpdFailure::ChiefMissesSphere => {
                format!("{}: the chief ray misses the reference sphere", what())
            }
        })
    })?;
    let (centre, radius) = (sphere.centre, sphere.radius);
    let r_xp = 0.5 * para.exit_pupil_diameter_mm;
    let r_xp = if r_xp.is_finite() && r_xp > 0.0 {
        r_xp
    } else {
        radius * (0.5 / para.working_fnum.unwrap_or(1.0))
    };
    let mut out = Wavefront {
        field,
        wavelength_nm,
        n_launched: m,
        pupil: Vec::with_capacity(m),
        ray_index: Vec::with_capacity(m),
        exit_pupil: Vec::with_capacity(m),
        weight: Vec::with_capacity(m),
        opd_waves: Vec::with_capacity(m),
        sphere_points: Vec::with_capacity(m),
        directions: Vec::with_capacity(m),
        image_points: Vec::with_capacity(m),
        image: *img,
        centre_mm: [centre.x, centre.y, centre.z],
        centre_image_mm: {
            let c = img.point_to_local(centre);
            [c.x, c.y]
        },
        radius_mm: radius,
        image_index: n_img,
    };
    for &(i, opd, q) in &sphere.rays {
        let r = batch.get(i);
        let e = img.rotation.apply_t(q - sphere.chief_point);
        out.pupil.push(pts[i]);
        out.ray_index.push(i);
        out.exit_pupil.push([e.x / r_xp, e.y / r_xp]);
        out.weight.push(w[i]);
        out.opd_waves.push(opd);
        out.sphere_points.push(q);
        out.directions.push(img.rotation.apply_t(r.d));
        let h = img.point_to_local(r.o);
        out.image_points.push([h.x, h.y]);
    }
    if out.opd_waves.len() < min_rays {
        return Err(Error::numerical(format!(
            "{}: {} of {m} rays reach the image; a wavefront needs at least {min_rays}",
            what(),
            out.opd_waves.len()
        )));
    }
    let total: f64 = out.weight.iter().sum();
    if total > 0.0 {
        for v in &mut out.weight {
            *v /= total;
        }
    }
    Ok(out)
}

impl Wavefront {
    /// The RMS OPD to centroid (piston and tilt removed by a weighted least-squares plane over
    /// the entrance pupil), waves: [`WavefrontStats::rms_to_centroid_waves`] without the
    /// Zernike fits, for the tolerance criterion.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Numerical`] when the rays cannot determine a plane.
    ///
    /// # Examples
    /// ```
    /// use tolray::trace::Field;
    /// use tolray::wave::{wavefront, WaveOptions};
    /// use tolray::Lens;
    /// let lens = Lens::load("cooke-triplet")?;
    /// let w = wavefront(&lens, &lens.compile(), Field::fraction(0.7), 587.5618, &WaveOptions::default())?;
    /// let full = w.stats(3)?;
    /// assert!((w.rms_to_centroid_waves()? - full.rms_to_centroid_waves).abs() < 1e-15);
    /// # Ok::<(), tolray::Error>(())
    /// ```
    pub fn rms_to_centroid_waves(&self) -> Result<f64> {
        let tilt = zernike::fit(
            Ordering::Standard,
            3,
            &self.pupil,
            &self.opd_waves,
            &self.weight,
        )?;
        Ok(tilt.residual_rms)
    }

    /// The points the Zernike terms are fitted at.
    fn fit_points(&self, coords: PupilCoords) -> &[[f64; 2]] {
        match coords {
            PupilCoords::Entrance => &self.pupil,
            PupilCoords::Exit => &self.exit_pupil,
        }
    }

    /// RMS and PV to chief and centroid, the Maréchal Strehl, and Zernike Standard (`terms`
    /// terms) and Fringe (`min(terms, 37)`) fits in entrance-pupil coordinates; see
    /// [`Wavefront::stats_in`].
    ///
    /// # Errors
    /// As [`Wavefront::stats_in`].
    pub fn stats(&self, terms: usize) -> Result<WavefrontStats> {
        self.stats_in(terms, PupilCoords::Entrance)
    }

    /// As [`Wavefront::stats`], the Zernike terms fitted in `coords`. Tilt for the RMS to
    /// centroid is removed in the same coordinates.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for a term count [`zernike::check_terms`] refuses;
    /// [`crate::ErrorKind::Numerical`] when the rays cannot determine the terms.
    pub fn stats_in(&self, terms: usize, coords: PupilCoords) -> Result<WavefrontStats> {
        let (v, w) = (&self.opd_waves, &self.weight);
        let xy = self.fit_points(coords);
        let mean: f64 = v.iter().zip(w).map(|(a, b)| a * b).sum();
        let rms_chief = v
            .iter()
            .zip(w)
            .map(|(a, b)| b * (a - mean) * (a - mean))
            .sum::<f64>()
            .sqrt();
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &a| {
                (l.min(a), h.max(a))
            });
        // Piston and tilt are Standard Z1..Z3.
        let tilt = zernike::fit(Ordering::Standard, 3, xy, v, w)?;
        let plane = |p: &[f64; 2]| {
            tilt.coefficients[0] + 2.0 * (tilt.coefficients[1] * p[0] + tilt.coefficients[2] * p[1])
        };
        let (lo_c, hi_c) =
            v.iter()
                .zip(xy)
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), (&a, p)| {
                    let r = a - plane(p);
                    (l.min(r), h.max(r))
                });
        let sigma = tilt.residual_rms;
        let standard = zernike::fit(Ordering::Standard, terms, xy, v, w)?;
        let fringe = zernike::fit(Ordering::Fringe, terms.min(zernike::FRINGE_TERMS), xy, v, w)?;
        Ok(WavefrontStats {
            rms_to_chief_waves: rms_chief,
            rms_to_centroid_waves: sigma,
            pv_to_chief_waves: hi - lo,
            pv_to_centroid_waves: hi_c - lo_c,
            strehl_marechal: (-(std::f64::consts::TAU * sigma).powi(2)).exp(),
            zernike_standard: standard,
            zernike_fringe: fringe,
        })
    }
}
