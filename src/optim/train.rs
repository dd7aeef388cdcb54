//! The paper's two-stage optimization: stage 1 pre-trains without tolerances on the spot loss;
//! stage 2 samples N tolerance patterns per iteration, traces each at its own field of the PSF
//! grid, and minimizes λ_spot L_spot + λ_psf L_psf. Both stages respect manufacturability
//! constraints (bounds by projection, edge thickness / total track / EFL by penalties).
//!
//! [`step`] runs one iteration on a [`TrainState`]; [`run_training`] runs them all as
//! `tolray train` does, with a log, checkpoints, a stop request and an exact resume, and
//! [`final_report`] evaluates the designs of a finished run on held-out tolerance patterns.

use super::adam::{cosine_schedule, Adam};
pub use super::run::{
    final_report, fmt_list, run_to_report, run_training, Checkpoints, DesignReport, RunControl,
    RunEnd, RunOutcome, TrainReport,
};
use super::{
    gradient, param_value, set_param, spot_size, spot_sum, value, MtfLoss, Objective, SpotMeasure,
    WavefrontLoss, GRAD_WIDTH,
};
use crate::error::{Error, Result};
use crate::lens::{Adjustments, Lens, Param, SurfaceRole, System};
use crate::psf::{
    grid_fields, psf_of, psf_of_launched, psf_similarity, psf_similarity_of, PsfCentre, PsfOptions,
};
use crate::real::Real;
use crate::tolerance::{MtfDirection, ToleranceSpec};
use crate::trace::{Bundles, Field, Pupil, PupilPattern, TraceOptions, Traceable};
use crate::wave::Sampling;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Which stage an iteration belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Stage {
    /// Stage 1: no tolerances, spot loss.
    Pretrain,
    /// Stage 2: tolerance-aware.
    Tolerance,
}

/// The optical term of the training loss.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OpticalLoss {
    /// The paper's: the spot size (RMS radius in stage 1, mean distance from the centroid in
    /// stage 2), mm.
    #[default]
    Spot,
    /// The RMS wavefront error to centroid over a pupil quadrature
    /// ([`crate::optim::WavefrontLoss`]), waves, times `mm_per_wave`: weighed as a spot, so that
    /// the PSF-similarity term and the constraints keep their balance.
    RmsWavefront {
        /// Millimetres of spot a wave of RMS wavefront error counts as.
        mm_per_wave: f64,
    },
    /// The diffraction MTF at one frequency ([`crate::optim::MtfLoss`]): `1 − MTF` averaged over
    /// fields and wavelengths, times `mm_per_unit`.
    Mtf {
        /// Frequency, cycles/mm.
        freq_lpmm: f64,
        /// Tangential, sagittal or their mean.
        direction: MtfDirection,
        /// Millimetres of spot a unit of lost modulation counts as.
        mm_per_unit: f64,
    },
}

impl OpticalLoss {
    /// What an iteration logs of the wave term's value `v` (none for the spot loss):
    /// `(RMS wavefront waves, MTF)`, the MTF being `1 − v`.
    fn logged(&self, v: Option<f64>) -> (Option<f64>, Option<f64>) {
        match self {
            OpticalLoss::Mtf { .. } => (None, v.map(|v| 1.0 - v)),
            _ => (v, None),
        }
    }

    /// The RMS wavefront loss of `lens` weighed as the RMS spot radius a pure defocus of the same
    /// RMS wavefront error gives: 4√6 · N · λ mm per wave (N the working F-number, λ the primary
    /// wavelength in mm), 0.023 mm for an f/4 lens in green light.
    ///
    /// ```
    /// use tolray::optim::train::OpticalLoss;
    /// let lens = tolray::Lens::load("lens1").unwrap();
    /// let OpticalLoss::RmsWavefront { mm_per_wave } = OpticalLoss::rms_wavefront_for(&lens).unwrap() else {
    ///     unreachable!()
    /// };
    /// assert!(mm_per_wave > 0.01 && mm_per_wave < 0.03);
    /// ```
    ///
    /// # Errors
    /// Paraxial errors; [`crate::ErrorKind::Argument`] for an afocal lens (no focus, no
    /// wavefront to train).
    pub fn rms_wavefront_for(lens: &Lens) -> Result<OpticalLoss> {
        let p = lens.paraxial(lens.primary_wavelength_nm)?;
        let n = p
            .working_fnum
            .filter(|v| v.is_finite() && *v > 0.0)
            .ok_or_else(|| {
                Error::argument(
                    "the lens is afocal: it has no focus, so no wavefront error to train",
                )
            })?;
        Ok(OpticalLoss::RmsWavefront {
            mm_per_wave: 4.0 * 6f64.sqrt() * n * lens.primary_wavelength_nm * 1e-6,
        })
    }

