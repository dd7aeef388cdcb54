//! `tolray train`: the two-stage optics training, run by the library's
//! [`run_training`](tolray::optim::train::run_training) with a progress bar and Ctrl-C; with
//! `--decoder`, the image stage (lens and decoder), run by the deep-optics study runner
//! ([`tolray::deep::study::run_resumable`]) for one stage-2 design.

use crate::app::{GRACEFUL_STOP, STOP_REQUESTED};
use crate::deep::{run_study, EvalArgs};
use crate::report::emit;
use crate::usage;
use anyhow::Context;
use clap::Args;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use tolray::decoder::DecoderKind;
use tolray::deep::study::{self, StudyConfig};
use tolray::deep::DeepConfig;
use tolray::image::source::TrainImages;
use tolray::optim::train::{
    run_to_report, Checkpoints, OpticalLoss, RunControl, RunEnd, TrainConfig, TrainState,
};
use tolray::tolerance::{Criterion, ToleranceSpec};
use tolray::{Lens, Object};

/// Checks a `--loss` value: spot, rms-wavefront or mtf@FREQ[:t|s|mean].
fn parse_loss(s: &str) -> Result<String, String> {
    match s {
        "spot" | "rms-wavefront" => Ok(s.to_string()),
        _ if s.starts_with("mtf@") => match Criterion::parse(s) {
            Ok(Criterion::Mtf { .. }) => Ok(s.to_string()),
            Ok(_) => Err(format!("{s}: not an MTF loss")),
            Err(_) => Err(format!(
                "{s}: give mtf@FREQ[:t|s|mean], FREQ a positive number of cycles/mm"
            )),
        },
        _ => Err(format!(
            "{s}: give spot, rms-wavefront or mtf@FREQ[:t|s|mean] (FREQ in cycles/mm)"
        )),
    }
}

/// Arguments of `tolray train`.
#[derive(Args)]
pub struct TrainArgs {
    /// Lens JSON file or built-in name (ignored with --resume); with --decoder and --stage
    /// tolerance, a design folder (lens.json and decoder.bin, e.g. an earlier run's stage1).
    pub lens: Option<String>,
    /// Object distance in front of the first vertex in mm (0: on the vertex's plane), "inf",
    /// or "virtual:MM" (a beam converging on a point MM behind the first vertex).
    #[arg(long, value_name = "MM|inf|virtual:MM")]
    pub object: Option<String>,
    /// Which stages to run.
    #[arg(long, default_value = "both", value_parser = ["pretrain", "tolerance", "both"])]
    pub stage: String,
    /// Iterations per stage [default: 100]; with --decoder, iterations of stage 2 [default: 100].
    #[arg(long)]
    pub iters: Option<usize>,
    /// Iterations of stage 1 when it should differ from --iters; with --decoder [default: 200].
    #[arg(long)]
    pub pretrain_iters: Option<usize>,
    /// Tolerance patterns per stage-2 iteration [default: 64]; with --decoder, training crops
    /// (each with its own pattern in stage 2) per iteration [default: 32].
    #[arg(long)]
    pub samples: Option<usize>,
    /// Seed of patterns and pupil samples (and with --decoder, of crops and noise).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output directory: log.jsonl, checkpoint.json, lens-*.json, report, pictures (with
    /// --decoder: stage1/ and the stage-2 design's folder, training.png, report.json/.html).
    /// With --resume it defaults to the resumed folder.
    #[arg(long, value_name = "DIR", required_unless_present = "resume")]
    pub out: Option<PathBuf>,
    /// Continue the run saved in DIR exactly where it stopped (either kind: the settings come
    /// from its checkpoint).
    #[arg(long, value_name = "DIR")]
    pub resume: Option<PathBuf>,
    /// Write a checkpoint every K iterations (and always at the end or on Ctrl-C).
    #[arg(long, default_value_t = 10, value_name = "K")]
    pub checkpoint_every: usize,
    /// Tolerance spec for stage 2 (default: the paper's Table A1).
    #[arg(long, value_name = "SPEC.json")]
    pub spec: Option<PathBuf>,
    /// Weight of the spot loss (per mm) [default: 10; with --decoder 0.1]; 0 turns it off.
    #[arg(long)]
    pub lambda_spot: Option<f64>,
    /// Weight of the PSF-similarity loss [default: 1; with --decoder 0.01]; 0 turns it off.
    #[arg(long)]
    pub lambda_psf: Option<f64>,
    /// The optical term of both stages: spot (the paper's spot size), rms-wavefront (the RMS
    /// wavefront error to centroid in waves, weighed as the RMS spot of a defocus with that
    /// error: 4√6·N·λ mm a wave) or mtf@FREQ[:t|s|mean] (1 − the diffraction MTF at FREQ
    /// cycles/mm, tangential, sagittal or their mean [default], weighed as a spot of 1/(2·FREQ)
    /// mm per unit). Not with --decoder.
    #[arg(long, default_value = "spot", value_parser = parse_loss, value_name = "LOSS")]
    pub loss: String,
    /// Rays per PSF in stage 2.
    #[arg(long, default_value_t = 256)]
    pub psf_spp: usize,
    /// Factor on the learning rates in stage 2 (which fine-tunes the stage-1 design)
    /// [default: 0.1]. Not with --decoder.
    #[arg(long)]
    pub tolerance_lr_scale: Option<f64>,
    /// Maximum total track, mm.
    #[arg(long, value_name = "MM")]
    pub max_track: Option<f64>,
    /// Target effective focal length, mm.
    #[arg(long, value_name = "MM")]
    pub target_efl: Option<f64>,
    /// Held-out patterns for the final report (seed differs from training) [default: 400; with
    /// --decoder, fabricated units each design is evaluated on: 100]. 100 is too few to compare
    /// two designs' spot spreads: their standard deviations then vary by about 10 % from one
    /// held-out seed to another.
    #[arg(long)]
    pub eval_trials: Option<usize>,
    #[command(flatten)]
    pub image: ImageStageArgs,
}

