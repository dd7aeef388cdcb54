//! The training runner behind `tolray train`, re-exported from [`crate::optim::train`]: [`step`]
//! in a loop with a JSON-lines log, checkpoints, a stop request and an exact resume
//! ([`run_training`]), then the held-out final report ([`final_report`]).
//!
//! Files of a run's output directory: `log.jsonl` (one [`IterLog`] per finished iteration),
//! `checkpoint.json` (the [`TrainState`] to resume from), `lens-latest.json` and
//! `lens-iterN.json` (the design at each checkpoint), and after the report `report.txt`,
//! `report.json` and `lens-final.json`. `lens-initial.json`, the starting design, is the caller's
//! to write before a fresh run. Every file is written atomically (through a temporary file and a
//! rename) except the log, which grows by one appended line per iteration.

use super::train::{held_out, step, HeldOut, IterLog, TrainConfig, TrainState};
use crate::error::{Error, ErrorKind, Result};
use crate::files::write_atomic;
use crate::lens::{json, Lens};
use std::num::NonZeroUsize;
use std::path::Path;

/// When a run writes a checkpoint, besides when it is stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Checkpoints {
    /// After every this many iterations.
    Every(NonZeroUsize),
    /// Only when stopped ([`run_training`] also writes one after its last iteration).
    WhenStopped,
}

impl Checkpoints {
    /// Every `n` iterations, 0 meaning only when stopped (`tolray deep --checkpoint-every 0`).
    ///
    /// ```
    /// use tolray::optim::train::Checkpoints;
    /// assert!(Checkpoints::every(5).due(10) && !Checkpoints::every(5).due(11));
    /// assert!(!Checkpoints::every(0).due(10));
    /// ```
    pub fn every(n: usize) -> Checkpoints {
        NonZeroUsize::new(n).map_or(Checkpoints::WhenStopped, Checkpoints::Every)
    }

    /// Whether a checkpoint is due after iteration `k` (counted from 1).
    pub fn due(self, k: usize) -> bool {
        match self {
            Checkpoints::Every(n) => k.is_multiple_of(n.get()),
            Checkpoints::WhenStopped => false,
        }
    }
}

/// How a training run is driven: the one control of both runners, `tolray train`'s
/// ([`run_training`], [`run_to_report`], the C ABI's `tolray_train`) and the deep-optics study's
/// ([`crate::deep::study::run_resumable`]).
#[derive(Clone, Copy)]
pub struct RunControl<'a> {
    /// When to write checkpoints.
    pub checkpoints: Checkpoints,
    /// Polled after every iteration: when it returns true the run writes its checkpoint and
    /// returns as stopped (unless that iteration was the last).
    pub stop: &'a dyn Fn() -> bool,
}

impl std::fmt::Debug for RunControl<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunControl")
            .field("checkpoints", &self.checkpoints)
            .finish_non_exhaustive()
    }
}

/// How [`run_training`] ended.
#[derive(Clone, Debug, PartialEq)]
pub enum RunOutcome {
    /// Every iteration ran; the logs of all of them (those of an earlier, resumed run first).
    Finished {
        /// One log per iteration of both stages, in order.
        logs: Vec<IterLog>,
    },
    /// Stopped on request, with a checkpoint written after iteration `next_iter - 1`:
    /// resume by running the state read back from that checkpoint.
    Stopped {
        /// The next iteration to run (global, over both stages).
        next_iter: usize,
    },
}

/// Writes `checkpoint.json` and `lens-latest.json` of `state` into `out`.
fn save_checkpoint(state: &TrainState, out: &Path) -> Result<()> {
    let text = serde_json::to_string(state)
        .map_err(|e| Error::new(ErrorKind::Invalid, format!("checkpoint: {e}")))?;
    write_atomic(&out.join("checkpoint.json"), (text + "\n").as_bytes())?;
    json::write_file(&state.lens, &out.join("lens-latest.json"))
}

