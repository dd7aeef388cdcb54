//! `tolray train`: the two-stage optics training, run by the library's
//! [`run_training`](tolray::optim::train::run_training) with a progress bar and Ctrl-C.

use crate::app::{GRACEFUL_STOP, STOP_REQUESTED};
use crate::report::emit;
use crate::usage;
use anyhow::Context;
use clap::Args;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use tolray::lens::json;
use tolray::optim::train::{
    final_report, run_training, RunOptions, RunOutcome, TrainConfig, TrainState,
};
use tolray::tolerance::ToleranceSpec;
use tolray::{Lens, Object};

/// Arguments of `tolray train`.
#[derive(Args)]
pub struct TrainArgs {
    /// Lens JSON file or built-in name (ignored with --resume).
    pub lens: Option<String>,
    /// Object distance from the first vertex in mm, or "inf".
    #[arg(long, value_name = "MM|inf")]
    pub object: Option<String>,
    /// Which stages to run.
    #[arg(long, default_value = "both", value_parser = ["pretrain", "tolerance", "both"])]
    pub stage: String,
    /// Iterations per stage.
    #[arg(long, default_value_t = 100)]
    pub iters: usize,
    /// Iterations of stage 1 when it should differ from --iters.
    #[arg(long)]
    pub pretrain_iters: Option<usize>,
    /// Tolerance patterns per stage-2 iteration.
    #[arg(long, default_value_t = 64)]
    pub samples: usize,
    /// Seed of patterns and pupil samples.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output directory: log.jsonl, checkpoint.json, lens-*.json, report, pictures.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Continue the run saved in DIR exactly where it stopped.
    #[arg(long, value_name = "DIR")]
    pub resume: Option<PathBuf>,
    /// Write a checkpoint every K iterations (and always at the end or on Ctrl-C).
    #[arg(long, default_value_t = 10, value_name = "K")]
    pub checkpoint_every: usize,
    /// Tolerance spec for stage 2 (default: the paper's Table A1).
    #[arg(long, value_name = "SPEC.json")]
    pub spec: Option<PathBuf>,
    /// Weight of the spot loss (per mm).
    #[arg(long, default_value_t = 10.0)]
    pub lambda_spot: f64,
    /// Weight of the PSF-similarity loss.
    #[arg(long, default_value_t = 1.0)]
    pub lambda_psf: f64,
    /// Rays per PSF in stage 2.
    #[arg(long, default_value_t = 256)]
    pub psf_spp: usize,
    /// Factor on the learning rates in stage 2 (which fine-tunes the stage-1 design).
    #[arg(long, default_value_t = 0.1)]
    pub tolerance_lr_scale: f64,
    /// Maximum total track, mm.
    #[arg(long, value_name = "MM")]
    pub max_track: Option<f64>,
    /// Target effective focal length, mm.
    #[arg(long, value_name = "MM")]
    pub target_efl: Option<f64>,
    /// Held-out patterns for the final report (seed differs from training). 100 is too few
    /// to compare two designs' spreads: their standard deviations then vary by about 10 %
    /// from one held-out seed to another.
    #[arg(long, default_value_t = 400)]
    pub eval_trials: usize,
}

/// Runs `tolray train`.
pub fn run(a: TrainArgs) -> anyhow::Result<()> {
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
        psf_spp,
        tolerance_lr_scale,
        max_track,
        target_efl,
        eval_trials,
    } = a;
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
            cfg.samples = samples;
            cfg.seed = seed;
            cfg.lambda_spot = lambda_spot;
            cfg.lambda_psf = lambda_psf;
            cfg.psf_spp = psf_spp;
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
            std::fs::create_dir_all(&out)
                .with_context(|| format!("{}: cannot create directory", out.display()))?;
            json::write_file(&l, &out.join("lens-initial.json"))?;
            TrainState::new(&l, cfg)
        }
    };
    train(
        state,
        &out,
        resume.is_some(),
        checkpoint_every.max(1),
        eval_trials,
    )
}

/// Runs (or continues) training with a progress bar, Ctrl-C as a stop request (exit code 130
/// with a checkpoint to resume from), then prints and writes the final report.
fn train(
    mut state: TrainState,
    out: &Path,
    resumed: bool,
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
    let opts = RunOptions {
        resumed,
        every,
        stop: &STOP_REQUESTED,
    };
    let outcome = run_training(&mut state, out, opts, |l| {
        bar.set_message(format!(
            "{:?} loss {:.5} spot {:.2} µm{}",
            l.stage,
            l.loss,
            l.spot_um,
            l.psf_similarity
                .map_or(String::new(), |s| format!(" sim {s:.4}"))
        ));
        bar.inc(1);
    })?;
    let logs = match outcome {
        RunOutcome::Finished { logs } => logs,
        RunOutcome::Stopped { next_iter } => {
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
    tolray::figures::save(
        &tolray::figures::training_figure(&logs, "Training"),
        &out.join("training.png"),
    )?;
    // Final report: initial, stage-1 and final designs; held-out patterns with another seed.
    let report = final_report(&state, out, eval_trials)?;
    emit(&report.text);
    report.write(out)?;
    eprintln!(
        "wrote {}/report.txt, report.json, lens-final.json, training.png, log.jsonl",
        out.display()
    );
    Ok(())
}