/// The image stage of `tolray train` (the flags that need --decoder).
#[derive(Args, Default)]
pub struct ImageStageArgs {
    /// Train the image stage: the lens and this decoder (wiener, unet, wiener+unet) together on
    /// simulated captures, stage 1 without and stage 2 with tolerances (the deep-optics trainer
    /// of `tolray deep`, for one design).
    #[arg(long, help_heading = "Image stage")]
    pub decoder: Option<String>,
    /// What stage 2 trains: both (lens and decoder: the tolerance-aware design), optics (the
    /// decoder frozen) or decoder (the lens frozen): the paper's Table 3 rows. The design is
    /// saved as tolerance-aware/, optics-only/ or decoder-only/ [default: both].
    #[arg(long, value_parser = ["both", "optics", "decoder"], help_heading = "Image stage")]
    pub stage2_trains: Option<String>,
    /// Iterations of the spot-loss focus fit before stage 1 (stage 0) [default: 300].
    #[arg(long, help_heading = "Image stage")]
    pub focus_iters: Option<usize>,
    /// Side of the training crops, pixels (the paper: 256) [default: 32].
    #[arg(long, help_heading = "Image stage")]
    pub crop: Option<usize>,
    /// U-Net width (channels of its first level) [default: 8].
    #[arg(long, help_heading = "Image stage")]
    pub unet_width: Option<usize>,
    /// Gaussian noise σ (linear [0, 1] units; the paper: 0.01) [default: 0.01; from a design,
    /// the sensor it was trained under (its sensor.json)].
    #[arg(long, help_heading = "Image stage")]
    pub noise: Option<f64>,
    /// Electrons of a full well (signal 1): adds photon shot noise, variance signal / full well,
    /// to the Gaussian noise (then the read noise: electrons / full well) [default: off; from a
    /// design, its sensor.json].
    #[arg(long, value_name = "ELECTRONS", help_heading = "Image stage")]
    pub full_well_electrons: Option<f64>,
    /// Train on random flipped blocks of the PNG/JPEG images of this folder instead of the
    /// built-in dead leaves.
    #[arg(long, value_name = "DIR", help_heading = "Image stage")]
    pub images: Option<PathBuf>,
    /// Refocus each sampled unit in stage 2 before imaging it (its best RMS focus, differentiated
    /// with the design).
    #[arg(long, value_name = "focus", value_parser = ["focus"], help_heading = "Image stage")]
    pub train_compensate: Option<String>,
    /// The PSFs the image stage trains and evaluates with: geometric (rays on pixels, the
    /// paper's) or diffraction (the pupil function's FFT on the same pixels, differentiated
    /// exactly; several times slower) [default: geometric].
    #[arg(long = "psf", value_name = "MODEL", value_parser = ["geometric", "diffraction"], help_heading = "Image stage")]
    pub psf_model: Option<String>,
    /// Iterations between validation-PSNR measurements (0: none) [default: 10].
    #[arg(long, help_heading = "Image stage")]
    pub validate_every: Option<usize>,
    /// Evaluate on the PNG/JPEG images of this folder (centre crops) instead of the built-in set.
    #[arg(long, value_name = "DIR", help_heading = "Image stage")]
    pub eval_images: Option<PathBuf>,
    /// Refocus each evaluated unit to its best RMS focus (the assembly's compensator).
    #[arg(long, value_name = "focus", value_parser = ["focus"], help_heading = "Image stage")]
    pub compensate: Option<String>,
}