/// Runs (or continues) training from `state` to its last iteration, writing into `out_dir`
/// (created if missing): each iteration's [`IterLog`] as a line of `log.jsonl`, and a checkpoint
/// (`checkpoint.json`, the [`TrainState`] to resume from, with `lens-latest.json`) and
/// `lens-iterN.json` as [`RunControl::checkpoints`] says, after the last iteration and when
/// stopped. A state past its first iteration (a checkpoint read back, `tolray train --resume`)
/// continues the run saved in `out_dir`: the log is cut to the checkpoint's iterations (it may
/// hold later ones, logged after the last checkpoint); otherwise the log starts empty.
/// Every file but the log, which grows by one appended line per iteration, is written atomically
/// (a temporary file and a rename). `progress` receives each iteration's log after it is written.
/// On return `state` is the state after the last iteration run, equal to the last checkpoint.
/// Before a fresh run, write the starting design to `lens-initial.json` in `out_dir` (as
/// `tolray train` does) for [`final_report`] to compare against.
///
/// A stopped run resumed from its checkpoint ends in exactly the state, log and designs of an
/// uninterrupted one: iterations are deterministic (see [`step`]).
///
/// # Errors
/// Training errors of [`step`], and I/O errors naming the file.
///
/// # Examples
/// ```
/// use tolray::optim::train::{final_report, run_training, Checkpoints, RunControl, RunOutcome};
/// use tolray::optim::train::{TrainConfig, TrainState};
///
/// # fn main() -> tolray::Result<()> {
/// let out = std::env::temp_dir().join(format!("tolray-run-doc-{}", std::process::id()));
/// let lens = tolray::Lens::load("lens1")?;
/// let mut cfg = TrainConfig::for_lens(&lens);
/// (cfg.pretrain_iters, cfg.tolerance_iters) = (2, 0);
/// let mut state = TrainState::new(&lens, cfg);
/// let ctl = RunControl { checkpoints: Checkpoints::every(1), stop: &|| false };
/// let outcome = run_training(&mut state, &out, ctl, |l| println!("loss {:.4}", l.loss))?;
/// let RunOutcome::Finished { logs } = outcome else { unreachable!() };
/// assert_eq!(logs.len(), 2);
/// assert!(out.join("lens-iter2.json").exists());
/// let report = final_report(&state, &out, 4)?;
/// assert_eq!(report.designs.last().map(|d| d.name.as_str()), Some("final"));
/// report.write(&out)?;
/// # std::fs::remove_dir_all(&out).ok();
/// # Ok(())
/// # }
/// ```
pub fn run_training(
    state: &mut TrainState,
    out_dir: &Path,
    ctl: RunControl<'_>,
    mut progress: impl FnMut(&IterLog),
) -> Result<RunOutcome> {
    use std::io::Write;
    std::fs::create_dir_all(out_dir).map_err(|e| {
        Error::new(
            ErrorKind::Io,
            format!("{}: cannot create directory: {e}", out_dir.display()),
        )
    })?;
    let log_path = out_dir.join("log.jsonl");
    // The log holds exactly one line per finished iteration: on resume, cut it to the checkpoint.
    let mut logs: Vec<IterLog> = if state.next_iter > 0 {
        std::fs::read_to_string(&log_path)
            .unwrap_or_default()
            .lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .take(state.next_iter)
            .collect()
    } else {
        Vec::new()
    };
    let line = |l: &IterLog| {
        serde_json::to_string(l)
            .map_err(|e| Error::new(ErrorKind::Invalid, format!("log: {e}")))
            .map(|s| s + "\n")
    };
    let body = logs.iter().map(line).collect::<Result<String>>()?;
    write_atomic(&log_path, body.as_bytes())?;
    let mut log = std::fs::OpenOptions::new()
        .append(true)
        .open(&log_path)
        .map_err(|e| {
            Error::new(
                ErrorKind::Io,
                format!("{}: cannot open: {e}", log_path.display()),
            )
        })?;
    let total = state.total_iters();
    while state.next_iter < total {
        let l = step(state)?;
        log.write_all(line(&l)?.as_bytes()).map_err(|e| {
            Error::new(
                ErrorKind::Io,
                format!("{}: cannot write: {e}", log_path.display()),
            )
        })?;
        progress(&l);
        logs.push(l);
        let done = state.next_iter == total;
        let stop = (ctl.stop)();
        if done || ctl.checkpoints.due(state.next_iter) || stop {
            save_checkpoint(state, out_dir)?;
            json::write_file(
                &state.lens,
                &out_dir.join(format!("lens-iter{}.json", state.next_iter)),
            )?;
        }
        if stop && !done {
            return Ok(RunOutcome::Stopped {
                next_iter: state.next_iter,
            });
        }
    }
    Ok(RunOutcome::Finished { logs })
}

