//! The deep-optics study: one lens designed three ways from the same start and judged on the
//! same held-out fabricated units. Stage 0 fits the prescription's focus with the spot loss;
//! stage 1 trains lens and decoder on the nominal lens; from there three branches run equally
//! long: the conventional design (stage 1 continued, no tolerances), the tolerance-aware design
//! (stage 2, tolerances in the loop) and the decoder-only control (stage-1 lens frozen, decoder
//! trained on tolerances). Each design is saved (`lens.json`, `decoder.bin`) and evaluated.

use super::eval::{evaluate, report, EvalConfig, EvalImages, Report};
use super::{step, DeepConfig, DeepLog, DeepState, Design, Phase};
pub use crate::decoder::file::{decoder_from_bytes, decoder_to_bytes, load_decoder, save_decoder};
use crate::error::{Error, ErrorKind, Result};
use crate::files::write_atomic;
use crate::image::render::SensorNoise;
use crate::lens::Lens;
use crate::optim::train::{Checkpoints, IterLog, RunControl, TrainState};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Names of the study's designs.
pub const CONVENTIONAL: &str = "conventional";
/// The tolerance-aware design.
pub const TOLERANCE_AWARE: &str = "tolerance-aware";
/// The decoder-only control.
pub const DECODER_ONLY: &str = "decoder-only";
/// Name of the optics-only control (the paper's Table 3: the stage-1 decoder frozen, the lens
/// trained with tolerances).
pub const OPTICS_ONLY: &str = "optics-only";
/// Name of the stage-1 design (the branches' common start) when it is evaluated
/// ([`StudyConfig::evaluate_stage1`]); its folder is `stage1`.
pub const STAGE1: &str = "stage1";

/// Study settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StudyConfig {
    /// Joint-training settings.
    pub deep: DeepConfig,
    /// Iterations of the spot-loss focus fit (stage 0).
    pub spot_iters: usize,
    /// Iterations of stage 1.
    pub stage1_iters: usize,
    /// Iterations of each branch after stage 1.
    pub stage2_iters: usize,
    /// Train and evaluate the conventional design (stage 1 continued without tolerances).
    #[serde(default = "yes")]
    pub conventional: bool,
    /// Train and evaluate the tolerance-aware design (stage 2: lens and decoder with tolerances).
    #[serde(default = "yes")]
    pub tolerance_aware: bool,
    /// Also train and evaluate the decoder-only control.
    pub decoder_only: bool,
    /// Also train and evaluate the optics-only control.
    #[serde(default)]
    pub optics_only: bool,
    /// Also evaluate the stage-1 design ([`STAGE1`]), each branch paired against it (what the
    /// branch bought over its start). `tolray train`'s image stage sets it.
    #[serde(default)]
    pub evaluate_stage1: bool,
    /// Iterations between validation-PSNR measurements (0: none); the last iteration of every
    /// phase is always measured.
    #[serde(default)]
    pub validate_every: usize,
    /// Evaluation settings.
    pub eval: EvalConfig,
    /// Built-in photographs in the evaluation set besides the dead-leaves image (0 to 4).
    #[serde(default = "default_photos")]
    pub eval_photos: usize,
    /// Evaluate on the PNG/JPEG images of this folder instead of the built-in set.
    #[serde(default)]
    pub eval_images_dir: Option<std::path::PathBuf>,
}

fn default_photos() -> usize {
    2
}

fn yes() -> bool {
    true
}

impl StudyConfig {
    /// The branches trained after stage 1, in order: (name, phase).
    pub fn branches(&self) -> Vec<(&'static str, Phase)> {
        [
            (self.conventional, CONVENTIONAL, Phase::Nominal),
            (self.tolerance_aware, TOLERANCE_AWARE, Phase::Tolerance),
            (self.decoder_only, DECODER_ONLY, Phase::DecoderOnly),
            (self.optics_only, OPTICS_ONLY, Phase::OpticsOnly),
        ]
        .into_iter()
        .filter(|b| b.0)
        .map(|b| (b.1, b.2))
        .collect()
    }

