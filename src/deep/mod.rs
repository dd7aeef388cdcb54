//! Deep optics: a lens and an image-reconstruction decoder trained together, first on the
//! nominal lens and then with random manufacturing tolerances in the loop (the paper's two
//! stages), and judged by the quality of decoded images over randomly fabricated units
//! ([`eval`]).
//!
//! One iteration: `samples` training crops ([`crate::image::source`]: dead leaves by default, or
//! random flipped blocks of a folder of photographs), crop `j`
//! imaged through its own lens (the nominal design in stage 1, a random tolerance pattern in
//! stage 2) at field `j mod grid²` of the PSF grid, by that field's RGB PSF plus Gaussian noise
//! ([`crate::image::render`]); the decoder reconstructs every crop and the image loss is averaged
//! over the batch. The gradients meet at one seam ([`PatternObjective`]): reverse mode through
//! the decoder and the rendering gives dL/dPSF for each crop's PSF, and the lens gradient is
//! the forward-mode (dual number) derivative of `<dL/dPSF, PSF(θ)>`, i.e. Jᵀ dL/dPSF, traced
//! through the same rays as the PSF that blurred the crop. Nothing else knows both halves.

pub mod eval;
pub mod html;
pub mod study;

use crate::analysis::SpotMoments;
use crate::decoder::{Crop, Decoder, DecoderKind, ImageLossWeights};
use crate::error::{Error, Result};
use crate::image::render::{blur_patch, blur_patch_psf_adjoint, standard_normals, SensorNoise};
use crate::image::source::TrainImages;
use crate::lens::{Adjustments, Lens, Param, System};
use crate::optim::adam::{cosine_schedule, Adam};
use crate::optim::train::{design_variables, TrainConfig};
use crate::optim::GRAD_WIDTH;
use crate::optim::{
    gradient, gradient_with_unit, param_value, set_param, spot_sum, Objective, SpotMeasure,
};
use crate::psf::{
    grid_fields, psf_of, psf_of_launched, psf_similarity, psf_similarity_of, PsfCentre, PsfOptions,
};
use crate::trace::{Bundles, Field, Pupil, PupilPattern, TraceOptions, Traceable};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// What a training phase optimizes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Phase {
    /// Stage 1 of the paper (and the conventional design's continuation): lens and decoder on
    /// the nominal lens, no tolerances.
    Nominal,
    /// Stage 2: lens and decoder with random tolerance patterns in the loop.
    Tolerance,
    /// The paper's decoder-only ablation: the lens is frozen, the decoder trains with random
    /// tolerance patterns.
    DecoderOnly,
    /// The paper's optics-only ablation: the decoder is frozen, the lens trains with random
    /// tolerance patterns.
    OpticsOnly,
}

impl Phase {
    fn trains_lens(self) -> bool {
        self != Phase::DecoderOnly
    }
    fn trains_decoder(self) -> bool {
        self != Phase::OpticsOnly
    }
    fn samples_tolerances(self) -> bool {
        self != Phase::Nominal
    }
}