impl ImageStageArgs {
    /// The first image-stage flag given, for the error when --decoder is missing.
    fn first_given(&self) -> Option<&'static str> {
        [
            (self.stage2_trains.is_some(), "--stage2-trains"),
            (self.focus_iters.is_some(), "--focus-iters"),
            (self.crop.is_some(), "--crop"),
            (self.unet_width.is_some(), "--unet-width"),
            (self.noise.is_some(), "--noise"),
            (self.full_well_electrons.is_some(), "--full-well-electrons"),
            (self.images.is_some(), "--images"),
            (self.train_compensate.is_some(), "--train-compensate"),
            (self.psf_model.is_some(), "--psf"),
            (self.validate_every.is_some(), "--validate-every"),
            (self.eval_images.is_some(), "--eval-images"),
            (self.compensate.is_some(), "--compensate"),
        ]
        .into_iter()
        .find(|f| f.0)
        .map(|f| f.1)
    }
}

/// Runs `tolray train`.
pub fn run(a: TrainArgs) -> anyhow::Result<()> {
    let image_resume = a
        .resume
        .as_ref()
        .is_some_and(|d| d.join("study.json").exists());
    if a.image.decoder.is_some() || image_resume {
        return image_stage(a);
    }
    if let Some(flag) = a.image.first_given() {
        usage!("{flag} belongs to the image stage: give --decoder KIND too");
    }
    let TrainArgs {
        lens,
        object,
        stage,
        iters,
        pretrain_iters,
        samples,
        seed,
        out,
        resume,
        checkpoint_every,
        spec,
        lambda_spot,
        lambda_psf,
        loss,
        psf_spp,
        tolerance_lr_scale,
        max_track,
        target_efl,
        eval_trials,
        image: _,
    } = a;
    let Some(out) = out.or_else(|| resume.clone()) else {
        usage!("train needs --out DIR (or --resume DIR)")
    };
    let iters = iters.unwrap_or(100);
    let state = match &resume {
        Some(dir) => {
            let p = dir.join("checkpoint.json");
            let text = std::fs::read_to_string(&p)
                .with_context(|| format!("{}: cannot read the checkpoint", p.display()))?;
            serde_json::from_str::<TrainState>(&text)
                .with_context(|| format!("{}: not a tolray checkpoint", p.display()))?
        }
        None => {
            let Some(name) = lens.as_deref() else {
                usage!("train needs a LENS (or --resume DIR)")
            };
            let mut l = Lens::load(name)?;
            if let Some(o) = &object {
                l.object = Object::parse(o)?;
            }
            let mut cfg = TrainConfig::for_lens(&l);
            cfg.pretrain_iters = if stage == "tolerance" {
                0
            } else {
                pretrain_iters.unwrap_or(iters)
            };
            cfg.tolerance_iters = if stage == "pretrain" { 0 } else { iters };
            cfg.samples = samples.unwrap_or(64);
            cfg.seed = seed;
            cfg.lambda_spot = lambda_spot.unwrap_or(10.0);
            cfg.lambda_psf = lambda_psf.unwrap_or(1.0);
            cfg.psf_spp = psf_spp;
            cfg.loss = match loss.as_str() {
                "spot" => OpticalLoss::Spot,
                "rms-wavefront" => OpticalLoss::rms_wavefront_for(&l)?,
                s => match Criterion::parse(s)? {
                    Criterion::Mtf {
                        freq_lpmm,
                        direction,
                    } => OpticalLoss::mtf_at(freq_lpmm, direction)?,
                    _ => unreachable!("refused by parse_loss"),
                },
            };
            let tolerance_lr_scale = tolerance_lr_scale.unwrap_or(0.1);
            if !(tolerance_lr_scale > 0.0 && tolerance_lr_scale.is_finite()) {
                usage!("--tolerance-lr-scale {tolerance_lr_scale}: must be positive");
            }
            cfg.tolerance_lr_scale = tolerance_lr_scale;
            cfg.constraints.max_total_track_mm = max_track;
            cfg.constraints.target_efl_mm = target_efl;
            cfg.validate()?;
            if let Some(p) = &spec {
                cfg.spec = ToleranceSpec::read(p)?;
                cfg.spec.validate(&l).map_err(|e| e.context(p.display()))?;
            }
            TrainState::new(&l, cfg)
        }
    };
    train(
        state,
        &out,
        checkpoint_every.max(1),
        eval_trials.unwrap_or(400),
    )
}