    /// The designs the evaluation scores, in order: the stage-1 design when
    /// [`StudyConfig::evaluate_stage1`] is set, then the branches.
    pub fn designs(&self) -> Vec<&'static str> {
        let mut d = if self.evaluate_stage1 {
            vec![STAGE1]
        } else {
            Vec::new()
        };
        d.extend(self.branches().into_iter().map(|b| b.0));
        d
    }

    /// The pairs of designs whose paired differences the report gives (a minus b): the
    /// tolerance-aware design against each other branch, each control against the conventional
    /// design, and with [`StudyConfig::evaluate_stage1`] each branch against stage 1.
    pub fn pairs(&self) -> Vec<(String, String)> {
        let has = |n: &str| self.designs().contains(&n);
        let mut p = Vec::new();
        let mut add = |a: &str, b: &str| {
            if has(a) && has(b) {
                p.push((a.to_string(), b.to_string()));
            }
        };
        add(TOLERANCE_AWARE, CONVENTIONAL);
        add(DECODER_ONLY, CONVENTIONAL);
        add(TOLERANCE_AWARE, DECODER_ONLY);
        add(OPTICS_ONLY, CONVENTIONAL);
        add(TOLERANCE_AWARE, OPTICS_ONLY);
        for (b, _) in self.branches() {
            add(b, STAGE1);
        }
        p
    }

    /// Checks the settings: the joint-training settings, and that there is a design to
    /// evaluate.
    ///
    /// # Errors
    /// [`ErrorKind::Argument`] naming what is wrong.
    pub fn validate(&self) -> Result<()> {
        self.deep.validate()?;
        if self.designs().is_empty() {
            return Err(Error::argument(
                "no design to train after stage 1 and stage 1 not evaluated: nothing to report",
            ));
        }
        if self.eval.trials == 0 {
            return Err(Error::argument("0 evaluation trials: give at least 1"));
        }
        Ok(())
    }

    /// The evaluation images these settings name: `grid x patch` pixels square, the built-in set
    /// or centre crops of the folder's images.
    ///
    /// # Errors
    /// As [`EvalImages::builtin`] and [`EvalImages::from_dir`].
    pub fn eval_images(&self) -> Result<EvalImages> {
        let side = self.eval.grid * self.eval.patch_px;
        match &self.eval_images_dir {
            Some(d) => EvalImages::from_dir(d, side),
            None => EvalImages::builtin(side, self.eval_photos, self.eval.seed),
        }
    }
}

/// Training curves of a study from its logs ([`crate::figures::deep_training_curves`]): stage 1
/// (`stage1`, which every branch's log starts with) once in grey, then each branch from the
/// last shared point, a design keeping its colour whichever branches ran. With no branches,
/// the figure is stage 1's.
#[must_use]
pub fn deep_training_figure(
    stage1: &[DeepLog],
    branches: &[(String, Vec<DeepLog>)],
    title: &str,
) -> crate::figures::Figure {
    use crate::figures::{deep_training_curves, DeepCurve};
    // The branches start after stage 1's last iteration (at 0 when stage 1 ran none).
    let split = stage1.last().map_or(0, |l| l.iter + 1);
    let row = |l: &DeepLog| (l.iter as f64, l.psnr_db, l.val_psnr_db, l.image_loss);
    let mut curves = Vec::new();
    if !stage1.is_empty() {
        let name = if branches.len() > 1 {
            "stage 1 (shared)"
        } else {
            "stage 1"
        };
        curves.push(DeepCurve {
            name: name.to_string(),
            colour: None,
            rows: stage1.iter().map(row).collect(),
        });
    }
    for (k, (name, logs)) in branches.iter().enumerate() {
        // Joined to the last shared point so that the curves continue.
        let from = split.saturating_sub(1);
        let c = [CONVENTIONAL, TOLERANCE_AWARE, DECODER_ONLY, OPTICS_ONLY]
            .iter()
            .position(|n| n == name)
            .unwrap_or(k);
        curves.push(DeepCurve {
            name: name.clone(),
            colour: Some(c),
            rows: logs.iter().filter(|l| l.iter >= from).map(row).collect(),
        });
    }
    let split = if branches.is_empty() { 0 } else { split };
    deep_training_curves(curves, split, title)
}