    /// The MTF loss at `freq_lpmm` cycles/mm along `direction`, weighed so that losing all
    /// modulation counts as a spot of half the frequency's period, `1 / (2ν)` mm (17 µm at
    /// 30 cycles/mm), near the spot sizes the spot loss trains: a blur about a period across
    /// wipes the frequency out.
    ///
    /// ```
    /// use tolray::optim::train::OpticalLoss;
    /// use tolray::tolerance::MtfDirection;
    /// let l = OpticalLoss::mtf_at(30.0, MtfDirection::Mean).unwrap();
    /// assert_eq!(l.name(), "mtf");
    /// assert!(OpticalLoss::mtf_at(0.0, MtfDirection::Mean).is_err());
    /// ```
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for a frequency that is not positive and finite.
    pub fn mtf_at(freq_lpmm: f64, direction: MtfDirection) -> Result<OpticalLoss> {
        if !(freq_lpmm > 0.0 && freq_lpmm.is_finite()) {
            return Err(Error::argument(format!(
                "MTF loss at {freq_lpmm} cycles/mm: give a positive, finite frequency"
            )));
        }
        Ok(OpticalLoss::Mtf {
            freq_lpmm,
            direction,
            mm_per_unit: 0.5 / freq_lpmm,
        })
    }

    /// True for the paper's spot loss (the default, left out of saved settings).
    pub fn is_spot(&self) -> bool {
        *self == OpticalLoss::Spot
    }

    /// The name `tolray train --loss` takes.
    pub fn name(&self) -> &'static str {
        match self {
            OpticalLoss::Spot => "spot",
            OpticalLoss::RmsWavefront { .. } => "rms-wavefront",
            OpticalLoss::Mtf { .. } => "mtf",
        }
    }
}

/// Manufacturability constraints.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Constraints {
    /// Minimum centre thickness of glass, mm.
    pub min_center_thickness_mm: f64,
    /// Minimum edge thickness of glass (at the smaller clear aperture), mm.
    pub min_edge_thickness_mm: f64,
    /// Minimum air gap (centre and edge), mm.
    pub min_air_gap_mm: f64,
    /// Maximum total track (first vertex to image), mm.
    pub max_total_track_mm: Option<f64>,
    /// Target effective focal length, mm (penalized relative deviation).
    pub target_efl_mm: Option<f64>,
    /// Penalty weight of the thickness, gap and track constraints (per mm² of violation).
    pub weight: f64,
    /// Penalty weight of the squared relative EFL deviation. The default (1e4) holds the EFL to
    /// about 0.1 % against the spot loss of a typical design.
    #[serde(default = "default_efl_weight")]
    pub efl_weight: f64,
}

fn default_efl_weight() -> f64 {
    1e4
}

/// The stage-2 learning-rate factor of checkpoints written before it existed.
fn default_tolerance_lr_scale() -> f64 {
    1.0
}

impl Default for Constraints {
    fn default() -> Self {
        Constraints {
            min_center_thickness_mm: 0.5,
            min_edge_thickness_mm: 0.3,
            min_air_gap_mm: 0.1,
            max_total_track_mm: None,
            target_efl_mm: None,
            weight: 10.0,
            efl_weight: default_efl_weight(),
        }
    }
}

/// Training settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    /// Iterations of stage 1.
    pub pretrain_iters: usize,
    /// Iterations of stage 2.
    pub tolerance_iters: usize,
    /// Tolerance patterns per stage-2 iteration.
    pub samples: usize,
    /// Seed (patterns and pupil samples derive from it and the iteration).
    pub seed: u64,
    /// Tolerances sampled in stage 2.
    pub spec: ToleranceSpec,
    /// Learning rate of curvatures, 1/mm.
    pub lr_curvature: f64,
    /// Learning rate of gaps, mm.
    pub lr_gap: f64,
    /// Learning rate of the image distance, mm.
    pub lr_image: f64,
    /// Factor on every learning rate in stage 2, which fine-tunes the stage-1 design: Adam's
    /// first steps move every variable by about its learning rate, which at the stage-1 rates
    /// throws lens1 out of focus (a spot of ~150 um) before stage 2 recovers.
    #[serde(default = "default_tolerance_lr_scale")]
    pub tolerance_lr_scale: f64,
    /// Weight of the spot loss (per mm of spot size).
    pub lambda_spot: f64,
    /// Weight of the PSF-similarity loss.
    pub lambda_psf: f64,
    /// Fields of the stage-1 spot loss.
    pub fields: Vec<Field>,
    /// Wavelengths, nm (RGB).
    pub wavelengths_nm: Vec<f64>,
    /// Pupil grid size of the spot loss.
    pub spot_grid: usize,
    /// PSF grid per side (stage-2 fields).
    pub psf_grid: usize,
    /// PSF kernel size.
    pub psf_ks: usize,
    /// Rays per PSF.
    pub psf_spp: usize,
    /// Constraints.
    pub constraints: Constraints,
    /// Clip at apertures.
    pub apertures: bool,
    /// The optical term of both stages (the spot term's place; its weight stays λ_spot in
    /// stage 2).
    #[serde(default, skip_serializing_if = "OpticalLoss::is_spot")]
    pub loss: OpticalLoss,
}