/// `tolray train --decoder KIND`: stage 0 (focus fit), stage 1 (lens and decoder, nominal) and
/// stage 2 (the branch `--stage2-trains` names, with tolerances), run by the study runner with
/// the stage-1 design evaluated beside the stage-2 design on the same held-out units.
fn image_stage(a: TrainArgs) -> anyhow::Result<()> {
    if let Some(dir) = &a.resume {
        if a.out.as_ref().is_some_and(|o| o != dir) {
            usage!(
                "--out {}: an image-stage run continues in its own folder; give --out {} or leave \
                 it out",
                a.out
                    .as_ref()
                    .map_or(String::new(), |o| o.display().to_string()),
                dir.display()
            );
        }
        let ck = study::read_checkpoint(dir)?;
        let cfg = ck.config.clone();
        let images = cfg.eval_images()?;
        return run_study(
            cfg,
            study::Start::Checkpoint(Box::new(ck)),
            &images,
            dir,
            a.checkpoint_every,
            "tolray train",
        );
    }
    if a.loss != "spot" {
        usage!(
            "--loss {}: the image stage trains its optics with the spot loss; leave --loss out \
             with --decoder",
            a.loss
        );
    }
    if a.tolerance_lr_scale.is_some() {
        usage!(
            "--tolerance-lr-scale is the optics trainer's; with --decoder the lens learning \
             rates are the image stage's own"
        );
    }
    let im = &a.image;
    let Some(name) = a.lens.as_deref() else {
        usage!("train needs a LENS (or --resume DIR)")
    };
    let from_design = a.stage == "tolerance";
    let design = if from_design {
        let dir = Path::new(name);
        if !dir.join("decoder.bin").exists() {
            usage!(
                "--stage tolerance with --decoder starts from a design: give a folder with \
                 lens.json and decoder.bin (e.g. the stage1/ of a `--stage pretrain` run), not \
                 {name}"
            );
        }
        Some(study::load_design(dir)?)
    } else {
        None
    };
    let mut lens = match &design {
        Some(d) => d.lens.clone(),
        None => Lens::load(name)?,
    };
    if let Some(o) = &a.object {
        lens.object = Object::parse(o)?;
    }
    let mut d = DeepConfig::for_lens(&lens);
    d.optics.samples = a.samples.unwrap_or(32);
    d.optics.seed = a.seed;
    d.optics.psf_spp = a.psf_spp;
    d.optics.constraints.max_total_track_mm = a.max_track;
    d.optics.constraints.target_efl_mm = a.target_efl;
    d.crop_px = im.crop.unwrap_or(32);
    d.decoder = DecoderKind::parse(im.decoder.as_deref().unwrap_or_default())?;
    if let Some(k) = design.as_ref().map(|d| d.decoder.kind) {
        if k != d.decoder {
            usage!(
                "{name}: the design's decoder is {0}: give --decoder {0}",
                k.name()
            );
        }
    }
    // A design start keeps its U-Net's width unless told otherwise.
    d.unet_width = im
        .unet_width
        .or(design.as_ref().map(|d| d.decoder.unet_width))
        .unwrap_or(8);
    // A design start keeps the sensor it was trained under (its sensor.json) unless told
    // otherwise, as `tolray evaluate` does.
    let trained = if from_design {
        study::load_sensor(Path::new(name))?
    } else {
        None
    };
    let sensor = match trained {
        Some(s) if im.noise.is_none() && im.full_well_electrons.is_none() => s,
        _ => crate::deep::sensor_noise(im.noise.unwrap_or(0.01), im.full_well_electrons)?,
    };
    d.noise_sigma = sensor.sigma;
    d.full_well_electrons = sensor.full_well_electrons;
    d.lambda_spot = a.lambda_spot.unwrap_or(0.1);
    d.lambda_psf = a.lambda_psf.unwrap_or(0.01);
    d.compensate_focus = im.train_compensate.is_some();
    if im.psf_model.as_deref() == Some("diffraction") {
        d.psf = tolray::psf::PsfModel::Diffraction;
    }
    if let Some(p) = &a.spec {
        d.optics.spec = ToleranceSpec::read(p)?;
    }
    d.validate()?;
    if let Some(dir) = &im.images {
        d.train_images = TrainImages::from_dir(dir, d.crop_px + d.optics.psf_ks - 1)?;
    }
    let mut ev = EvalArgs::defaults(a.eval_trials.unwrap_or(100), a.spec.clone());
    ev.eval_images = im.eval_images.clone();
    ev.compensate = im.compensate.clone();
    if let Some(m) = &im.psf_model {
        ev.psf_model = m.clone();
    }
    let (eval, images) = ev.config(&lens, sensor, d.optics.psf_grid, d.optics.psf_ks)?;
    let trains = im.stage2_trains.as_deref().unwrap_or("both");
    let stage2 = a.stage != "pretrain";
    let iters = a.iters.unwrap_or(100);
    let cfg = StudyConfig {
        deep: d,
        spot_iters: if from_design {
            0
        } else {
            im.focus_iters.unwrap_or(300)
        },
        stage1_iters: if from_design {
            0
        } else {
            a.pretrain_iters.unwrap_or(200)
        },
        stage2_iters: if stage2 { iters } else { 0 },
        conventional: false,
        tolerance_aware: stage2 && trains == "both",
        decoder_only: stage2 && trains == "decoder",
        optics_only: stage2 && trains == "optics",
        evaluate_stage1: true,
        validate_every: im.validate_every.unwrap_or(10),
        eval,
        eval_photos: 2,
        eval_images_dir: im.eval_images.clone(),
    };
    // A design start keeps its decoder and takes the lens with --object applied.
    let Some(out) = &a.out else {
        usage!("train needs --out DIR (or --resume DIR)")
    };
    let from = design.map(|d| tolray::deep::Design {
        lens: lens.clone(),
        decoder: d.decoder,
    });
    let start = match &from {
        Some(d) => study::Start::Design(d),
        None => study::Start::Lens(&lens),
    };
    run_study(cfg, start, &images, out, a.checkpoint_every, "tolray train")
}