/// Settings of the image stages. Optics settings (tolerances, PSF grid and kernel, rays per PSF,
/// wavelengths, constraints, learning rates, seed) come from [`TrainConfig`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DeepConfig {
    /// Optics settings shared with the optics-only trainer.
    pub optics: TrainConfig,
    /// Side of each training crop, pixels (the paper: 256).
    pub crop_px: usize,
    /// Standard deviation of the additive Gaussian noise, in linear [0, 1] units (paper: 0.01).
    pub noise_sigma: f64,
    /// Electrons of a full well for photon shot noise on top of `noise_sigma`
    /// ([`SensorNoise`]); `None` (the paper): Gaussian noise alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub full_well_electrons: Option<f64>,
    /// The decoder.
    pub decoder: DecoderKind,
    /// Base width (channels of the first level) of the U-Net.
    pub unet_width: usize,
    /// Learning rate of the U-Net weights.
    pub lr_unet: f64,
    /// Learning rate of the Wiener filters' PSF estimates.
    pub lr_wiener_psf: f64,
    /// Learning rate of the Wiener filters' log regularization weights.
    pub lr_wiener_reg: f64,
    /// Factor on the optics learning rates of `optics` in the image phases (they fine-tune a
    /// focused design).
    pub optics_lr_scale: f64,
    /// Image-loss weights.
    pub loss: ImageLossWeights,
    /// Weight of the spot loss (per mm of mean spot distance) in the image phases.
    pub lambda_spot: f64,
    /// Weight of the PSF-similarity loss in the tolerance phase.
    pub lambda_psf: f64,
    /// Training images: dead leaves (default) or a folder of photographs.
    #[serde(default)]
    pub train_images: TrainImages,
    /// Refocus each sampled unit of the tolerance phases to its best RMS focus before imaging
    /// it (the assembly's focus compensator, as evaluation's `compensate_focus`). The refocus is
    /// a function of the design (each unit's best RMS focus for the lens being evaluated), and
    /// the lens gradient includes its derivative: `dL/dθ = ∂L/∂θ + ∂L/∂δ · dδ/dθ`, both by dual
    /// numbers ([`FocusObjective`]; holding the refocus fixed instead misses that term, which
    /// for the sensor distance is exactly −∂L/∂δ, and training then drifts out of focus).
    #[serde(default)]
    pub compensate_focus: bool,
}

impl DeepConfig {
    /// Defaults sized for a CPU (see the README's cost table): 64-pixel crops, 64 patterns per
    /// iteration, σ = 0.01, a Wiener + U-Net decoder of width 8.
    pub fn for_lens(lens: &Lens) -> DeepConfig {
        DeepConfig {
            optics: TrainConfig::for_lens(lens),
            crop_px: 64,
            noise_sigma: 0.01,
            full_well_electrons: None,
            decoder: DecoderKind::WienerUnet,
            unet_width: 8,
            lr_unet: 2e-3,
            lr_wiener_psf: 2e-5,
            lr_wiener_reg: 0.05,
            optics_lr_scale: 0.1,
            loss: ImageLossWeights::default(),
            lambda_spot: 0.1,
            lambda_psf: 0.01,
            train_images: TrainImages::default(),
            compensate_focus: false,
        }
    }

    /// The sensor noise of the captures: `noise_sigma` and `full_well_electrons`.
    pub fn sensor(&self) -> SensorNoise {
        SensorNoise {
            sigma: self.noise_sigma,
            full_well_electrons: self.full_well_electrons,
        }
    }

    /// Checks the settings.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] naming the setting.
    pub fn validate(&self) -> Result<()> {
        self.optics.validate()?;
        if !(8..=1024).contains(&self.crop_px) || self.crop_px % 8 != 0 {
            return Err(Error::argument(format!(
                "crop {} px: give a multiple of 8 from 8 to 1024",
                self.crop_px
            )));
        }
        self.sensor().validate()?;
        for (what, v) in [
            ("lambda_spot", self.lambda_spot),
            ("lambda_psf", self.lambda_psf),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                return Err(Error::argument(format!(
                    "{what} {v}: must be zero or positive"
                )));
            }
        }
        for (what, v) in [
            ("lr_unet", self.lr_unet),
            ("lr_wiener_psf", self.lr_wiener_psf),
            ("lr_wiener_reg", self.lr_wiener_reg),
            ("optics_lr_scale", self.optics_lr_scale),
        ] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(Error::argument(format!("{what} {v}: must be positive")));
            }
        }
        if !(1..=256).contains(&self.unet_width) {
            return Err(Error::argument(format!(
                "U-Net width {}: give 1 to 256",
                self.unet_width
            )));
        }
        Ok(())
    }
}

/// A lens and its decoder: what deep optics designs and what evaluation judges.
#[derive(Clone, Debug)]
pub struct Design {
    /// The lens.
    pub lens: Lens,
    /// The decoder trained with it.
    pub decoder: Decoder,
}