impl TrainConfig {
    /// Defaults for `lens`: RGB from the lens, fields 0/0.5/0.7/1, 16x16 spot grid, 8x8 PSF
    /// grid of 51x51 kernels with 256 rays, 64 patterns of the paper's tolerances, stage 2 at a
    /// tenth of the stage-1 learning rates.
    pub fn for_lens(lens: &Lens) -> TrainConfig {
        TrainConfig {
            pretrain_iters: 100,
            tolerance_iters: 100,
            samples: 64,
            seed: 0,
            spec: ToleranceSpec::default(),
            lr_curvature: 2e-4,
            lr_gap: 0.01,
            lr_image: 0.05,
            tolerance_lr_scale: 0.1,
            lambda_spot: 10.0,
            lambda_psf: 1.0,
            fields: [0.0, 0.5, 0.7, 1.0].map(Field::fraction).to_vec(),
            wavelengths_nm: lens.rgb_wavelengths_nm.to_vec(),
            spot_grid: 16,
            psf_grid: 8,
            psf_ks: 51,
            psf_spp: 256,
            constraints: Constraints::default(),
            apertures: true,
            loss: OpticalLoss::Spot,
        }
    }
}

impl TrainConfig {
    /// Checks every setting a user can give: positive finite learning rates and weights,
    /// non-negative finite loss weights, sizes within what a run can afford, and a positive
    /// finite track or focal length where set.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] naming the setting and its value.
    pub fn validate(&self) -> Result<()> {
        let bad =
            |what: &str, v: f64, need: &str| Err(Error::argument(format!("{what} {v}: {need}")));
        for (what, v) in [
            ("lr_curvature", self.lr_curvature),
            ("lr_gap", self.lr_gap),
            ("lr_image", self.lr_image),
            ("tolerance_lr_scale", self.tolerance_lr_scale),
        ] {
            if !(v > 0.0 && v.is_finite()) {
                return bad(what, v, "must be positive and finite");
            }
        }
        for (what, v) in [
            ("lambda_spot", self.lambda_spot),
            ("lambda_psf", self.lambda_psf),
            ("constraint weight", self.constraints.weight),
            ("EFL weight", self.constraints.efl_weight),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                return bad(what, v, "must be zero or positive, and finite");
            }
        }
        for (what, v) in [
            ("max_total_track_mm", self.constraints.max_total_track_mm),
            ("target_efl_mm", self.constraints.target_efl_mm),
        ] {
            if let Some(v) = v {
                if !(v > 0.0 && v.is_finite()) {
                    return bad(what, v, "must be positive and finite (mm)");
                }
            }
        }
        for (what, v, lo, hi) in [
            ("samples", self.samples, 1, 4096),
            ("spot_grid", self.spot_grid, 1, 256),
            ("psf_grid", self.psf_grid, 1, 64),
            ("psf_spp", self.psf_spp, 1, 1 << 20),
            ("pretrain_iters", self.pretrain_iters, 0, 10_000_000),
            ("tolerance_iters", self.tolerance_iters, 0, 10_000_000),
        ] {
            if v < lo || v > hi {
                return bad(what, v as f64, &format!("give {lo} to {hi}"));
            }
        }
        if self.psf_ks < 3 || self.psf_ks.is_multiple_of(2) || self.psf_ks > 255 {
            return bad("psf_ks", self.psf_ks as f64, "must be odd, 3 to 255");
        }
        if let OpticalLoss::RmsWavefront { mm_per_wave } = self.loss {
            if !(mm_per_wave > 0.0 && mm_per_wave.is_finite()) {
                return bad(
                    "the wavefront loss' mm_per_wave",
                    mm_per_wave,
                    "must be positive and finite",
                );
            }
        }
        if let OpticalLoss::Mtf {
            freq_lpmm,
            mm_per_unit,
            ..
        } = self.loss
        {
            for (what, v) in [
                ("the MTF loss' frequency (cycles/mm)", freq_lpmm),
                ("the MTF loss' mm_per_unit", mm_per_unit),
            ] {
                if !(v > 0.0 && v.is_finite()) {
                    return bad(what, v, "must be positive and finite");
                }
            }
        }
        if self.fields.is_empty() || self.wavelengths_nm.is_empty() {
            return Err(Error::argument(
                "training needs at least one field and one wavelength",
            ));
        }
        for &w in &self.wavelengths_nm {
            crate::lens::material::check_wavelength_nm(w)?;
        }
        Ok(())
    }
}

