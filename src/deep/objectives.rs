//! What a deep-optics iteration differentiates: the crops' PSF objective (the seam between the decoder's reverse mode and the lens' forward mode) and each unit's refocus.

use super::*;

/// PSF options of the image stages: `ks` pixels at the sensor pitch, chief-ray centred, `spp`
/// random pupil rays of seed `seed`.
pub fn psf_options(lens: &Lens, ks: usize, spp: usize, seed: u64) -> PsfOptions {
    let mut psf = PsfOptions::for_lens(lens);
    psf.ks = ks;
    psf.centre = PsfCentre::Chief;
    psf.pupil = Pupil {
        pattern: PupilPattern::Random { n: spp, seed },
        scale: 1.0,
        aim: false,
    };
    psf
}

/// The RGB PSFs of `sys` over the `grid x grid` field grid of `lens`, as f32 in the layout of
/// [`crate::image::render::PsfMap`]: tile-major, then channel (the lens' RGB wavelengths), then
/// `ks x ks`.
///
/// # Errors
/// Ray-generation errors; a PSF into whose window no ray lands.
pub fn rgb_psf_map(
    lens: &Lens,
    sys: &System<f64>,
    grid: usize,
    wavelengths_nm: &[f64],
    opts: &PsfOptions,
) -> Result<Vec<f32>> {
    rgb_psf_map_of(PsfModel::Geometric, lens, sys, grid, wavelengths_nm, opts)
}

/// [`rgb_psf_map`] in the PSF model `model`: geometric ([`crate::psf::psf_map`]) or diffraction
/// ([`crate::wave::psf::diffraction_psf_tiles`], on the same pixels, centred on each field's
/// chief ray; a field with no wavefront, its chief ray lost in a vignetted corner of a
/// perturbed unit, takes its geometric PSF, which falls back to the rays' centroid).
///
/// # Errors
/// As [`rgb_psf_map`]; wavefront errors for the diffraction model.
pub fn rgb_psf_map_of(
    model: PsfModel,
    lens: &Lens,
    sys: &System<f64>,
    grid: usize,
    wavelengths_nm: &[f64],
    opts: &PsfOptions,
) -> Result<Vec<f32>> {
    let ks2 = opts.ks * opts.ks;
    let nc = wavelengths_nm.len();
    let mut out = vec![0f32; grid * grid * nc * ks2];
    for (c, &wl) in wavelengths_nm.iter().enumerate() {
        let map = match model {
            PsfModel::Geometric => crate::psf::psf_map(lens, sys, grid, wl, opts)?,
            PsfModel::Diffraction => {
                let tiles = crate::wave::psf::diffraction_psf_tiles(
                    lens,
                    sys,
                    grid,
                    wl,
                    opts.ks,
                    opts.pitch_mm,
                )?;
                let geometric = if tiles.iter().any(|t| t.is_err()) {
                    Some(crate::psf::psf_map(lens, sys, grid, wl, opts)?)
                } else {
                    None
                };
                tiles
                    .into_iter()
                    .enumerate()
                    .map(|(t, r)| r.or_else(|e| geometric.as_ref().map(|g| g[t].clone()).ok_or(e)))
                    .collect::<Result<Vec<_>>>()?
            }
        };
        for (t, p) in map.iter().enumerate() {
            crate::psf::check_landed(p, &format!("PSF of grid cell {t} at {wl} nm"))?;
            let dst = &mut out[(t * nc + c) * ks2..(t * nc + c + 1) * ks2];
            for (d, s) in dst.iter_mut().zip(p) {
                *d = *s as f32;
            }
        }
    }
    Ok(out)
}

/// The nominal lens' RGB PSF map in `model`, `spp` rays per geometric PSF (used to initialise a
/// decoder).
pub(super) fn nominal_psf_map(
    model: PsfModel,
    lens: &Lens,
    cfg: &TrainConfig,
    spp: usize,
) -> Result<Vec<f32>> {
    let opts = psf_options(lens, cfg.psf_ks, spp, cfg.seed);
    rgb_psf_map_of(
        model,
        lens,
        &lens.compile(),
        cfg.psf_grid,
        &cfg.wavelengths_nm,
        &opts,
    )
}