/// The joint trainer's state: enough to continue exactly.
#[derive(Clone, Debug)]
pub struct DeepState {
    /// Settings.
    pub config: DeepConfig,
    /// The current design.
    pub design: Design,
    /// Design variables of the lens.
    pub vars: Vec<Param>,
    /// Adam over the lens variables (fresh at each phase).
    pub adam_lens: Adam,
    /// Adam over the decoder parameters (kept across phases).
    pub adam_decoder: Adam,
    /// The phase being run.
    pub phase: Phase,
    /// Iterations of this phase.
    pub phase_iters: usize,
    /// Next iteration of this phase.
    pub phase_iter: usize,
    /// Iterations run before this phase (so that every iteration draws fresh crops and
    /// patterns).
    pub iter_offset: usize,
}

/// What one iteration measured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DeepLog {
    /// Global iteration (over all phases).
    pub iter: usize,
    /// Phase.
    pub phase: Phase,
    /// Mean image loss of the batch.
    pub image_loss: f64,
    /// PSNR of the decoded batch against the sharp crops (sRGB, dB).
    pub psnr_db: f64,
    /// Mean spot distance of the batch's bundles, µm.
    pub spot_um: f64,
    /// Mean PSF similarity to the nominal design (tolerance phases).
    pub psf_similarity: Option<f64>,
    /// PSNR of the validation batch ([`validation_psnr`]) after this iteration, dB, when it was
    /// measured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub val_psnr_db: Option<f64>,
}

impl DeepState {
    /// A state that starts `phase` for `iters` iterations from `design`, with a fresh decoder
    /// initialised from the lens' own PSFs when `decoder` is `None`.
    ///
    /// # Errors
    /// Invalid settings, ray-generation errors.
    pub fn new(
        config: DeepConfig,
        lens: Lens,
        decoder: Option<Decoder>,
        phase: Phase,
        iters: usize,
        iter_offset: usize,
    ) -> Result<DeepState> {
        config.validate()?;
        let decoder = match decoder {
            Some(d) => d,
            None => {
                let psfs = nominal_psf_map(&lens, &config.optics, config.optics.psf_spp.max(2048))?;
                Decoder::new(
                    config.decoder,
                    config.optics.psf_grid,
                    config.optics.psf_ks,
                    &psfs,
                    config.sensor().typical_std(),
                    config.unet_width,
                    config.optics.seed,
                )?
            }
        };
        let vars = design_variables(&lens);
        let adam_lens = Adam::new(lens_learning_rates(&lens, &vars, &config));
        let adam_decoder = Adam::new(decoder.learning_rates(
            config.lr_wiener_psf,
            config.lr_wiener_reg,
            config.lr_unet,
        ));
        Ok(DeepState {
            config,
            design: Design { lens, decoder },
            vars,
            adam_lens,
            adam_decoder,
            phase,
            phase_iters: iters,
            phase_iter: 0,
            iter_offset,
        })
    }

    /// Switches to `phase` for `iters` iterations, keeping the design and the decoder's
    /// optimizer state; the lens optimizer starts afresh.
    pub fn start_phase(&mut self, phase: Phase, iters: usize) {
        self.iter_offset += self.phase_iter;
        self.phase = phase;
        self.phase_iters = iters;
        self.phase_iter = 0;
        self.adam_lens = Adam::new(lens_learning_rates(
            &self.design.lens,
            &self.vars,
            &self.config,
        ));
    }

    /// True when the phase has run all its iterations.
    pub fn done(&self) -> bool {
        self.phase_iter >= self.phase_iters
    }

    /// The state in serializable form (for checkpoints).
    pub fn to_saved(&self) -> SavedState {
        SavedState {
            config: self.config.clone(),
            lens_json: crate::lens::json::to_string(&self.design.lens),
            decoder: self.design.decoder.clone(),
            vars: self.vars.clone(),
            adam_lens: self.adam_lens.clone(),
            adam_decoder: self.adam_decoder.clone(),
            phase: self.phase,
            phase_iters: self.phase_iters,
            phase_iter: self.phase_iter,
            iter_offset: self.iter_offset,
        }
    }