/// The design variables of a lens: every refracting surface's curvature (not an ideal thin
/// lens, which is flat) and every gap (the last is the image distance); the stop's size and the
/// glasses stay fixed.
pub fn design_variables(lens: &Lens) -> Vec<Param> {
    let mut v = Vec::new();
    for (i, s) in lens.surfaces.iter().enumerate() {
        if s.role == SurfaceRole::Refractive
            && !matches!(s.shape, crate::lens::Shape::Paraxial { .. })
        {
            v.push(Param::Curvature(i));
        }
    }
    v.extend((0..lens.surfaces.len()).map(Param::Gap));
    v
}

/// Constraint penalties (and the EFL target) evaluated in `S` on the compiled nominal geometry.
fn penalties<S: Real>(
    lens: &Lens,
    sys: &System<S>,
    lift: &dyn Fn(Param, S) -> S,
    c: &Constraints,
) -> S {
    let mut p = S::cst(0.0);
    let n = lens.surfaces.len();
    let hinge = |x: S| if x.value() > 0.0 { x * x } else { S::cst(0.0) };
    let dirs = lens.travel_directions();
    // Edge thickness / edge air gap at the smaller clear aperture of each neighbouring pair,
    // along the light's path (toward −z after an odd number of mirrors).
    for i in 0..n - 1 {
        let (a, b) = (&sys.rows[i], &sys.rows[i + 1]);
        let r2 = S::cst(
            lens.surfaces[i]
                .semi_aperture_mm
                .min(lens.surfaces[i + 1].semi_aperture_mm)
                .powi(2),
        );
        let sag = |row: &crate::lens::SurfaceRow<S>| crate::trace::kernel_sag(row, r2);
        let edge = b.pos.z - a.pos.z + sag(b) - sag(a);
        let edge = if dirs[i + 1] < 0.0 { -edge } else { edge };
        let min = if lens.surfaces[i].material.is_air() {
            c.min_air_gap_mm
        } else {
            c.min_edge_thickness_mm
        };
        p += hinge(S::cst(min) - edge);
    }
    if let Some(tt) = c.max_total_track_mm {
        p += hinge(sys.image.translation.z - S::cst(tt));
    }
    p *= S::cst(c.weight);
    if let Some(f) = c.target_efl_mm {
        let efl = crate::lens::paraxial::efl_lifted(lens, crate::lens::material::LAMBDA_D_NM, lift);
        let d = (efl - S::cst(f)) / S::cst(f);
        p += d * d * S::cst(c.efl_weight);
    }
    p
}

/// The wave term of a loss: the RMS wavefront error or the MTF loss.
enum WaveTerm {
    Rms(WavefrontLoss),
    Mtf(MtfLoss),
}

impl Objective for WaveTerm {
    fn eval<S: Traceable>(&self, sys: &System<S>, lift: &dyn Fn(Param, S) -> S) -> S {
        match self {
            WaveTerm::Rms(w) => w.eval(sys, lift),
            WaveTerm::Mtf(m) => m.eval(sys, lift),
        }
    }
}

/// Stage-1 objective: RMS spot (mm) averaged over fields and wavelengths, or a wave term
/// weighed as a spot ([`OpticalLoss`]), plus penalties.
struct PretrainObjective<'a> {
    lens: &'a Lens,
    bundles: Bundles,
    wave: Option<(WaveTerm, f64)>,
    trace: TraceOptions,
    constraints: &'a Constraints,
}

impl Objective for PretrainObjective<'_> {
    fn eval<S: Traceable>(&self, sys: &System<S>, lift: &dyn Fn(Param, S) -> S) -> S {
        let optical = match &self.wave {
            Some((w, mm_per_wave)) => w.eval(sys, lift) * S::cst(*mm_per_wave),
            None => {
                spot_sum(&self.bundles, sys, lift, SpotMeasure::Rms, self.trace)
                    * S::cst(1.0 / self.bundles.len() as f64)
            }
        };
        optical + penalties(self.lens, sys, lift, self.constraints)
    }
}

/// The wave term of `cfg` over `fields` × its wavelengths, launched from `lens`, with its
/// weight, or `None` for the spot loss.
fn wave_term(
    lens: &Lens,
    cfg: &TrainConfig,
    fields: &[Field],
    trace: TraceOptions,
) -> Result<Option<(WaveTerm, f64)>> {
    match cfg.loss {
        OpticalLoss::Spot => Ok(None),
        OpticalLoss::RmsWavefront { mm_per_wave } => {
            let w = WavefrontLoss::new(
                lens,
                fields,
                &cfg.wavelengths_nm,
                Sampling::default(),
                trace,
            )?;
            Ok(Some((WaveTerm::Rms(w), mm_per_wave)))
        }
        OpticalLoss::Mtf {
            freq_lpmm,
            direction,
            mm_per_unit,
        } => {
            let m = MtfLoss::new(
                lens,
                fields,
                &cfg.wavelengths_nm,
                freq_lpmm,
                direction,
                Sampling::Grid(crate::tolerance::criterion::MTF_GRID),
                trace,
            )?;
            Ok(Some((WaveTerm::Mtf(m), mm_per_unit)))
        }
    }
}