/// How [`run_to_report`] ended.
#[derive(Clone, Debug, PartialEq)]
pub enum RunEnd {
    /// Every iteration ran; the report is written.
    Finished(Box<TrainReport>),
    /// Stopped on request with a checkpoint: resume from `checkpoint.json`.
    Stopped {
        /// The next iteration to run (global, over both stages).
        next_iter: usize,
    },
}

/// A whole run, as `tolray train` and the C ABI's `tolray_train` drive it: for a fresh run
/// (a state at its first iteration) the starting design is written to `lens-initial.json`; then
/// [`run_training`]; when it finishes, `training.png` (the loss and spot curves), and the
/// [`final_report`] on `eval_trials` held-out patterns, written by [`TrainReport::write`].
///
/// # Errors
/// As [`run_training`] and [`final_report`]; I/O errors naming the file.
pub fn run_to_report(
    state: &mut TrainState,
    out_dir: &Path,
    ctl: RunControl<'_>,
    eval_trials: usize,
    progress: impl FnMut(&IterLog),
) -> Result<RunEnd> {
    if state.next_iter == 0 {
        std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
        json::write_file(&state.lens, &out_dir.join("lens-initial.json"))?;
    }
    let logs = match run_training(state, out_dir, ctl, progress)? {
        RunOutcome::Finished { logs } => logs,
        RunOutcome::Stopped { next_iter } => return Ok(RunEnd::Stopped { next_iter }),
    };
    crate::figures::save(
        &super::train::training_figure(&logs, "Training"),
        &out_dir.join("training.png"),
    )?;
    let report = final_report(state, out_dir, eval_trials)?;
    report.write(out_dir)?;
    Ok(RunEnd::Finished(Box::new(report)))
}

/// One design of a [`TrainReport`] with its held-out evaluation.
#[derive(Clone, Debug, PartialEq)]
pub struct DesignReport {
    /// "initial", "stage 1" (when both stages ran) or "final".
    pub name: String,
    /// The design.
    pub lens: Lens,
    /// Its evaluation on the held-out patterns.
    pub held_out: HeldOut,
}

/// The final report of a training run: the initial, stage-1 and final designs evaluated on
/// held-out tolerance patterns (see [`final_report`]).
#[derive(Clone, Debug, PartialEq)]
pub struct TrainReport {
    /// The run's settings.
    pub config: TrainConfig,
    /// Held-out patterns per design.
    pub eval_trials: usize,
    /// Seed of the held-out patterns (the training seed + 1000003).
    pub eval_seed: u64,
    /// "initial", then "stage 1" when both stages ran, then "final".
    pub designs: Vec<DesignReport>,
    /// The text report: the held-out table and the prescription change (`report.txt`).
    pub text: String,
}