    /// The state saved by [`DeepState::to_saved`], exactly (a folder of training images is read
    /// again).
    ///
    /// # Errors
    /// An unreadable lens, invalid settings, a folder of training images that cannot be read.
    pub fn from_saved(s: SavedState) -> Result<DeepState> {
        let mut config = s.config;
        config.validate()?;
        let min_side = config.crop_px + config.optics.psf_ks - 1;
        config.train_images.reload(min_side)?;
        let lens = crate::lens::json::from_str(&s.lens_json)?;
        if s.adam_decoder.m.len() != s.decoder.params().len() || s.vars.len() != s.adam_lens.m.len()
        {
            return Err(Error::invalid(
                "checkpoint: optimizer state does not match the parameters",
            ));
        }
        Ok(DeepState {
            config,
            design: Design {
                lens,
                decoder: s.decoder,
            },
            vars: s.vars,
            adam_lens: s.adam_lens,
            adam_decoder: s.adam_decoder,
            phase: s.phase,
            phase_iters: s.phase_iters,
            phase_iter: s.phase_iter,
            iter_offset: s.iter_offset,
        })
    }
}

/// A [`DeepState`] as a checkpoint stores it: the lens as DeepLens JSON text (exact), every
/// other field as it is.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SavedState {
    /// Settings.
    pub config: DeepConfig,
    /// The lens, DeepLens JSON.
    pub lens_json: String,
    /// The decoder.
    pub decoder: Decoder,
    /// Design variables.
    pub vars: Vec<Param>,
    /// Adam over the lens variables.
    pub adam_lens: Adam,
    /// Adam over the decoder parameters.
    pub adam_decoder: Adam,
    /// Phase.
    pub phase: Phase,
    /// Iterations of the phase.
    pub phase_iters: usize,
    /// Next iteration of the phase.
    pub phase_iter: usize,
    /// Iterations before the phase.
    pub iter_offset: usize,
}