/// Stage-2 objective of one pattern at one field: λ_spot · mean spot + λ_psf · (1 − mean Sim),
/// the similarity to the design's own PSFs (which move with it).
struct PatternObjective<'a> {
    spot: Bundles,
    wave: Option<(WaveTerm, f64)>,
    psf_rays: Bundles,
    psf: PsfOptions,
    cfg: &'a TrainConfig,
}

impl Objective for PatternObjective<'_> {
    fn eval<S: Traceable>(&self, sys: &System<S>, lift: &dyn Fn(Param, S) -> S) -> S {
        let trace = TraceOptions {
            apertures: self.cfg.apertures,
        };
        let optics = self.psf_rays.optics(lift);
        let design = self.psf_rays.launch.design(lift);
        let mut sim = S::cst(0.0);
        for k in 0..self.psf_rays.len() {
            let at = |s: &System<S>| {
                psf_of_launched(s, &self.psf_rays, k, optics.as_ref(), &self.psf, trace).0
            };
            sim += psf_similarity_of(&at(&design), &at(sys), self.psf.ks);
        }
        let nw = S::cst(1.0 / self.psf_rays.len().max(1) as f64);
        let optical = match &self.wave {
            Some((w, mm_per_wave)) => {
                S::cst(self.cfg.lambda_spot * mm_per_wave) * w.eval(sys, lift)
            }
            None => {
                let spot = spot_sum(&self.spot, sys, lift, SpotMeasure::Mean, trace);
                S::cst(self.cfg.lambda_spot / self.spot.len().max(1) as f64) * spot
            }
        };
        optical + S::cst(self.cfg.lambda_psf) * (S::cst(1.0) - sim * nw)
    }
}

/// Training curves of the optics from a run's logs ([`crate::figures::training_curves`]): the
/// loss, the spot size and the PSF similarity per iteration, with the start of stage 2 marked.
#[must_use]
pub fn training_figure(logs: &[IterLog], title: &str) -> crate::figures::Figure {
    let rows = logs
        .iter()
        .map(|l| (l.iter as f64, l.loss, l.spot_um, l.psf_similarity))
        .collect();
    let stage2 = logs
        .iter()
        .find(|l| l.stage == Stage::Tolerance)
        .map(|l| l.iter as f64)
        .filter(|&i| i > 0.0);
    crate::figures::training_curves(rows, stage2, title)
}

/// What one iteration measured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IterLog {
    /// Global iteration number (from 0, over both stages).
    pub iter: usize,
    /// Stage.
    pub stage: Stage,
    /// Total loss.
    pub loss: f64,
    /// Mean spot size of the iteration's bundles, µm (RMS in stage 1, mean distance in stage 2).
    pub spot_um: f64,
    /// Mean PSF similarity (stage 2).
    pub psf_similarity: Option<f64>,
    /// Learning-rate scale of the schedule.
    pub lr_scale: f64,
    /// Mean RMS wavefront error to centroid of the iteration's fields (and, in stage 2,
    /// patterns), waves, with the wavefront loss ([`OpticalLoss::RmsWavefront`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wavefront_waves: Option<f64>,
    /// Mean diffraction MTF at the loss' frequency over the iteration's fields (and, in stage
    /// 2, patterns), with the MTF loss ([`OpticalLoss::Mtf`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mtf: Option<f64>,
}

/// The optimizer's full state, enough to continue exactly.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainState {
    /// Settings.
    pub config: TrainConfig,
    /// The current design (stored in checkpoints as DeepLens JSON text, `lens_json`).
    #[serde(rename = "lens_json", with = "crate::lens::json::as_text")]
    pub lens: Lens,
    /// Design variables.
    pub vars: Vec<Param>,
    /// Adam state of the current stage.
    pub adam: Adam,
    /// Next iteration to run (global).
    pub next_iter: usize,
    /// The design at the end of stage 1, if reached (`stage1_lens_json` in checkpoints).
    #[serde(
        rename = "stage1_lens_json",
        default,
        with = "crate::lens::json::as_text::option"
    )]
    pub stage1_lens: Option<Lens>,
}

impl TrainState {
    /// A fresh state for `lens`. The state holds the lens as its checkpoint restores it (what
    /// DeepLens JSON keeps of it), so that a resumed run traces what an uninterrupted one does.
    pub fn new(lens: &Lens, config: TrainConfig) -> TrainState {
        let lens = crate::lens::json::from_str(&crate::lens::json::to_string(lens))
            .unwrap_or_else(|_| lens.clone());
        let vars = design_variables(&lens);
        let adam = Adam::new(learning_rates(&lens, &vars, &config));
        TrainState {
            config,
            lens,
            vars,
            adam,
            next_iter: 0,
            stage1_lens: None,
        }
    }
    /// Total iterations of both stages.
    pub fn total_iters(&self) -> usize {
        self.config.pretrain_iters + self.config.tolerance_iters
    }
}