/// A crop's RGB PSFs through `sys` (compiled with `lift`): the rays' PSFs of `rays`, or with
/// `diffraction` each wavelength's diffraction PSF where it has one (else the rays' PSF, a
/// choice made on values), in any number type: the value path of training and the dual path
/// of its gradient are this one function.
pub fn crop_psfs<S: Traceable>(
    rays: &Bundles,
    diffraction: Option<&DiffractionPsfs>,
    sys: &System<S>,
    lift: &dyn Fn(Param, S) -> S,
    psf: &PsfOptions,
    trace: TraceOptions,
) -> Vec<Vec<S>> {
    let optics = rays.optics(lift);
    let mut out: Vec<Option<Vec<S>>> = match diffraction {
        Some(d) => d.psfs(sys, lift),
        None => vec![None; rays.len()],
    };
    for (k, p) in out.iter_mut().enumerate() {
        if p.is_none() {
            *p = Some(psf_of_launched(sys, rays, k, optics.as_ref(), psf, trace).0);
        }
    }
    out.into_iter().flatten().collect()
}

/// The lens objective of one training crop's pattern: the spot and PSF-similarity terms (weighted
/// by `weight`, the batch mean) plus the image term `<dL/dPSF, PSF(θ)>`, whose dual-number
/// derivative is the image loss' gradient through this crop's PSF (a vector-Jacobian product
/// from the forward-mode Jacobian). The rays are launched from the design, and the similarity's
/// reference is the design's own PSF: both move with the design in gradients.
pub struct PatternObjective {
    /// Spot bundles at the crop's field (one per wavelength).
    pub spot: Bundles,
    /// Rays of the crop's RGB PSF.
    pub psf_rays: Bundles,
    /// The crop's diffraction PSFs when training uses them ([`crop_psfs`]).
    pub diffraction: Option<Arc<DiffractionPsfs>>,
    /// PSF settings.
    pub psf: PsfOptions,
    /// Whether the similarity term is on (tolerance phases; off in the nominal phase).
    pub similarity: bool,
    /// dL/dPSF per channel (`ks²` each).
    pub image_grad: Vec<Vec<f64>>,
    /// Weight of the spot and similarity terms (1 / batch size).
    pub weight: f64,
    /// λ_spot, per mm.
    pub lambda_spot: f64,
    /// λ_psf.
    pub lambda_psf: f64,
    /// Trace options.
    pub trace: TraceOptions,
}

impl Objective for PatternObjective {
    fn eval<S: Traceable>(&self, sys: &System<S>, lift: &dyn Fn(Param, S) -> S) -> S {
        let spot = spot_sum(&self.spot, sys, lift, SpotMeasure::Mean, self.trace);
        let mut total =
            spot * S::cst(self.weight * self.lambda_spot / self.spot.len().max(1) as f64);
        let at = |s: &System<S>| {
            crop_psfs(
                &self.psf_rays,
                self.diffraction.as_deref(),
                s,
                lift,
                &self.psf,
                self.trace,
            )
        };
        let psfs = at(sys);
        let design = self
            .similarity
            .then(|| at(&self.psf_rays.launch.design(lift)));
        let mut sim = S::cst(0.0);
        for (k, p) in psfs.iter().enumerate() {
            if let Some(d) = &design {
                sim += psf_similarity_of(&d[k], p, self.psf.ks);
            }
            for (g, v) in self.image_grad[k].iter().zip(p) {
                if *g != 0.0 {
                    total += *v * S::cst(*g);
                }
            }
        }
        if self.similarity {
            let n = S::cst(1.0 / self.psf_rays.len().max(1) as f64);
            total += (S::cst(1.0) - sim * n) * S::cst(self.weight * self.lambda_psf);
        }
        total
    }
}