/// The final report of the run in `out_dir` whose last state is `state`: the initial design
/// (`lens-initial.json` of `out_dir`, or the current design when that file cannot be read), the
/// design at the end of stage 1 (when both stages ran) and the final design, each evaluated with
/// [`held_out`] on `eval_trials` patterns of a seed other than training's.
///
/// # Errors
/// A corrupted design in `state`, and the errors of [`held_out`].
pub fn final_report(state: &TrainState, out_dir: &Path, eval_trials: usize) -> Result<TrainReport> {
    let initial =
        json::read_file(&out_dir.join("lens-initial.json")).unwrap_or_else(|_| state.lens.clone());
    let final_lens = state.lens.clone();
    let stage1 = state.stage1_lens.clone();
    let cfg = &state.config;
    let total = state.total_iters();
    let eval_seed = cfg.seed.wrapping_add(1_000_003);
    let mut designs: Vec<(&str, Lens)> = vec![("initial", initial)];
    if let (Some(s1), true) = (stage1, cfg.pretrain_iters > 0 && cfg.tolerance_iters > 0) {
        designs.push(("stage 1", s1));
    }
    designs.push(("final", final_lens));
    let mut text = format!("Training report ({} iterations: {} pretrain + {} tolerance-aware, {} patterns per iteration, seed {})\n\n", total, cfg.pretrain_iters, cfg.tolerance_iters, cfg.samples, cfg.seed);
    text.push_str(&format!("Held-out evaluation: {eval_trials} tolerance patterns of seed {eval_seed} (training used seed {}); RMS spot in µm, mean over the fields, with the sensor where the design puts it and with each lens refocused to its best focus (the assembly's focus compensator)\n", cfg.seed));
    text.push_str(&format!(
        "{:>10} {:>28} {:>10} {:>10} {:>11} {:>10} {:>10} {:>11} {:>10}\n",
        "design",
        "nominal RMS per field",
        "MC mean",
        "MC std",
        "90 % below",
        "refoc mean",
        "refoc std",
        "refoc 90 %",
        "PSF sim"
    ));
    let mut reports = Vec::new();
    for (name, l) in designs {
        let h = held_out(&l, cfg, eval_trials, eval_seed)?;
        text.push_str(&format!(
            "{name:>10} {:>28} {:>10.3} {:>10.3} {:>11.3} {:>10.3} {:>10.3} {:>11.3} {:>10.4}\n",
            fmt_list(&h.nominal_rms_um),
            h.rms_mean_um,
            h.rms_std_um,
            h.rms_yield90_um,
            h.refocused_rms_mean_um,
            h.refocused_rms_std_um,
            h.refocused_rms_yield90_um,
            h.psf_similarity_mean
        ));
        reports.push(DesignReport {
            name: name.to_string(),
            lens: l,
            held_out: h,
        });
    }
    let (initial, final_lens) = (&reports[0].lens, &reports[reports.len() - 1].lens);
    text.push_str("\nPrescription (radius / gap in mm): initial -> final\n");
    for (i, (a, b)) in initial
        .surfaces
        .iter()
        .zip(&final_lens.surfaces)
        .enumerate()
    {
        let r = |c: f64| {
            if c == 0.0 {
                "inf".to_string()
            } else {
                format!("{:.4}", 1.0 / c)
            }
        };
        text.push_str(&format!(
            "  {i:>3}  R {:>12} -> {:>12}   gap {:>9.4} -> {:>9.4}\n",
            r(a.c),
            r(b.c),
            a.d_next_mm,
            b.d_next_mm
        ));
    }
    Ok(TrainReport {
        config: cfg.clone(),
        eval_trials,
        eval_seed,
        designs: reports,
        text,
    })
}

impl TrainReport {
    /// The final design (the last of [`TrainReport::designs`]).
    pub fn final_lens(&self) -> &Lens {
        &self.designs[self.designs.len() - 1].lens
    }

    /// The JSON report: `{"config": ..., "designs": [{"design", "held_out", "lens"}, ...]}`.
    pub fn to_json(&self) -> serde_json::Value {
        let designs: Vec<serde_json::Value> = self
            .designs
            .iter()
            .map(|d| {
                serde_json::json!({"design": d.name, "held_out": d.held_out, "lens": json::to_value(&d.lens)})
            })
            .collect();
        serde_json::json!({"config": self.config, "designs": designs})
    }

    /// Writes `report.txt`, `report.json` and `lens-final.json` into `out_dir`.
    ///
    /// # Errors
    /// I/O errors naming the file.
    pub fn write(&self, out_dir: &Path) -> Result<()> {
        write_atomic(&out_dir.join("report.txt"), self.text.as_bytes())?;
        let report = serde_json::to_string_pretty(&self.to_json())
            .map_err(|e| Error::new(ErrorKind::Invalid, format!("report: {e}")))?;
        write_atomic(&out_dir.join("report.json"), (report + "\n").as_bytes())?;
        json::write_file(self.final_lens(), &out_dir.join("lens-final.json"))
    }
}