fn learning_rates(lens: &Lens, vars: &[Param], cfg: &TrainConfig) -> Vec<f64> {
    let last = lens.surfaces.len() - 1;
    vars.iter()
        .map(|p| match p {
            Param::Curvature(_) => cfg.lr_curvature,
            Param::Gap(i) if *i == last => cfg.lr_image,
            _ => cfg.lr_gap,
        })
        .collect()
}

/// Projects the variables back into their bounds: gaps at least their minimum along the light's
/// path (toward −z after an odd number of mirrors, where gaps are negative; a virtual image's
/// gap at least 1 mm on its own side), curvatures inside the rim of their clear aperture.
pub(crate) fn project(lens: &mut Lens, c: &Constraints) {
    let n = lens.surfaces.len();
    let dirs = lens.travel_directions();
    for i in 0..n {
        let s = &mut lens.surfaces[i];
        // A virtual image plane (the last gap against the travel) stays on its side.
        let dir = if i == n - 1 && s.d_next_mm * dirs[i + 1] < 0.0 {
            -dirs[i + 1]
        } else {
            dirs[i + 1]
        };
        let min = if i == n - 1 {
            1.0
        } else if s.material.is_air() {
            c.min_air_gap_mm
        } else {
            c.min_center_thickness_mm
        };
        s.d_next_mm = dir * (s.d_next_mm * dir).max(min);
        let cmax = 0.95 / s.semi_aperture_mm;
        s.c = s.c.clamp(-cmax, cmax);
    }
}