/// Where [`run_resumable`] starts.
pub enum Start<'a> {
    /// A fresh study of this lens.
    Lens(&'a Lens),
    /// A saved design (lens and decoder, e.g. an earlier run's `stage1` folder): the focus fit
    /// is skipped and stage 1 (for [`StudyConfig::stage1_iters`], which may be 0) continues
    /// from it. Its decoder must have the configured kind, grid, kernel and U-Net width.
    Design(&'a Design),
    /// Where a checkpoint of the same study stopped.
    Checkpoint(Box<Checkpoint>),
}

/// Saves a design into `dir` (`lens.json`, `decoder.bin`).
///
/// # Errors
/// I/O errors naming the path.
pub fn save_design(d: &Design, dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    crate::lens::json::write_file(&d.lens, &dir.join("lens.json"))?;
    save_decoder(&d.decoder, &dir.join("decoder.bin"))
}

/// Writes `sensor.json` in a design's folder: the sensor noise it was trained under, which
/// `tolray evaluate` takes as its default (so that a design is not scored under another sensor
/// without a word).
///
/// # Errors
/// I/O errors naming the path.
pub fn save_sensor(dir: &Path, sensor: &SensorNoise) -> Result<()> {
    let text = serde_json::to_string_pretty(sensor)
        .map_err(|e| Error::numerical(format!("sensor settings: {e}")))?;
    write_atomic(&dir.join(SENSOR_FILE), (text + "\n").as_bytes())
}

/// The sensor noise a design in `dir` was trained under ([`save_sensor`]), `None` for a folder
/// without `sensor.json` (designs saved before it existed).
///
/// # Errors
/// A `sensor.json` that does not parse or holds invalid settings, naming the file.
pub fn load_sensor(dir: &Path) -> Result<Option<SensorNoise>> {
    let path = dir.join(SENSOR_FILE);
    if !path.exists() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
    let s: SensorNoise = serde_json::from_str(&text)
        .map_err(|e| Error::new(ErrorKind::Parse, format!("{}: {e}", path.display())))?;
    s.validate()
        .map_err(|e| Error::invalid(format!("{}: {}", path.display(), e.message())))?;
    Ok(Some(s))
}

/// The file of [`save_sensor`].
pub const SENSOR_FILE: &str = "sensor.json";

/// Loads a design saved by [`save_design`].
///
/// # Errors
/// As the readers.
pub fn load_design(dir: &Path) -> Result<Design> {
    let lens = crate::lens::json::read_file(&dir.join("lens.json"))?;
    let decoder = load_decoder(&dir.join("decoder.bin"))?;
    Ok(Design { lens, decoder })
}

/// A study's checkpoint (`checkpoint.json` in its folder): everything needed to continue exactly
/// where it stopped. Finished branches are in their folders.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Checkpoint {
    /// The study's settings.
    pub config: StudyConfig,
    /// The spot-loss focus fit while it runs.
    pub spot: Option<TrainState>,
    /// Stage 1 (running, or finished: the branches' common start).
    pub stage1: Option<DeepState>,
    /// Stage 1's log.
    pub stage1_logs: Vec<DeepLog>,
    /// The branch being trained: name, state, log (stage 1's included).
    pub branch: Option<(String, DeepState, Vec<DeepLog>)>,
    /// Finished branches with their logs, in order.
    pub finished: Vec<(String, Vec<DeepLog>)>,
}

/// One iteration's log, as the `progress` callback of [`run_resumable`] and [`run`] receives it.
#[derive(Clone, Copy, Debug)]
pub enum Progress<'a> {
    /// An iteration of the spot-loss focus fit (stage 0) and its number of iterations.
    Focus(&'a IterLog, usize),
    /// An iteration of stage 1 (named "stage 1") or of a branch (named after it).
    Image(&'a str, &'a DeepLog),
}