fn lens_learning_rates(lens: &Lens, vars: &[Param], cfg: &DeepConfig) -> Vec<f64> {
    let last = lens.surfaces.len() - 1;
    let o = &cfg.optics;
    vars.iter()
        .map(|p| {
            cfg.optics_lr_scale
                * match p {
                    Param::Curvature(_) => o.lr_curvature,
                    Param::Gap(i) if *i == last => o.lr_image,
                    _ => o.lr_gap,
                }
        })
        .collect()
}

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
    let ks2 = opts.ks * opts.ks;
    let nc = wavelengths_nm.len();
    let mut out = vec![0f32; grid * grid * nc * ks2];
    for (c, &wl) in wavelengths_nm.iter().enumerate() {
        let map = crate::psf::psf_map(lens, sys, grid, wl, opts)?;
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

/// The nominal lens' RGB PSF map with `spp` rays per PSF (used to initialise a decoder).
fn nominal_psf_map(lens: &Lens, cfg: &TrainConfig, spp: usize) -> Result<Vec<f32>> {
    let opts = psf_options(lens, cfg.psf_ks, spp, cfg.seed);
    rgb_psf_map(
        lens,
        &lens.compile(),
        cfg.psf_grid,
        &cfg.wavelengths_nm,
        &opts,
    )
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
        let optics = self.psf_rays.optics(lift);
        let design = self.similarity.then(|| self.psf_rays.launch.design(lift));
        let at = |s: &System<S>, k: usize| {
            psf_of_launched(s, &self.psf_rays, k, optics.as_ref(), &self.psf, self.trace).0
        };
        let mut sim = S::cst(0.0);
        for k in 0..self.psf_rays.len() {
            let p = at(sys, k);
            if let Some(d) = &design {
                sim += psf_similarity_of(&at(d, k), &p, self.psf.ks);
            }
            for (g, v) in self.image_grad[k].iter().zip(&p) {
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

/// One training crop of an iteration, everything drawn: its tile, tolerance pattern, rays,
/// sharp image (with the halo the blur needs) and noise. Replaying a batch with another lens or
/// decoder changes nothing else, so its loss is a deterministic function of the design (what the
/// gradient checks difference).
#[derive(Clone, Debug)]
pub struct BatchCrop {
    /// PSF tile (field of the grid).
    pub tile: usize,
    /// The crop's tolerance pattern (none in the nominal phase).
    pub pattern: Option<crate::tolerance::Perturbation>,
    /// Refocus bundles when the crop's unit is refocused (`compensate_focus` in a tolerance
    /// phase), launched from the design at the start of the iteration.
    pub refocus: Option<Arc<FocusObjective>>,
    /// Rays of its RGB PSF, launched from the design at the start of the iteration.
    pub rays: Bundles,
    /// Spot bundles at its field (likewise).
    pub spot: Bundles,
    /// Nominal-design PSFs (the similarity term's constant reference; tolerance phases only).
    pub ideal: Vec<Vec<f64>>,
    /// Sharp image with a halo of (ks - 1) / 2 pixels, 3 planes of (crop + ks - 1)².
    pub xpad: Vec<f32>,
    /// Standard normal samples of the noise of its capture, 3 planes of crop²
    /// ([`SensorNoise::apply`]).
    pub noise: Vec<f32>,
}

/// The crops of one iteration.
#[derive(Clone, Debug)]
pub struct Batch {
    /// Global iteration.
    pub iter: usize,
    /// The crops.
    pub crops: Vec<BatchCrop>,
    /// PSF settings (rays of this iteration).
    pub psf: PsfOptions,
    /// Trace options.
    pub trace: TraceOptions,
}

/// Draws the batch of global iteration `it` for `lens`: crop `j` at tile `j mod grid²`, its
/// pattern, training crop and noise from (seed, it · samples + j).
///
/// # Errors
/// Ray-generation errors; invalid patterns.
pub fn draw_batch(cfg: &DeepConfig, lens: &Lens, phase: Phase, it: usize) -> Result<Batch> {
    let o = &cfg.optics;
    let fields = grid_fields(lens, o.psf_grid);
    let trace = TraceOptions {
        apertures: o.apertures,
    };
    let psf = psf_options(
        lens,
        o.psf_ks,
        o.psf_spp,
        o.seed ^ (it as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
    );
    let nominal = lens.compile();
    // One set of refocus bundles for the batch, shared by its refocused crops.
    let focus = if phase.samples_tolerances() && cfg.compensate_focus {
        Some(Arc::new(FocusObjective::new(lens, cfg.optics.apertures)?))
    } else {
        None
    };
    let (c, ks) = (cfg.crop_px, o.psf_ks);
    let side = c + ks - 1;
    let n = o.samples;
    let crops = (0..n)
        .into_par_iter()
        .map(|j| -> Result<BatchCrop> {
            let stream = (it * n + j) as u64;
            let tile = j % fields.len();
            let pattern = if phase.samples_tolerances() {
                Some(o.spec.sample(lens, o.seed, stream)?)
            } else {
                None
            };
            let refocus = if pattern.is_some() {
                focus.clone()
            } else {
                None
            };
            let pairs: Vec<(Field, f64)> = o
                .wavelengths_nm
                .iter()
                .map(|&w| (fields[tile], w))
                .collect();
            let rays = Bundles::pairs(lens, &pairs, &psf.pupil)?;
            let ideal = if phase.samples_tolerances() {
                (0..pairs.len())
                    .map(|k| psf_of(&nominal, &rays, k, &psf, trace).0)
                    .collect()
            } else {
                Vec::new()
            };
            let spot = Bundles::new(
                lens,
                &[fields[tile]],
                &o.wavelengths_nm,
                &Pupil::grid((o.spot_grid / 2).max(2)),
            )?;
            let xpad = cfg.train_images.crop(side, o.seed, stream)?.data;
            let noise = standard_normals(3 * c * c, o.seed ^ 0x6e_6f69_7365, stream);
            Ok(BatchCrop {
                tile,
                pattern,
                refocus,
                rays,
                spot,
                ideal,
                xpad,
                noise,
            })
        })
        .collect::<Result<_>>()?;
    Ok(Batch {
        iter: it,
        crops,
        psf,
        trace,
    })
}

/// How a fabricated unit is refocused (training and evaluation alike): best RMS focus over
/// the fields 0, 0.7 and 1 at the lens's RGB wavelengths, a 16 x 16 pupil grid, apertures on.
pub fn refocus_options(lens: &Lens) -> crate::tolerance::analysis::McOptions {
    crate::tolerance::analysis::McOptions {
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
fn crop_lens(lens: &Lens, bc: &BatchCrop) -> Result<(Lens, Adjustments)> {
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

/// What a batch evaluation gives.
#[derive(Clone, Debug)]
pub struct BatchEval {
    /// Total loss: mean image loss + the spot and similarity terms (batch means).
    pub loss: f64,
    /// Mean image loss.
    pub image_loss: f64,
    /// Batch PSNR, dB.
    pub psnr_db: f64,
    /// Mean spot distance, µm.
    pub spot_um: f64,
    /// Mean PSF similarity (tolerance phases).
    pub psf_similarity: Option<f64>,
    /// dL/dθ over the lens variables (empty unless asked).
    pub dlens: Vec<f64>,
    /// dL/dφ over the decoder parameters.
    pub ddecoder: Vec<f64>,
}

/// Evaluates the batch with `lens` and `decoder`: renders every crop through its own PSF (the
/// crop's pattern applied to `lens`, traced with the batch's rays), decodes, scores; with
/// `vars`, also the exact gradient with respect to those lens variables (dual numbers through
/// [`PatternObjective`]).
///
/// # Errors
/// A crop whose PSF receives no ray; decoder errors.
pub fn eval_batch(
    cfg: &DeepConfig,
    batch: &Batch,
    lens: &Lens,
    decoder: &Decoder,
    vars: Option<&[Param]>,
) -> Result<BatchEval> {
    let o = &cfg.optics;
    let (c, ks) = (cfg.crop_px, o.psf_ks);
    let n = batch.crops.len();
    let (psf, trace) = (batch.psf, batch.trace);
    // 1. Each crop's PSFs (values) and capture.
    let sensor = cfg.sensor();
    // Per crop: its capture, mean spot (mm), PSF similarity and the noise's dy/db.
    let rendered: Vec<(Crop, f64, f64, Option<Vec<f32>>)> = batch
        .crops
        .par_iter()
        .enumerate()
        .map(|(j, bc)| -> Result<_> {
            let (plens, adj) = crop_lens(lens, bc)?;
            let sys: System<f64> = System::compile(&plens, &adj, &|_, v| v);
            let psfs: Vec<Vec<f64>> = (0..bc.rays.len())
                .map(|k| psf_of(&sys, &bc.rays, k, &psf, trace).0)
                .collect();
            for (k, p) in psfs.iter().enumerate() {
                crate::psf::check_landed(
                    p,
                    &format!(
                        "iteration {}, crop {j}, {} nm",
                        batch.iter, bc.rays.sets[k].wavelength_nm
                    ),
                )?;
            }
            let psf32: Vec<f32> = psfs.iter().flatten().map(|&v| v as f32).collect();
            let mut y = blur_patch(&bc.xpad, c, c, &psf32, ks)?;
            // dy/db of the noise, for the lens gradient (shot noise only: else 1).
            let slope = sensor.slope(&y, &bc.noise);
            sensor.apply(&mut y, &bc.noise);
            let x = crop_centre(&bc.xpad, c + ks - 1, (ks - 1) / 2, c);
            let spot_mm = spot_sum(&bc.spot, &sys, &|_, v| v, SpotMeasure::Mean, trace)
                / bc.spot.len().max(1) as f64;
            let sim = if bc.ideal.is_empty() {
                1.0
            } else {
                bc.ideal
                    .iter()
                    .zip(&psfs)
                    .map(|(i, p)| psf_similarity(i, p, ks))
                    .sum::<f64>()
                    / bc.ideal.len() as f64
            };
            let crop = Crop {
                tile: bc.tile,
                y,
                x,
                w: c,
                h: c,
            };
            Ok((crop, spot_mm, sim, slope))
        })
        .collect::<Result<_>>()?;
    let crops: Vec<Crop> = rendered.iter().map(|r| r.0.clone()).collect();
    // 2. The decoder, forward and backward.
    let out = decoder.train_batch(&crops, &cfg.loss)?;
    let inv = 1.0 / n as f64;
    let spot_mm: f64 = rendered.iter().map(|r| r.1).sum::<f64>() * inv;
    let sim: f64 = rendered.iter().map(|r| r.2).sum::<f64>() * inv;
    let tol = batch.crops.iter().any(|b| !b.ideal.is_empty());
    let loss = out.loss
        + cfg.lambda_spot * spot_mm
        + if tol {
            cfg.lambda_psf * (1.0 - sim)
        } else {
            0.0
        };
    // 3. The lens gradient: dL/dPSF of each crop, then Jᵀ dL/dPSF by dual numbers.
    let dlens = match vars {
        None => Vec::new(),
        Some(vars) => {
            let ks2 = ks * ks;
            let per: Vec<Vec<f64>> = batch
                .crops
                .par_iter()
                .zip(out.dy.par_iter())
                .zip(rendered.par_iter())
                .map(|((bc, dy), r)| -> Result<Vec<f64>> {
                    // Through the noise: dL/db = dL/dy · dy/db (shot noise scales with b).
                    let dy_clean: Vec<f32>;
                    let dy = match &r.3 {
                        None => dy,
                        Some(slope) => {
                            dy_clean = dy.iter().zip(slope).map(|(a, b)| a * b).collect();
                            &dy_clean
                        }
                    };
                    let g = blur_patch_psf_adjoint(&bc.xpad, c, c, ks, dy)?;
                    let obj = PatternObjective {
                        spot: bc.spot.clone(),
                        psf_rays: bc.rays.clone(),
                        psf,
                        similarity: !bc.ideal.is_empty(),
                        image_grad: g
                            .chunks(ks2)
                            .map(|ch| ch.iter().map(|&v| v as f64).collect())
                            .collect(),
                        weight: inv,
                        lambda_spot: cfg.lambda_spot,
                        lambda_psf: cfg.lambda_psf,
                        trace,
                    };
                    let (plens, adj) = crop_lens(lens, bc)?;
                    let (Some(pattern), Some(focus)) = (&bc.pattern, &bc.refocus) else {
                        return Ok(gradient::<_, GRAD_WIDTH>(&obj, &plens, &adj, vars)?.1);
                    };
                    // The refocus δ moves the unit's sensor along z (patterns do not tilt the
                    // image plane), as the unit's last gap does: ∂L/∂δ is the derivative in that
                    // gap with the design (launch, reference PSFs) held.
                    let last = Param::Gap(plens.surfaces.len() - 1);
                    let g = gradient_with_unit::<_, GRAD_WIDTH>(&obj, &plens, &adj, vars, last)?.1;
                    let dl_ddelta = g[vars.len()];
                    let (ul, ua) = unit_lens(lens, pattern, None)?;
                    let dd = gradient::<_, GRAD_WIDTH>(focus.as_ref(), &ul, &ua, vars)?.1;
                    Ok((0..vars.len()).map(|k| g[k] + dl_ddelta * dd[k]).collect())
                })
                .collect::<Result<_>>()?;
            let mut g = vec![0.0; vars.len()];
            for gj in &per {
                for (a, b) in g.iter_mut().zip(gj) {
                    *a += b;
                }
            }
            g
        }
    };
    Ok(BatchEval {
        loss,
        image_loss: out.loss,
        psnr_db: out.psnr_db,
        spot_um: spot_mm * 1e3,
        psf_similarity: tol.then_some(sim),
        dlens,
        ddecoder: out.dparams,
    })
}

/// The centre `c x c` block (offset `off`) of a 3-plane square image of side `side`.
fn crop_centre(xpad: &[f32], side: usize, off: usize, c: usize) -> Vec<f32> {
    let mut x = Vec::with_capacity(3 * c * c);
    for ch in 0..3 {
        for r in 0..c {
            let s = ch * side * side + (r + off) * side + off;
            x.extend_from_slice(&xpad[s..s + c]);
        }
    }
    x
}

/// Runs one iteration of the current phase and returns its log. Crops, patterns, noise and
/// pupil samples derive from (seed, global iteration, crop index): the same state gives the
/// same numbers whatever the thread count.
///
/// # Errors
/// Ray-generation errors; a crop whose PSF receives no ray; a non-finite loss.
pub fn step(state: &mut DeepState) -> Result<DeepLog> {
    let it = state.iter_offset + state.phase_iter;
    let phase = state.phase;
    let batch = draw_batch(&state.config, &state.design.lens, phase, it)?;
    let vars = phase.trains_lens().then_some(state.vars.as_slice());
    let e = eval_batch(
        &state.config,
        &batch,
        &state.design.lens,
        &state.design.decoder,
        vars,
    )?;
    if !e.loss.is_finite() {
        return Err(Error::numerical(format!(
            "iteration {it}: the loss is not finite"
        )));
    }
    let scale = cosine_schedule(state.phase_iter as u64, state.phase_iters as u64, 0.05);
    if phase.trains_lens() {
        let mut lens = state.design.lens.clone();
        let mut x: Vec<f64> = state
            .vars
            .iter()
            .map(|&p| param_value(&lens, p))
            .collect::<Result<_>>()?;
        state.adam_lens.step(&mut x, &e.dlens, scale);
        for (&p, &v) in state.vars.iter().zip(&x) {
            set_param(&mut lens, p, v)?;
        }
        if state.config.compensate_focus && phase.samples_tolerances() {
            refocus_design(&mut lens, state.config.optics.apertures)?;
        }
        crate::optim::train::project(&mut lens, &state.config.optics.constraints);
        state.design.lens = lens;
    }
    if phase.trains_decoder() {
        let mut params = state.design.decoder.params().to_vec();
        state.adam_decoder.step(&mut params, &e.ddecoder, scale);
        state.design.decoder.set_params(&params)?;
    }
    state.phase_iter += 1;
    Ok(DeepLog {
        iter: it,
        phase,
        image_loss: e.image_loss,
        psnr_db: e.psnr_db,
        spot_um: e.spot_um,
        psf_similarity: e.psf_similarity,
        val_psnr_db: None,
    })
}

/// Moves the sensor of `lens` to its own best RMS focus ([`FocusObjective`] on the lens without
/// a pattern). Training on refocused units leaves the design's sensor position free (each
/// unit's refocus cancels a move of the sensor exactly, so the loss of a drawn batch is flat in
/// it), so after each step of such a phase the design is put back at its best focus: the
/// design a user receives is a focused lens, and the reference of the PSF-similarity term (the
/// design's nominal PSFs, drawn with each batch) is that of the focused design, as the refocused
/// units it is compared with. Without it the reference stayed at the stage-1 sensor and the
/// similarity of refocused units to it was 0.16 instead of 0.87 (lens1).
///
/// # Errors
/// Ray-generation errors; a refocus that is not finite.
pub fn refocus_design(lens: &mut Lens, apertures: bool) -> Result<()> {
    let f = FocusObjective::new(lens, apertures)?;
    let d = crate::optim::value(&f, lens, &Adjustments::none(lens.surfaces.len()));
    if !d.is_finite() {
        return Err(Error::numerical("the design's best focus is not finite"));
    }
    let last = lens.surfaces.len() - 1;
    lens.surfaces[last].d_next_mm += d;
    Ok(())
}

/// Seed offset of the validation batch: its crops, patterns and noise are never trained on.
const VALIDATION_SEED: u64 = 0x7661_6c69_6461_7465;

/// PSNR (sRGB, dB) of the current design on a fixed validation batch: `samples` crops from the
/// training source, each through its own random fabricated unit (a pattern of the spec, refocused
/// when the config says so), drawn from a seed that training never uses. The same batch for
/// every branch and iteration of a run, so the curves compare.
///
/// # Errors
/// As [`eval_batch`].
pub fn validation_psnr(state: &DeepState) -> Result<f64> {
    let mut cfg = state.config.clone();
    cfg.optics.seed ^= VALIDATION_SEED;
    let batch = draw_batch(&cfg, &state.design.lens, Phase::Tolerance, 0)?;
    Ok(eval_batch(
        &cfg,
        &batch,
        &state.design.lens,
        &state.design.decoder,
        None,
    )?
    .psnr_db)
}
