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
    gradient, gradient_with_unit, param_value, set_param, spot_sum, DiffractionPsfs, Objective,
    SpotMeasure,
};
use crate::psf::{
    grid_fields, psf_of_launched, psf_similarity, psf_similarity_of, PsfCentre, PsfModel,
    PsfOptions,
};
use crate::trace::{Bundles, Field, Pupil, PupilPattern, TraceOptions, Traceable};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

mod batch;
mod objectives;
mod step;
pub use batch::*;
pub use objectives::*;
pub use step::*;

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
    /// The PSFs training renders with and differentiates: the rays' (the paper's) or
    /// diffraction PSFs ([`crate::optim::DiffractionPsfs`], exact in dual numbers too).
    #[serde(default, skip_serializing_if = "PsfModel::is_geometric")]
    pub psf: PsfModel,
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
            psf: PsfModel::Geometric,
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
        if !self.optics.loss.is_spot() {
            return Err(Error::argument(format!(
                "loss {}: the image stage trains its optics with the spot loss only",
                self.optics.loss.name()
            )));
        }
        if !(8..=1024).contains(&self.crop_px) || !self.crop_px.is_multiple_of(8) {
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
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Design {
    /// The lens (in checkpoints as DeepLens JSON text, `lens_json`: exact).
    #[serde(rename = "lens_json", with = "crate::lens::json::as_text")]
    pub lens: Lens,
    /// The decoder trained with it.
    pub decoder: Decoder,
}

/// The joint trainer's state: enough to continue exactly. Checkpoints store it as it is (the
/// design's fields inline, its lens as DeepLens JSON text); one read back is made ready to run
/// by [`DeepState::restored`].
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct DeepState {
    /// Settings.
    pub config: DeepConfig,
    /// The current design.
    #[serde(flatten)]
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
                let psfs = nominal_psf_map(
                    config.psf,
                    &lens,
                    &config.optics,
                    config.optics.psf_spp.max(2048),
                )?;
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

    /// A state read back from a checkpoint, checked and made ready to continue exactly: its
    /// settings validated, a folder of training images read again, the optimizers' sizes
    /// checked against the parameters.
    ///
    /// # Errors
    /// Invalid settings, a folder of training images that cannot be read, optimizer state that
    /// does not match the parameters.
    pub fn restored(mut self) -> Result<DeepState> {
        self.config.validate()?;
        let min_side = self.config.crop_px + self.config.optics.psf_ks - 1;
        self.config.train_images.reload(min_side)?;
        if self.adam_decoder.m.len() != self.design.decoder.params().len()
            || self.vars.len() != self.adam_lens.m.len()
        {
            return Err(Error::invalid(
                "checkpoint: optimizer state does not match the parameters",
            ));
        }
        Ok(self)
    }
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