/// Runs the study on `lens`, writing the designs and their training logs under `out`; returns
/// the evaluation report. `progress` receives each iteration's log.
///
/// # Errors
/// Training, evaluation and I/O errors.
pub fn run(
    lens: &Lens,
    cfg: &StudyConfig,
    images: &EvalImages,
    out: &Path,
    progress: &mut dyn FnMut(Progress<'_>),
) -> Result<Report> {
    let ctl = RunControl {
        checkpoints: Checkpoints::WhenStopped,
        stop: &|| false,
    };
    run_resumable(Start::Lens(lens), cfg, images, out, ctl, progress)?
        .ok_or_else(|| Error::new(ErrorKind::Invalid, "the study stopped without a request"))
}

/// Reads `checkpoint.json` of a study folder.
///
/// # Errors
/// I/O and parse errors naming the file.
pub fn read_checkpoint(dir: &Path) -> Result<Checkpoint> {
    crate::files::read_json(&dir.join("checkpoint.json"))
}

/// [`run`] with checkpoints as `ctl` says (and after each finished design unless only when
/// stopped), a stop request, and an exact resume from a checkpoint of the same study: the
/// designs, logs and report are those of an uninterrupted run. `progress` receives each
/// iteration's log. Returns `None` when stopped (the checkpoint is written).
///
/// # Errors
/// As [`run`]; a checkpoint whose settings differ from `cfg`.
pub fn run_resumable(
    start: Start<'_>,
    cfg: &StudyConfig,
    images: &EvalImages,
    out: &Path,
    ctl: RunControl<'_>,
    progress: &mut dyn FnMut(Progress<'_>),
) -> Result<Option<Report>> {
    cfg.validate()?;
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let ck_path = out.join("checkpoint.json");
    let save = |ck: &Checkpoint| -> Result<()> {
        let text = serde_json::to_string(ck)
            .map_err(|e| Error::new(ErrorKind::Invalid, format!("checkpoint: {e}")))?;
        write_atomic(&ck_path, text.as_bytes())
    };
    let mut ck = match start {
        Start::Checkpoint(ck) => {
            let ck = *ck;
            if ck.config != *cfg {
                return Err(Error::argument(format!(
                    "{}: the checkpoint's study settings differ from these",
                    ck_path.display()
                )));
            }
            ck
        }
        Start::Lens(lens) => {
            // Stage 0: the spot loss brings the prescription into focus.
            let mut optics = cfg.deep.optics.clone();
            optics.pretrain_iters = cfg.spot_iters;
            optics.tolerance_iters = 0;
            Checkpoint {
                config: cfg.clone(),
                spot: Some(TrainState::new(lens, optics)),
                stage1: None,
                stage1_logs: Vec::new(),
                branch: None,
                finished: Vec::new(),
            }
        }
        Start::Design(d) => {
            let dc = &d.decoder;
            let want = &cfg.deep;
            if dc.kind != want.decoder
                || dc.grid != want.optics.psf_grid
                || dc.ks != want.optics.psf_ks
                || (dc.kind.has_unet() && dc.unet_width != want.unet_width)
            {
                return Err(Error::argument(format!(
                    "the design's decoder ({}, grid {}, kernel {}, U-Net width {}) differs from \
                     the settings' ({}, grid {}, kernel {}, U-Net width {})",
                    dc.kind.name(),
                    dc.grid,
                    dc.ks,
                    dc.unet_width,
                    want.decoder.name(),
                    want.optics.psf_grid,
                    want.optics.psf_ks,
                    want.unet_width
                )));
            }
            let s1 = DeepState::new(
                cfg.deep.clone(),
                d.lens.clone(),
                Some(d.decoder.clone()),
                Phase::Nominal,
                cfg.stage1_iters,
                0,
            )?;
            Checkpoint {
                config: cfg.clone(),
                spot: None,
                stage1: Some(s1),
                stage1_logs: Vec::new(),
                branch: None,
                finished: Vec::new(),
            }
        }
    };
    let stop_requested = ctl.stop;
    // After iteration `k` of a phase: when a stop is requested or a checkpoint is due, writes
    // `ck` with the running state put in by `fill`; true when the study is to stop.
    let pause = |ck: &Checkpoint, k: usize, fill: &dyn Fn(&mut Checkpoint)| -> Result<bool> {
        let stop = stop_requested();
        if stop || ctl.checkpoints.due(k) {
            let mut c = ck.clone();
            fill(&mut c);
            save(&c)?;
        }
        Ok(stop)
    };
    if let Some(mut st) = ck.spot.take() {
        while st.next_iter < cfg.spot_iters {
            let l = crate::optim::train::step(&mut st)?;
            progress(Progress::Focus(&l, cfg.spot_iters));
            if pause(&ck, st.next_iter, &|c| c.spot = Some(st.clone()))? {
                return Ok(None);
            }
        }
        let s1 = DeepState::new(
            cfg.deep.clone(),
            st.lens.clone(),
            None,
            Phase::Nominal,
            cfg.stage1_iters,
            0,
        )?;
        ck.stage1 = Some(s1.clone());
    }
    let validate = |s: &DeepState, l: &mut DeepLog| -> Result<()> {
        let k = s.phase_iter;
        if cfg.validate_every > 0 && (k.is_multiple_of(cfg.validate_every) || s.done()) {
            l.val_psnr_db = Some(super::validation_psnr(s)?);
        }
        Ok(())
    };
    let saved1 = ck
        .stage1
        .clone()
        .ok_or_else(|| Error::invalid("checkpoint: no stage-1 state"))?;
    let mut s1 = saved1.restored()?;
    while !s1.done() {
        let mut l = step(&mut s1)?;
        validate(&s1, &mut l)?;
        progress(Progress::Image("stage 1", &l));
        ck.stage1_logs.push(l);
        if pause(&ck, s1.phase_iter, &|c| c.stage1 = Some(s1.clone()))? {
            return Ok(None);
        }
    }
    ck.stage1 = Some(s1.clone());
    save_design(&s1.design, &out.join(STAGE1))?;
    save_sensor(&out.join(STAGE1), &cfg.deep.sensor())?;
    if cfg.evaluate_stage1 {
        write_log(&out.join(STAGE1), &ck.stage1_logs)?;
    }
    for (name, phase) in cfg.branches() {
        if ck.finished.iter().any(|f| f.0 == name) {
            continue;
        }
        let (mut s, mut logs) = match ck.branch.take() {
            Some((n, saved, logs)) if n == name => (saved.restored()?, logs),
            _ => {
                let mut s = s1.clone();
                s.start_phase(phase, cfg.stage2_iters);
                (s, ck.stage1_logs.clone())
            }
        };
        while !s.done() {
            let mut l = step(&mut s)?;
            validate(&s, &mut l)?;
            progress(Progress::Image(name, &l));
            logs.push(l);
            let fill = |c: &mut Checkpoint| {
                c.branch = Some((name.to_string(), s.clone(), logs.clone()));
            };
            if pause(&ck, s.phase_iter, &fill)? {
                return Ok(None);
            }
        }
        let dir = out.join(name);
        save_design(&s.design, &dir)?;
        save_sensor(&dir, &cfg.deep.sensor())?;
        write_log(&dir, &logs)?;
        ck.finished.push((name.to_string(), logs));
        if ctl.checkpoints != Checkpoints::WhenStopped {
            save(&ck)?;
        }
    }
    crate::figures::save(
        &deep_training_figure(&ck.stage1_logs, &ck.finished, "deep-optics training"),
        &out.join("training.png"),
    )?;
    let mut scores = Vec::new();
    for name in cfg.designs() {
        let d = load_design(&out.join(name))?;
        scores.push(evaluate(name, &d, images, &cfg.eval, 0..cfg.eval.trials)?);
    }
    let names: Vec<String> = images.images.iter().map(|i| i.0.clone()).collect();
    report(&cfg.eval, &names, scores, &cfg.pairs()).map(Some)
}

/// Writes a design's training log as `log.jsonl` in `dir` (one [`DeepLog`] per line).
fn write_log(dir: &Path, logs: &[DeepLog]) -> Result<()> {
    let text: String = logs
        .iter()
        .map(|l| serde_json::to_string(l).unwrap_or_default() + "\n")
        .collect();
    write_atomic(&dir.join("log.jsonl"), text.as_bytes())
}