/// Numbers to three decimals, separated by spaces (as the CLI's tables print them).
/// Numbers to 3 decimals, space-separated (the reports' per-field lists; the CLI uses it too).
///
/// ```
/// assert_eq!(tolray::optim::train::fmt_list(&[1.0, 2.34567]), "1.000 2.346");
/// ```
pub fn fmt_list(v: &[f64]) -> String {
    v.iter()
        .map(|x| format!("{x:.3}"))
        .collect::<Vec<_>>()
        .join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run stopped at once and resumed ends in the state, log and design of an uninterrupted
    /// one; a stale log line past the checkpoint is cut on resume.
    #[test]
    fn stopped_and_resumed_equals_uninterrupted() {
        // Unoptimised (the unit tests' build), the dual-number training's frames outgrow the
        // 2 MiB stacks of the test's thread and of rayon's workers: run it on a pool of larger.
        rayon::ThreadPoolBuilder::new()
            .stack_size(64 << 20)
            .build()
            .unwrap()
            .install(stopped_and_resumed);
    }

    fn stopped_and_resumed() {
        let dir = std::env::temp_dir().join(format!("tolray-run-test-{}", std::process::id()));
        let lens = Lens::load("lens1").unwrap();
        let mut cfg = TrainConfig::for_lens(&lens);
        (cfg.pretrain_iters, cfg.tolerance_iters) = (2, 1);
        (cfg.samples, cfg.psf_spp) = (2, 32);
        let mut full = TrainState::new(&lens, cfg.clone());
        let opts = RunControl {
            checkpoints: Checkpoints::every(1),
            stop: &|| false,
        };
        let RunOutcome::Finished { logs } =
            run_training(&mut full, &dir.join("full"), opts, |_| {}).unwrap()
        else {
            panic!("not stopped")
        };
        assert_eq!(logs.len(), 3);
        for n in 1..=3 {
            assert!(dir.join(format!("full/lens-iter{n}.json")).exists());
        }

        let part = dir.join("part");
        let mut state = TrainState::new(&lens, cfg);
        let mut seen = 0;
        let opts = RunControl {
            checkpoints: Checkpoints::every(10),
            stop: &|| true,
        };
        let end = run_training(&mut state, &part, opts, |_| seen += 1).unwrap();
        assert_eq!(end, RunOutcome::Stopped { next_iter: 1 });
        assert_eq!(seen, 1);
        let ck: TrainState = crate::files::read_json(&part.join("checkpoint.json")).unwrap();
        assert!(ck == state);
        // A line logged after the checkpoint (a killed run) is dropped on resume.
        let log = part.join("log.jsonl");
        let text = std::fs::read_to_string(&log).unwrap();
        std::fs::write(&log, text.clone() + &text).unwrap();
        let opts = RunControl {
            checkpoints: Checkpoints::every(10),
            stop: &|| false,
        };
        let RunOutcome::Finished { logs: resumed } =
            run_training(&mut state, &part, opts, |_| {}).unwrap()
        else {
            panic!("stopped")
        };
        assert!(state == full);
        assert_eq!(resumed, logs);
        assert_eq!(
            std::fs::read_to_string(&log).unwrap(),
            std::fs::read_to_string(dir.join("full/log.jsonl")).unwrap()
        );
        let report = final_report(&state, &part, 2).unwrap();
        let names: Vec<&str> = report.designs.iter().map(|d| d.name.as_str()).collect();
        // No lens-initial.json here: the current design stands in for the initial one.
        assert_eq!(names, ["initial", "stage 1", "final"]);
        assert!(report
            .text
            .contains("Held-out evaluation: 2 tolerance patterns"));
        report.write(&part).unwrap();
        assert_eq!(
            json::read_file(&part.join("lens-final.json")).unwrap(),
            state.lens.clone()
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