/// Runs one iteration on `state` and returns its log. Deterministic: patterns and pupil samples
/// come from (seed, iteration).
///
/// # Errors
/// Invalid designs (e.g. every ray lost) and ray-generation errors.
pub fn step(state: &mut TrainState) -> Result<IterLog> {
    let it = state.next_iter;
    let cfg = state.config.clone();
    let stage = if it < cfg.pretrain_iters {
        Stage::Pretrain
    } else {
        Stage::Tolerance
    };
    let (stage_it, stage_len) = match stage {
        Stage::Pretrain => (it, cfg.pretrain_iters),
        Stage::Tolerance => (it - cfg.pretrain_iters, cfg.tolerance_iters),
    };
    if stage == Stage::Tolerance && stage_it == 0 {
        // A new stage starts with fresh optimizer moments.
        state.adam = Adam::new(learning_rates(&state.lens, &state.vars, &cfg));
        state.stage1_lens.get_or_insert_with(|| state.lens.clone());
    }
    let mut lens = state.lens.clone();
    let trace = TraceOptions {
        apertures: cfg.apertures,
    };
    let (loss, grad, spot_um, sim, (wavefront_waves, mtf)) = match stage {
        Stage::Pretrain => {
            let bundles = Bundles::new(
                &lens,
                &cfg.fields,
                &cfg.wavelengths_nm,
                &Pupil::grid(cfg.spot_grid),
            )?;
            let obj = PretrainObjective {
                lens: &lens,
                bundles,
                wave: wave_term(&lens, &cfg, &cfg.fields, trace)?,
                trace,
                constraints: &cfg.constraints,
            };
            let adj = Adjustments::none(lens.surfaces.len());
            let (v, g) = gradient::<_, GRAD_WIDTH>(&obj, &lens, &adj, &state.vars)?;
            let sys = lens.compile();
            let spot: f64 = (0..obj.bundles.len())
                .map(|k| spot_size(&obj.bundles.sensor_points(&sys, k, trace), SpotMeasure::Rms))
                .sum::<f64>()
                / obj.bundles.len() as f64;
            let wave = cfg
                .loss
                .logged(obj.wave.as_ref().map(|(w, _)| value(w, &lens, &adj)));
            (v, g, spot * 1e3, None, wave)
        }
        Stage::Tolerance => {
            let fields = grid_fields(&lens, cfg.psf_grid);
            let nominal = lens.compile();
            let mut psf = PsfOptions::for_lens(&lens);
            psf.ks = cfg.psf_ks;
            psf.centre = PsfCentre::Chief;
            psf.pupil = Pupil {
                pattern: PupilPattern::Random {
                    n: cfg.psf_spp,
                    seed: cfg.seed ^ (it as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
                },
                scale: 1.0,
                aim: false,
            };
            let slots_ok = cfg.spec.validate(&lens);
            slots_ok?;
            // The MTF loss over the fields this iteration's patterns use (pattern j at field
            // j mod the field count), built once, its cutoff checked once per field: each
            // pattern's term is it at the pattern's field.
            let used = &fields[..cfg.samples.min(fields.len())];
            let mtf = match cfg.loss {
                OpticalLoss::Mtf { .. } => wave_term(&lens, &cfg, used, trace)?,
                _ => None,
            };
            let results = (0..cfg.samples)
                .into_par_iter()
                .map(|j| -> Result<PatternResult> {
                    let field = fields[j % fields.len()];
                    let pattern =
                        cfg.spec
                            .sample(&lens, cfg.seed, (it * cfg.samples + j) as u64)?;
                    let (plens, adj) = pattern.apply(&lens)?;
                    let pairs: Vec<(Field, f64)> =
                        cfg.wavelengths_nm.iter().map(|&w| (field, w)).collect();
                    let psf_rays = Bundles::pairs(&lens, &pairs, &psf.pupil)?;
                    // The design's own PSFs (for the logged similarity).
                    let ideal: Vec<Vec<f64>> = (0..pairs.len())
                        .map(|k| psf_of(&nominal, &psf_rays, k, &psf, trace).0)
                        .collect();
                    let spot = Bundles::new(
                        &lens,
                        &[field],
                        &cfg.wavelengths_nm,
                        &Pupil::grid(cfg.spot_grid / 2),
                    )?;
                    let obj = PatternObjective {
                        spot,
                        wave: match &mtf {
                            Some((WaveTerm::Mtf(m), w)) => {
                                Some((WaveTerm::Mtf(m.at_field(j % fields.len())), *w))
                            }
                            _ => wave_term(&lens, &cfg, &[field], trace)?,
                        },
                        psf_rays,
                        psf,
                        cfg: &cfg,
                    };
                    let (v, g) = gradient::<_, GRAD_WIDTH>(&obj, &plens, &adj, &state.vars)?;
                    let sys: System<f64> = System::compile(&plens, &adj, &|_, v| v);
                    let s = (0..obj.spot.len())
                        .map(|k| {
                            spot_size(&obj.spot.sensor_points(&sys, k, trace), SpotMeasure::Mean)
                        })
                        .sum::<f64>()
                        / obj.spot.len() as f64;
                    let sim = (0..obj.psf_rays.len())
                        .map(|k| {
                            psf_similarity(
                                &ideal[k],
                                &psf_of(&sys, &obj.psf_rays, k, &obj.psf, trace).0,
                                obj.psf.ks,
                            )
                        })
                        .sum::<f64>()
                        / obj.psf_rays.len() as f64;
                    let wave = obj.wave.as_ref().map(|(w, _)| value(w, &plens, &adj));
                    Ok((v, g, s, sim, wave))
                })
                .collect::<Result<Vec<_>>>()?;
            let m = 1.0 / results.len().max(1) as f64;
            let mut g = vec![0.0; state.vars.len()];
            let (mut v, mut s, mut sim) = (0.0, 0.0, 0.0);
            let mut wave = (!cfg.loss.is_spot()).then_some(0.0);
            for r in &results {
                v += r.0 * m;
                s += r.2 * m;
                sim += r.3 * m;
                if let (Some(a), Some(b)) = (wave.as_mut(), r.4) {
                    *a += b * m;
                }
                for (a, b) in g.iter_mut().zip(&r.1) {
                    *a += b * m;
                }
            }
            let pobj = PenaltyObjective {
                lens: &lens,
                constraints: &cfg.constraints,
            };
            let (pv, pg) = gradient::<_, GRAD_WIDTH>(
                &pobj,
                &lens,
                &Adjustments::none(lens.surfaces.len()),
                &state.vars,
            )?;
            for (a, b) in g.iter_mut().zip(&pg) {
                *a += b;
            }
            (v + pv, g, s * 1e3, Some(sim), cfg.loss.logged(wave))
        }
    };
    if !loss.is_finite() {
        return Err(Error::numerical(format!(
            "iteration {it}: the loss is not finite (the design lost its rays?)"
        )));
    }
    if let Some(k) = grad.iter().position(|g| !g.is_finite()) {
        return Err(Error::numerical(format!(
            "iteration {it}: the loss' derivative in {:?} is not finite (a ray grazing a \
             surface?)",
            state.vars[k]
        )));
    }
    let scale = cosine_schedule(stage_it as u64, stage_len as u64, 0.05)
        * match stage {
            Stage::Pretrain => 1.0,
            Stage::Tolerance => cfg.tolerance_lr_scale,
        };
    let mut x: Vec<f64> = state
        .vars
        .iter()
        .map(|&p| param_value(&lens, p))
        .collect::<Result<_>>()?;
    state.adam.step(&mut x, &grad, scale);
    for (&p, &v) in state.vars.iter().zip(&x) {
        set_param(&mut lens, p, v)?;
    }
    project(&mut lens, &cfg.constraints);
    state.lens = lens;
    state.next_iter += 1;
    if state.next_iter == cfg.pretrain_iters && cfg.tolerance_iters > 0 {
        state.stage1_lens = Some(state.lens.clone());
    }
    Ok(IterLog {
        iter: it,
        stage,
        loss,
        spot_um,
        psf_similarity: sim,
        lr_scale: scale,
        wavefront_waves,
        mtf,
    })
}

/// One stage-2 pattern's loss, gradient, mean spot (mm), PSF similarity and RMS wavefront error
/// (waves, with the wavefront loss).
type PatternResult = (f64, Vec<f64>, f64, f64, Option<f64>);

struct PenaltyObjective<'a> {
    lens: &'a Lens,
    constraints: &'a Constraints,
}