/// Runs (or continues) training with a progress bar, Ctrl-C as a stop request (exit code 130
/// with a checkpoint to resume from), then prints and writes the final report.
fn train(
    mut state: TrainState,
    out: &Path,
    every: usize,
    eval_trials: usize,
) -> anyhow::Result<()> {
    let bar = indicatif::ProgressBar::new(state.total_iters() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} {msg} (ETA {eta})")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_position(state.next_iter as u64);
    // Ctrl-C now asks for a stop at the end of the iteration (an exact checkpoint), instead of
    // main's default of removing partial files and exiting at once.
    GRACEFUL_STOP.store(true, Ordering::SeqCst);
    let opts = RunControl {
        checkpoints: Checkpoints::every(every),
        stop: &|| STOP_REQUESTED.load(Ordering::SeqCst),
    };
    let end = run_to_report(&mut state, out, opts, eval_trials, |l| {
        bar.set_message(format!(
            "{:?} loss {:.5} spot {:.2} µm{}{}",
            l.stage,
            l.loss,
            l.spot_um,
            l.wavefront_waves
                .map_or(String::new(), |w| format!(" wavefront {w:.4} waves"))
                + &l.mtf.map_or(String::new(), |m| format!(" MTF {m:.4}")),
            l.psf_similarity
                .map_or(String::new(), |s| format!(" sim {s:.4}"))
        ));
        bar.inc(1);
    })?;
    let report = match end {
        RunEnd::Finished(report) => report,
        RunEnd::Stopped { next_iter } => {
            bar.abandon();
            eprintln!(
                "interrupted: checkpoint at iteration {} in {}; continue with --resume {}",
                next_iter,
                out.display(),
                out.display()
            );
            std::process::exit(130);
        }
    };
    bar.finish_and_clear();
    emit(&report.text);
    eprintln!(
        "wrote {}/report.txt, report.json, lens-final.json, training.png, log.jsonl",
        out.display()
    );
    Ok(())
}