/// How a fabricated unit is refocused (training and evaluation alike): best RMS focus over
/// the fields 0, 0.7 and 1 at the lens's RGB wavelengths, a 16 x 16 pupil grid, apertures on.
pub fn refocus_options(lens: &Lens) -> crate::tolerance::monte_carlo::McOptions {
    crate::tolerance::monte_carlo::McOptions {
        spec: crate::tolerance::ToleranceSpec::default(),
        trials: 1,
        seed: 0,
        fields: [0.0, 0.7, 1.0].map(Field::fraction).to_vec(),
        wavelengths_nm: lens.rgb_wavelengths_nm.to_vec(),
        pupil: Pupil::grid(16),
        compensate_focus: true,
        apertures: true,
        criterion: Default::default(),
    }
}

/// `pattern` applied to `lens`, with the sensor moved by `refocus_mm` along its normal.
///
/// # Errors
/// An invalid pattern.
pub fn unit_lens(
    lens: &Lens,
    pattern: &crate::tolerance::Perturbation,
    refocus_mm: Option<f64>,
) -> Result<(Lens, Adjustments)> {
    let (plens, mut adj) = pattern.apply(lens)?;
    if let Some(d) = refocus_mm {
        let r = adj.image_motion.rotation;
        adj.image_motion.translation =
            adj.image_motion.translation + r.apply(crate::math::Vec3::new(0.0, 0.0, d));
    }
    Ok((plens, adj))
}

/// The best-RMS refocus of a unit as a differentiable function of the design: over bundles
/// launched from the design (fields 0, 0.7 and 1 at the RGB wavelengths and a 16 x 16 pupil
/// grid, as [`refocus_options`]; apertures as the training config says), the sensor shift `δ = −Σ_f B_f / Σ_f C_f` minimizing the summed
/// mean-square spot radius `A_f + 2 B_f δ + C_f δ²` of the fields (the formula of the Monte
/// Carlo's focus compensator). Evaluated in dual numbers it gives dδ/dθ exactly.
#[derive(Clone, Debug)]
pub struct FocusObjective {
    /// The refocus bundles.
    pub bundles: Bundles,
    /// Number of fields.
    pub fields: usize,
    /// Trace options.
    pub trace: TraceOptions,
}

impl FocusObjective {
    /// Bundles of `lens` for its refocus (a 16 x 16 pupil grid). With `apertures` (as training
    /// traces by default and the Monte Carlo's compensator always does) the focus is that of the
    /// light a unit passes; a ray crossing an aperture's edge is then a jump in the refocus.
    ///
    /// # Errors
    /// Paraxial and ray-generation errors.
    pub fn new(lens: &Lens, apertures: bool) -> Result<FocusObjective> {
        let o = refocus_options(lens);
        let trace = TraceOptions { apertures };
        Ok(FocusObjective {
            bundles: Bundles::new(lens, &o.fields, &o.wavelengths_nm, &o.pupil)?,
            fields: o.fields.len(),
            trace,
        })
    }
}

impl Objective for FocusObjective {
    fn eval<S: Traceable>(&self, sys: &System<S>, lift: &dyn Fn(Param, S) -> S) -> S {
        let optics = self.bundles.optics(lift);
        let mut rays: Vec<Vec<[S; 4]>> = vec![Vec::new(); self.fields];
        for k in 0..self.bundles.len() {
            let f = self.bundles.sets[k].field_index;
            rays[f].extend(
                self.bundles
                    .launched_sensor_rays(sys, optics.as_ref(), k, self.trace),
            );
        }
        let moments: Vec<SpotMoments<S>> = rays
            .iter()
            .filter_map(|r| SpotMoments::of_rays(r))
            .collect();
        SpotMoments::best_focus(&moments)
    }
}

/// A crop's lens: its pattern (and, when the crop is refocused, its refocus for this `lens`)
/// applied to `lens`, with the adjustments.
pub(super) fn crop_lens(lens: &Lens, bc: &BatchCrop) -> Result<(Lens, Adjustments)> {
    let Some(p) = &bc.pattern else {
        return Ok((lens.clone(), Adjustments::none(lens.surfaces.len())));
    };
    let (l, a) = unit_lens(lens, p, None)?;
    let Some(f) = &bc.refocus else {
        return Ok((l, a));
    };
    let d = crate::optim::value(f.as_ref(), &l, &a);
    if !d.is_finite() {
        return Err(Error::numerical("a unit's refocus is not finite"));
    }
    unit_lens(lens, p, Some(d))
}