impl Objective for PenaltyObjective<'_> {
    fn eval<S: Traceable>(&self, sys: &System<S>, lift: &dyn Fn(Param, S) -> S) -> S {
        penalties(self.lens, sys, lift, self.constraints)
    }
}

/// Held-out evaluation of a design under random tolerances.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HeldOut {
    /// Mean over patterns of the RMS spot (mean over fields), µm, sensor left where the design
    /// puts it.
    pub rms_mean_um: f64,
    /// Standard deviation over patterns of that RMS spot, µm.
    pub rms_std_um: f64,
    /// 90 % of lenses have RMS spot below this, µm.
    pub rms_yield90_um: f64,
    /// As `rms_mean_um`, with each lens refocused to its best RMS focus (the focus compensator
    /// of assembly), µm.
    pub refocused_rms_mean_um: f64,
    /// Standard deviation over patterns of the refocused RMS spot, µm.
    pub refocused_rms_std_um: f64,
    /// 90 % of refocused lenses have RMS spot below this, µm.
    pub refocused_rms_yield90_um: f64,
    /// Mean PSF similarity of each perturbed lens to the design's own nominal PSF.
    pub psf_similarity_mean: f64,
    /// Nominal RMS spot per field, µm.
    pub nominal_rms_um: Vec<f64>,
}

/// Evaluates `lens` on `trials` held-out patterns of `seed` (use a seed different from
/// training): RMS spot statistics with the sensor where the design puts it and with each lens
/// refocused (the focus compensator), and the mean PSF similarity at each pattern's field of the
/// PSF grid.
///
/// # Errors
/// As the Monte Carlo analysis.
pub fn held_out(lens: &Lens, cfg: &TrainConfig, trials: usize, seed: u64) -> Result<HeldOut> {
    let summary =
        |compensate_focus: bool| -> Result<(crate::tolerance::monte_carlo::Stats, Vec<f64>)> {
            let mc = crate::tolerance::McOptions {
                spec: cfg.spec.clone(),
                trials,
                seed,
                fields: cfg.fields.clone(),
                wavelengths_nm: vec![cfg.wavelengths_nm[cfg.wavelengths_nm.len() / 2]],
                pupil: Pupil::grid(cfg.spot_grid),
                compensate_focus,
                apertures: cfg.apertures,
                criterion: Default::default(),
            };
            let rep = crate::tolerance::monte_carlo(lens, "design", &mc, None, &|| {})?;
            let s = rep
                .summary
                .map(|s| s.mean_over_fields)
                .ok_or_else(|| Error::numerical("no summary"))?;
            Ok((s, rep.nominal_rms_um))
        };
    let ((s, nominal_rms_um), (r, _)) = (summary(false)?, summary(true)?);
    let fields = grid_fields(lens, cfg.psf_grid);
    let nominal = lens.compile();
    let mut psf = PsfOptions::for_lens(lens);
    psf.ks = cfg.psf_ks;
    psf.pupil = Pupil {
        pattern: PupilPattern::Random {
            n: cfg.psf_spp.max(1024),
            seed,
        },
        scale: 1.0,
        aim: false,
    };
    let trace = TraceOptions {
        apertures: cfg.apertures,
    };
    let sims = (0..trials)
        .into_par_iter()
        .map(|j| -> Result<f64> {
            let field = fields[j % fields.len()];
            let pattern = cfg.spec.sample(lens, seed, j as u64)?;
            let (plens, adj) = pattern.apply(lens)?;
            let sys: System<f64> = System::compile(&plens, &adj, &|_, v| v);
            let wl = cfg.wavelengths_nm[cfg.wavelengths_nm.len() / 2];
            let rays = Bundles::pairs(lens, &[(field, wl)], &psf.pupil)?;
            let ideal = psf_of(&nominal, &rays, 0, &psf, trace).0;
            Ok(psf_similarity(
                &ideal,
                &psf_of(&sys, &rays, 0, &psf, trace).0,
                psf.ks,
            ))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(HeldOut {
        rms_mean_um: s.mean,
        rms_std_um: s.std,
        rms_yield90_um: s.yield_below[0][1],
        refocused_rms_mean_um: r.mean,
        refocused_rms_std_um: r.std,
        refocused_rms_yield90_um: r.yield_below[0][1],
        psf_similarity_mean: sims.iter().sum::<f64>() / sims.len().max(1) as f64,
        nominal_rms_um,
    })
}
